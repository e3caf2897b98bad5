"""One mapping from every error to an HTTP answer, all with the same body.

Body of every error response (:class:`service.schemas.ErrorResponse`)::

    {"detail": [{"loc": ["body", "receivers", 0, "position_m"],
                 "msg": "point ... lies on an organ surface ...",
                 "type": "ambiguous_position"}]}

``loc`` starts with where the field is (``body``, ``query``, ``path``,
``header``, ``upload``, or ``server`` for saturation/budget errors), then the
field path. FastAPI's own schema errors (422) are rewritten into this shape
(without echoing the input back).

Mapping:

=================================  ======================================
error                              status
=================================  ======================================
schema violation                   422
``raytrace.errors.InputError``      422 (and every subclass)
``EstimatorInputError``             422
``raytrace.errors.NotFoundError``   404
``Unauthorized`` / ``Forbidden``    401 / 403 (API keys, origins)
``UploadTooLarge``                  413
``UnsupportedMediaType``            415
``NotInstalled``                    501 (gprMax missing on the server)
``ServerSaturated``                 503 + Retry-After
``BudgetExceededError`` deadline    504
``BudgetExceededError`` work/memory 503 + Retry-After (kind ``work`` is not
                                    transient: retrying the same request
                                    will fail the same way; the message says
                                    what to lower)
``BudgetExceededError`` cancelled   503 + Retry-After
anything else                      500 (logged with the request id; a bug)
=================================  ======================================
"""

from __future__ import annotations

import logging
import re
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from estimators.errors import EstimatorInputError
from raytrace.errors import BudgetExceededError, CapsuleRTError, InputError, NotFoundError

log = logging.getLogger("capsule_rt.service")


class ServiceError(Exception):
    """An error raised by the service layer itself."""

    status_code = 400
    type = "bad_request"

    def __init__(self, reason: str, loc: list[str | int] | None = None, headers: dict[str, str] | None = None):
        super().__init__(reason)
        self.reason = reason
        self.loc = loc or []
        self.headers = headers or {}


class Unauthorized(ServiceError):
    status_code = 401
    type = "unauthorized"


class Forbidden(ServiceError):
    status_code = 403
    type = "forbidden"


class UploadTooLarge(ServiceError):
    status_code = 413
    type = "too_large"


class UnsupportedMediaType(ServiceError):
    status_code = 415
    type = "unsupported_media_type"


class ServerSaturated(ServiceError):
    status_code = 503
    type = "saturated"


class Conflict(ServiceError):
    status_code = 409
    type = "conflict"


class StorageFull(ServiceError):
    status_code = 507
    type = "storage_full"


class NotInstalled(ServiceError):
    """The server lacks an optional tool the request needs (gprMax): not the request's fault, not transient."""

    status_code = 501
    type = "not_installed"


class NotFound(ServiceError):
    status_code = 404
    type = "not_found"


class Unprocessable(ServiceError):
    status_code = 422
    type = "invalid"


class InvalidMesh(Unprocessable):
    """The mesh part is no binary glTF: the loader's own error type (raytrace PhantomValidationError)."""

    type = "phantom_validation"


_INDEX = re.compile(r"\[(\d+)\]")


def field_to_loc(field: str | tuple | None) -> list[str | int]:
    """``receivers[2].position_m`` -> ``["receivers", 2, "position_m"]``; a tuple of parts
    (``("manifest", "sites", "Sphere.001")``, see :mod:`raytrace.errors`) is taken as is."""
    if isinstance(field, tuple):
        return list(field)
    if not field:
        return []
    loc: list[str | int] = []
    for part in _INDEX.sub(r".\1", field).split("."):
        if part == "":
            continue
        loc.append(int(part) if part.isdigit() else part)
    return loc


def _type_name(exc: Exception) -> str:
    name = type(exc).__name__.removesuffix("Error")
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower() or "error"


def error_body(loc: list[str | int], msg: str, typ: str) -> dict[str, Any]:
    return {"detail": [{"loc": list(loc), "msg": msg, "type": typ}]}


def _where(request: Request) -> str:
    return request.scope.get("capsule_rt.error_loc") or ("query" if request.method in ("GET", "DELETE") else "body")


