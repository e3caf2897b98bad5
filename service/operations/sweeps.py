"""A sweep spec's body (JSON or YAML) decoded and its media type checked, for POST /v1/sweeps
(docs/sweeps.md); the job itself runs in :mod:`service.sweep_jobs` over :mod:`sweeps`."""

from __future__ import annotations

import json
from typing import Any

from service.errors import ServiceError, Unprocessable, UnsupportedMediaType
from sweeps.spec import parse_text

#: The media types a spec may come as: JSON, or YAML. Anything else (above all the types a web page's form
#: or a no-preflight fetch sends: text/plain, application/x-www-form-urlencoded, multipart/form-data) is 415.
YAML_TYPES = ("application/yaml", "application/x-yaml", "text/yaml")


def spec_media_type(header: str | None) -> str:
    kind = (header or "").split(";")[0].strip().lower()
    if kind == "application/json" or (kind.startswith("application/") and kind.endswith("+json")) or kind in YAML_TYPES:
        return kind
    raise UnsupportedMediaType(f"a sweep spec is sent as application/json or application/yaml, not "
                               f"{kind[:100] or 'a body without Content-Type'}", loc=["header", "content-type"])


def decode_spec(body: bytes, kind: str) -> dict:
    """A sweep spec's body (JSON, or YAML for ``application/yaml``) as an object: 400 naming the
    body when it is not UTF-8, not JSON/YAML, or nests too deeply to parse; 422 when it is not an
    object. Call it off the event loop: a 1 MiB YAML spec takes seconds to parse."""
    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError:
        raise ServiceError("the spec is not UTF-8 text", loc=["body"]) from None
    try:
        if kind in YAML_TYPES:
            from raytrace.errors import InputError

            try:
                data: Any = parse_text(text, ".yaml")
            except InputError as exc:
                raise ServiceError(exc.reason, loc=["body"]) from None
        else:
            try:
                data = json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
            except ValueError as exc:  # malformed, NaN/Infinity, an integer of too many digits
                raise ServiceError(f"malformed JSON: {exc}", loc=["body"]) from None
    except RecursionError:
        raise ServiceError("the spec nests too deeply to be parsed", loc=["body"]) from None
    if not isinstance(data, dict):
        raise Unprocessable("a sweep spec is a JSON object", loc=["body"])
    return data
