"""Pure-ASGI middleware: request id, access log, request metrics; methods per the contract. (A write's
key and body cap: service.admission.Gate; foreign origins: service.security.OriginGuard.)"""

from __future__ import annotations

import logging
import re
import time
import uuid

from service.logs import request_id_var
from service.metrics import Metrics

_SANE_ID = re.compile(r"^[A-Za-z0-9._:-]{1,128}$")
#: Metric label values are bounded: any other method is counted as OTHER.
_METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})
access_log = logging.getLogger("capsule_rt.access")


class RequestContextMiddleware:
    """Accept ``X-Request-ID`` from the client if sane (else make one), echo it in
    the response, log one JSON line per request and count it per route template."""

    def __init__(self, app, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        rid = None
        for name, value in scope.get("headers", []):
            if name == b"x-request-id":
                try:
                    candidate = value.decode("ascii")
                except UnicodeDecodeError:
                    candidate = ""
                if _SANE_ID.match(candidate):
                    rid = candidate
                break
        rid = rid or uuid.uuid4().hex
        scope["capsule_rt.request_id"] = rid
        token = request_id_var.set(rid)
        status = {"code": 500}
        start = time.perf_counter()

        async def send_wrapper(message):
            if message["type"] == "http.response.start":
                status["code"] = message["status"]
                headers = list(message.get("headers", []))
                headers.append((b"x-request-id", rid.encode("ascii")))
                message = {**message, "headers": headers}
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            elapsed = time.perf_counter() - start
            route = scope.get("route")
            template = getattr(route, "path", None) or "unmatched"
            method = scope.get("method", "")
            method = method if method in _METHODS else "OTHER"
            self.metrics.requests.labels(method, template, str(status["code"])).inc()
            self.metrics.latency.labels(method, template).observe(elapsed)
            access_log.info(
                "request",
                extra={
                    "method": method,
                    "path": scope.get("path", ""),
                    "route": template,
                    "status": status["code"],
                    "duration_s": round(elapsed, 6),
                },
            )
            request_id_var.reset(token)


class AllowedMethods:
    """Answer per the contract (the OpenAPI document) about methods: ``OPTIONS`` on an
    operation's path is 204 with ``Allow`` listing the methods the document declares for it
    (a CORS preflight, when CORS is configured, is answered before this); a 405 lists the
    same set (the router alone would list only one of the routes sharing the path)."""

    def __init__(self, app, openapi) -> None:
        self.app = app
        self._openapi = openapi  # a callable returning the document (built on first use)
        self._table: list[tuple[re.Pattern, str]] | None = None

    def _allow(self, path: str) -> str | None:
        if self._table is None:
            table = []
            for template, item in self._openapi().get("paths", {}).items():
                pattern = re.compile("^" + re.sub(r"\\\{[^}]+\\\}", "[^/]+", re.escape(template)) + "$")
                methods = sorted({m.upper() for m in item} & _METHODS | {"OPTIONS"})
                table.append((pattern, ", ".join(methods)))
            self._table = table
        return next((allow for pattern, allow in self._table if pattern.match(path)), None)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        allow = self._allow(scope.get("path", ""))
        if allow is not None and scope.get("method") == "OPTIONS":
            await send({"type": "http.response.start", "status": 204,
                        "headers": [(b"allow", allow.encode("ascii")), (b"content-length", b"0")]})
            await send({"type": "http.response.body", "body": b""})
            return

        async def send_allow(message):
            if message["type"] == "http.response.start" and message["status"] == 405 and allow is not None:
                headers = [(k, v) for k, v in message.get("headers", []) if k.lower() != b"allow"]
                message = {**message, "headers": [*headers, (b"allow", allow.encode("ascii"))]}
            await send(message)

        await self.app(scope, receive, send_allow)