def install_error_handlers(app: FastAPI, retry_after_s: int) -> None:
    retry = {"Retry-After": str(retry_after_s)}

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        items = []
        for err in exc.errors():
            msg = str(err.get("msg", "invalid"))
            items.append({"loc": list(err.get("loc", [])), "msg": msg, "type": str(err.get("type", "value_error"))})
        return JSONResponse({"detail": items}, status_code=422)

    @app.exception_handler(ServiceError)
    async def _service(request: Request, exc: ServiceError) -> JSONResponse:
        headers = dict(exc.headers)
        if exc.status_code == 503:
            headers.setdefault("Retry-After", retry["Retry-After"])
        return JSONResponse(error_body(exc.loc, exc.reason, exc.type), status_code=exc.status_code, headers=headers)

    @app.exception_handler(CapsuleRTError)
    async def _core(request: Request, exc: CapsuleRTError) -> JSONResponse:
        return core_error_response(exc, _where(request), retry)

    @app.exception_handler(EstimatorInputError)
    async def _estimator(request: Request, exc: EstimatorInputError) -> JSONResponse:
        loc = [_where(request), *field_to_loc(getattr(exc, "field", None))]
        return JSONResponse(error_body(loc, getattr(exc, "reason", str(exc)), "estimator_input"), status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        msg = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        loc: list[str | int] = (["path"] if exc.status_code in (404, 405)
                                else ["body"] if exc.status_code in (400, 413) else [])
        kinds = {400: "malformed_body", 404: "not_found", 405: "method_not_allowed", 413: "too_large"}
        return JSONResponse(
            error_body(loc, msg, kinds.get(exc.status_code, "http_error")),
            status_code=exc.status_code,
            headers=getattr(exc, "headers", None),
        )

    @app.exception_handler(Exception)
    async def _bug(request: Request, exc: Exception) -> JSONResponse:
        # Runs in Starlette's outermost middleware, after the request-id context
        # has been reset: take the id from the scope.
        rid = str(request.scope.get("capsule_rt.request_id", ""))
        log.exception("unhandled error", extra={"path": request.url.path, "request_id": rid})
        return JSONResponse(
            error_body(["server"], f"internal error (request id {rid}); this is a bug, please report it", "internal"),
            status_code=500,
            headers={"X-Request-ID": rid} if rid else None,
        )


def core_error_response(exc: CapsuleRTError, where: str, retry: dict[str, str]) -> JSONResponse:
    loc = [where, *field_to_loc(exc.field)]
    if isinstance(exc, BudgetExceededError):
        loc = ["server", *field_to_loc(exc.field)]
        if exc.kind == "deadline":
            return JSONResponse(error_body(loc, exc.reason, "deadline_exceeded"), status_code=504)
        typ = {"work": "work_budget_exceeded", "memory": "memory_budget_exceeded"}.get(exc.kind, "cancelled")
        return JSONResponse(error_body(loc, exc.reason, typ), status_code=503, headers=retry)
    if isinstance(exc, NotFoundError):
        return JSONResponse(error_body(loc, exc.reason, "not_found"), status_code=404)
    if isinstance(exc, InputError):
        return JSONResponse(error_body(loc, exc.reason, _type_name(exc)), status_code=422)
    return JSONResponse(error_body(loc, exc.reason, _type_name(exc)), status_code=422)


#: Error responses declared in the OpenAPI schema of every route.
def error_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    from service.schemas import ErrorResponse

    text = {
        400: "Malformed request.",
        401: "API key missing or not valid (only when the server requires keys: uploads, jobs and deletes; header "
             "`X-API-Key`).",
        403: "Refused: another key submitted this phantom or job, or a write from a foreign origin.",
        404: "Unknown phantom, scenario, site or route.",
        409: "Conflict (e.g. deleting a built-in phantom).",
        413: "Request body over its size cap.",
        415: "Unsupported media type (a body in a format the operation does not take).",
        422: "Schema violation or a physical precondition broken; `detail[].loc` names the field.",
        501: "The server lacks an optional tool the request needs (gprMax); the message says what works without.",
        503: "Saturated or work budget exceeded; retry after `Retry-After` seconds.",
        504: "Deadline exceeded.",
        507: "Upload storage full.",
    }
    return {c: {"model": ErrorResponse, "description": text[c]} for c in codes}
