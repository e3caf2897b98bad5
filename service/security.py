"""Who may write: optional API keys, phantom ownership, and the origins allowed to write.

The model (docs/service.md, "Security"):

* Reads (every GET) and the computations that keep no state (channel, ranging,
  bounds, localization, tracking, plots, vision) are open.
* Writes that keep or remove state (uploads, sweep and full-wave jobs, their
  cancellations and deletes: the operations declared ``keyed``,
  :mod:`service.admission`): with ``CAPSULE_RT_API_KEYS`` unset, open to anyone who
  reaches the port (a private bench or a container network). With keys set,
  they need the header ``X-API-Key`` holding one of them (401 otherwise, before
  the body is read), a stored phantom or job records which key submitted it (as
  :func:`owner_id`, a hash: the key itself is never written to disk), and only
  that key deletes it (403 for any other). Phantoms and jobs stored while keys
  were unset have no owner: any valid key deletes them.
* Browsers: a web page of another origin can send a multipart form POST
  without any CORS preflight, and the browser only hides the answer. So a
  write (POST, PUT, PATCH, DELETE) whose ``Origin`` header is neither the
  server's own origin nor in ``CAPSULE_RT_CORS_ORIGINS`` is refused with 403
  before it is read. Clients that are not browsers send no ``Origin`` and are
  unaffected. ``CAPSULE_RT_CORS_ORIGINS`` (default empty) also lists the
  origins whose pages may read the API's answers (CORS headers).
"""

from __future__ import annotations

import hashlib
import hmac
from urllib.parse import urlsplit

from starlette.requests import Request
from starlette.responses import JSONResponse

from service.errors import Forbidden, Unauthorized, error_body
from service.settings import Settings

API_KEY_HEADER = "X-API-Key"
_WRITES = frozenset({"POST", "PUT", "PATCH", "DELETE"})


def owner_id(key: str) -> str:
    """The id stored for the key that uploaded a phantom (SHA-256, 16 hex digits)."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()[:16]


def key_error(given: str | None, settings: Settings) -> Unauthorized | None:
    """Why a write's ``X-API-Key`` header value is refused (None when keys are not in use or it is
    valid). Every configured key is compared in constant time (no early exit that times the match)."""
    if not settings.api_keys:
        return None
    challenge = {"WWW-Authenticate": f'ApiKey header="{API_KEY_HEADER}"'}
    if given is None:
        return Unauthorized(
            f"this server requires an API key for uploads, jobs and deletes: send it in the {API_KEY_HEADER} header",
            loc=["header", API_KEY_HEADER.lower()], headers=challenge)
    valid = [hmac.compare_digest(given.encode("utf-8", "replace"), k.encode("utf-8")) for k in settings.api_keys]
    if not any(valid):
        return Unauthorized("the API key is not valid", loc=["header", API_KEY_HEADER.lower()], headers=challenge)
    return None


def writer(request: Request, settings: Settings) -> str | None:
    """The owner id of a write request's API key (None when keys are not in use);
    401 when keys are in use and the request has no valid one."""
    given = request.headers.get(API_KEY_HEADER)
    error = key_error(given, settings)
    if error is not None:
        raise error
    return None if not settings.api_keys else owner_id(given)


def check_owner(stored_owner: str | None, requester: str | None, what: str) -> None:
    """403 unless ``requester`` (an owner id, None without keys) may delete ``what`` (a phantom, a job),
    stored with ``stored_owner`` (None: stored without keys, which any valid key may delete)."""
    if requester is not None and stored_owner is not None and not hmac.compare_digest(stored_owner, requester):
        raise Forbidden(f"{what} was submitted with another API key; only that key deletes it",
                        loc=["header", API_KEY_HEADER.lower()])


def _own_origin(scope) -> str | None:
    for name, value in scope.get("headers", []):
        if name == b"host":
            return value.decode("latin-1").lower()
    return None


class OriginGuard:
    """Pure-ASGI middleware: refuse a write whose ``Origin`` is foreign (module docstring)."""

    def __init__(self, app, allowed_origins: list[str]) -> None:
        self.app = app
        self.allowed = frozenset(o.lower().rstrip("/") for o in allowed_origins)

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http" and scope.get("method") in _WRITES:
            origin = next((v.decode("latin-1") for k, v in scope.get("headers", []) if k == b"origin"), None)
            if origin is not None and not self._allowed(origin.strip().lower(), scope):
                body = error_body(
                    ["header", "origin"],
                    f"writes from a web page of origin {origin[:200]!r} are refused: it is neither this "
                    "server's origin nor in CAPSULE_RT_CORS_ORIGINS",
                    Forbidden.type,
                )
                await JSONResponse(body, status_code=403)(scope, receive, send)
                return
        await self.app(scope, receive, send)

    def _allowed(self, origin: str, scope) -> bool:
        if origin.rstrip("/") in self.allowed:
            return True
        try:
            parts = urlsplit(origin)
        except ValueError:
            return False
        return parts.scheme in ("http", "https") and parts.netloc != "" and parts.netloc == _own_origin(scope)
