"""JSON request bodies too big to handle on the event loop (ranging profiles).

A route of :class:`ThreadedJsonRoute` reads its body (within the route's
``max_body_size``, refused with 413 while it streams in), then in a worker
thread: parses it, checks the length of every bounded list against its
``max_length`` *before* a single item is validated (pydantic validates all
items of a list, then its length: a million-path profile would cost seconds
before its refusal), and validates the model in pydantic's strict mode (``true`` is not a
number nor ``0`` a boolean, whatever the model's own config says). FastAPI is handed the
validated model, which it accepts as is, so the event loop never walks a
large body. Errors have the shape of FastAPI's own: 422 with
``loc = ["body", ...]``, and 400 for a body that is not JSON at all.
"""

from __future__ import annotations

import json
import types
import typing
from typing import Any, get_args, get_origin

import anyio.to_thread
from annotated_types import MaxLen
from fastapi.exceptions import RequestValidationError
from fastapi.routing import APIRoute
from pydantic import BaseModel, ValidationError
from starlette.exceptions import HTTPException
from starlette.requests import Request


def _list_bound(annotation: Any, metadata: list) -> tuple[int | None, Any]:
    """(max_length, item annotation) of a list field (None when it is not a bounded list)."""
    bound = next((m.max_length for m in metadata if isinstance(m, MaxLen)), None)
    for arg in _members(annotation):
        if get_origin(arg) is list:
            return bound, get_args(arg)[0]
    return None, None


def _members(annotation: Any) -> tuple:
    """The members of an ``X | Y | None`` union (or the annotation itself)."""
    if get_origin(annotation) in (typing.Union, types.UnionType):
        return get_args(annotation)
    return (annotation,)


def _model_of(annotation: Any) -> type[BaseModel] | None:
    for arg in _members(annotation):
        if isinstance(arg, type) and issubclass(arg, BaseModel):
            return arg
    return None


def check_list_lengths(model: type[BaseModel], data: Any, loc: tuple = ("body",)) -> None:
    """Raise a 422 for the first list longer than its field's ``max_length``, anywhere in
    ``data`` (walking nested models and lists of models), without validating any item."""
    if not isinstance(data, dict):
        return
    for name, field in model.model_fields.items():
        value = data.get(field.alias or name)
        if value is None:
            continue
        bound, item = _list_bound(field.annotation, field.metadata)
        if isinstance(value, list) and bound is not None:
            if len(value) > bound:
                raise RequestValidationError([{
                    "type": "too_long",
                    "loc": (*loc, name),
                    "msg": f"List should have at most {bound} items, not {len(value)}",
                    "input": None,
                }])
            inner = _model_of(item)
            if inner is not None:
                for k, element in enumerate(value):
                    check_list_lengths(inner, element, (*loc, name, k))
            continue
        inner = _model_of(field.annotation)
        if inner is not None:
            check_list_lengths(inner, value, (*loc, name))


def decode(model: type[BaseModel], body: bytes) -> BaseModel:
    """JSON bytes -> validated ``model`` (run it in a worker thread)."""
    try:
        data = json.loads(body)
    except json.JSONDecodeError as exc:
        raise RequestValidationError(
            [{"type": "json_invalid", "loc": ("body", exc.pos), "msg": "JSON decode error", "input": {}}]
        ) from None
    except RecursionError:
        raise HTTPException(400, "the JSON body nests too deeply to be parsed") from None
    except ValueError as exc:  # not UTF-8, or an integer with too many digits
        raise HTTPException(400, f"the body is not valid JSON: {str(exc)[:200]}") from None
    check_list_lengths(model, data)
    try:
        return model.model_validate(data, strict=True)  # a boolean or a numeric string is not a number
    except ValidationError as exc:
        errors = [{"type": e["type"], "loc": ("body", *e["loc"]), "msg": e["msg"], "input": None}
                  for e in exc.errors(include_url=False, include_input=False)]
        raise RequestValidationError(errors) from None


class ThreadedJsonRoute(APIRoute):
    """An APIRoute whose JSON body model is decoded off the event loop (module docstring)."""

    def get_route_handler(self):
        handler = super().get_route_handler()
        model = _model_of(self.body_field.field_info.annotation) if self.body_field is not None else None
        if model is None:
            return handler

        async def route_handler(request: Request):
            kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
            if kind == "application/json" or kind.endswith("+json"):
                body = await request.body()
                if body:
                    # FastAPI takes a cached request.json() as the body, and a model instance as valid
                    request._json = await anyio.to_thread.run_sync(decode, model, body)
            return await handler(request)

        return route_handler
