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
  write (POST, PUT, PATCH, DELETE) whose ``Origin`` header is not one of the
  configured origins (:func:`configured_origins`: ``CAPSULE_RT_CORS_ORIGINS`` and
  the server's own ``http://HOST:PORT``; scheme, host and port all count; never
  the request's ``Host``, which a DNS-rebinding page controls) is refused with
  403 before it is read. Clients that are not browsers send no ``Origin`` and
  are unaffected. ``CAPSULE_RT_CORS_ORIGINS`` (default empty) also lists the
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
    return None if given is None or not settings.api_keys else owner_id(given)


def check_owner(stored_owner: str | None, requester: str | None, what: str) -> None:
    """403 unless ``requester`` (an owner id, None without keys) may delete ``what`` (a phantom, a job),
    stored with ``stored_owner`` (None: stored without keys, which any valid key may delete)."""
    if requester is not None and stored_owner is not None and not hmac.compare_digest(stored_owner, requester):
        raise Forbidden(f"{what} was submitted with another API key; only that key deletes it",
                        loc=["header", API_KEY_HEADER.lower()])


Origin = tuple[str, str, int]

_DEFAULT_PORTS = {"http": 80, "https": 443}
_LOOPBACK = ("127.0.0.1", "localhost", "::1")


def parse_origin(text: str) -> Origin | None:
    """``scheme://host[:port]`` as (scheme, host, port) with the scheme's default port made explicit
    (browsers leave it out); None for anything else (``null``, a path, another scheme)."""
    try:
        parts = urlsplit(text.strip().lower())
        port = parts.port
    except ValueError:
        return None
    if parts.scheme not in _DEFAULT_PORTS or not parts.hostname or parts.path not in ("", "/") \
            or parts.query or parts.fragment or parts.username is not None:
        return None
    return parts.scheme, parts.hostname, port if port is not None else _DEFAULT_PORTS[parts.scheme]


def configured_origins(settings: Settings) -> frozenset[Origin]:
    """The origins whose pages may write: ``CAPSULE_RT_CORS_ORIGINS``, and the server's own as configured
    (``http://HOST:PORT`` of ``capsule-rt serve``; for a loopback or wildcard HOST, the loopback names of
    PORT: what a browser on this machine uses). Never the request's ``Host`` header: a page served from
    another name (DNS rebinding) would pass a Host check with its own Host."""
    origins = {o for o in (parse_origin(text) for text in settings.cors_origins) if o is not None}
    host = settings.host.strip("[]").lower()
    if host in (*_LOOPBACK, "0.0.0.0", "::", ""):
        origins |= {("http", name, settings.port) for name in _LOOPBACK}
    else:
        origins.add(("http", host, settings.port))
    return frozenset(origins)


class OriginGuard:
    """Pure-ASGI middleware: refuse a write whose ``Origin`` is not one of :func:`configured_origins`
    (scheme, host and port all count), before anything is read (module docstring)."""

    def __init__(self, app, settings: Settings) -> None:
        self.app = app
        self.allowed = configured_origins(settings)

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http" and scope.get("method") in _WRITES:
            origin = next((v.decode("latin-1") for k, v in scope.get("headers", []) if k == b"origin"), None)
            if origin is not None and parse_origin(origin) not in self.allowed:
                body = error_body(
                    ["header", "origin"],
                    f"writes from a web page of origin {origin[:200]!r} are refused: it is neither this "
                    "server's configured origin (http://HOST:PORT) nor in CAPSULE_RT_CORS_ORIGINS",
                    Forbidden.type,
                )
                await JSONResponse(body, status_code=403)(scope, receive, send)
                return
        await self.app(scope, receive, send)
