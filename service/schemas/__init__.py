"""Request and response models of the HTTP API (``docs/api.md``), pydantic v2: what every model shares.

The models live by what they describe: :mod:`service.schemas.channel` (POST /v1/channel),
:mod:`service.schemas.ranging` (ranging and Cramér-Rao bounds), :mod:`service.schemas.phantoms`
(tissues, phantoms, scenarios and the upload manifest); this module holds their bases, the shared
field types, the error body and the health answers.

Conventions:

* SI units, the unit in the field name and in brackets in its description.
* Every request model forbids unknown fields and non-finite numbers
  (``NaN`` / ``Infinity`` get a 422), and its types are strict: a boolean or
  a numeric string is not a number, 1.5 is not an integer. Where fields
  depend on each other (exactly one of two), the schema says it with
  ``oneOf`` nested in ``allOf`` (:func:`alternatives`). Responses never contain non-finite numbers either:
  a zero gain's ``-inf`` dB is clamped to :data:`GAIN_DB_FLOOR` (-400 dB).
* Complex numbers are ``{"re": float, "im": float}``.
* Array sizes and compute knobs are bounded; the ``le`` bounds here are the
  hard ceilings of :mod:`service.settings`, which an operator may tighten.
* Errors (every 4xx/5xx) have the body :class:`ErrorResponse`: ``detail`` is a
  list of ``{loc, msg, type}`` whose ``loc`` names the offending field
  (``["body", "receivers", 0, "position_m"]``), the same shape FastAPI uses
  for schema violations.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StringConstraints,
    model_validator,
)

from service.limits import MAX_BAND_POINTS, capped
from service.schemas.constants import FREQUENCY_MAX_HZ, FREQUENCY_MIN_HZ, NAME_PATTERN

#: dB value reported for a zero gain / power (instead of -inf) [dB].
GAIN_DB_FLOOR = -400.0

ID_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,63}$"

PhantomId = Annotated[str, StringConstraints(pattern=ID_PATTERN)]
ScenarioId = Annotated[str, StringConstraints(pattern=ID_PATTERN)]
Name = Annotated[str, StringConstraints(pattern=NAME_PATTERN)]
Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


def _integral(value: Any) -> Any:
    """JSON Schema's ``integer`` is any number without a fractional part (``100.0``, ``1e2``): such
    a float becomes the int; every other value goes on to strict validation (a boolean or a
    numeric string stays refused)."""
    if type(value) is float and value.is_integer():
        return int(value)
    return value


#: An integer field of a request: strict, but 100.0 counts, as the schema's ``integer`` says.
Int = Annotated[int, BeforeValidator(_integral)]


def int_range(ge: int, le: int) -> Any:
    """An ``Int`` between ``ge`` and ``le``, for optional fields: written this way (the bounds before
    the validator) the schema says ``minimum``/``maximum``; ``Int | None = Field(ge=...)`` would
    emit pydantic's internal ``ge`` keys, which no schema tool reads."""
    return Annotated[int, Field(ge=ge, le=le), BeforeValidator(_integral)]

FrequencyHz = Annotated[float, Field(ge=FREQUENCY_MIN_HZ, le=FREQUENCY_MAX_HZ)]


def alternatives(*groups: list[dict], keyword: str = "oneOf") -> dict:
    """The ``json_schema_extra`` of an object whose fields depend on each other: each group (a list
    of branches, e.g. "``position_m`` or ``site``") becomes ``{keyword: group}``, all of them under
    ``allOf``. JSON Schema reads ``{"allOf": [{"oneOf": X}]}`` exactly as ``{"oneOf": X}``; client
    generators do not: given an object-level ``oneOf`` they make the type a union of its bare
    branches and drop the object's own properties (openapi-python-client then refuses the
    schema), while they merge ``allOf`` and leave the nested ``oneOf`` to the server. A field
    that a branch excludes is written ``"not": {"required": [name]}``, never a ``false`` schema
    (which OpenAPI 3.1 allows but generators cannot parse). ``tests/service/test_generated_client.py``
    holds the generators to this."""
    return {"allOf": [{keyword: branches} for branches in groups]}


class Strict(BaseModel):
    """Base of request models: no unknown fields, no NaN / infinity, strict types (``"rays": true``
    and ``"rays": "5"`` are refused, as the schema's ``integer`` says)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class Out(BaseModel):
    """Base of response models (strict as well: a profile's paths, interactions and segments
    come back inside ranging requests)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


# ----------------------------------------------------------------- errors
class ErrorItem(BaseModel):
    loc: list[str | int] = Field(
        description="Where the problem is: location then field path, e.g. [\"body\", \"rays\"].")
    msg: str = Field(description="Why it was rejected.")
    type: str = Field(description="Machine-readable error type.")


class ErrorResponse(BaseModel):
    detail: list[ErrorItem]


# ----------------------------------------------------------------- shared
class Complex(Strict):
    re: float = Field(description="Real part [same unit as the quantity].")
    im: float = Field(description="Imaginary part [same unit as the quantity].")


class Band(Strict):
    start_hz: FrequencyHz = Field(description="First frequency [Hz].")
    stop_hz: FrequencyHz = Field(description="Last frequency [Hz] (> start_hz).")
    points: Int = Field(ge=2, le=MAX_BAND_POINTS, description="Number of equally spaced frequencies [-].",
                        json_schema_extra=capped("max_band_points"))

    @model_validator(mode="after")
    def _order(self) -> "Band":
        if not self.stop_hz > self.start_hz:
            raise ValueError("stop_hz must be greater than start_hz")
        return self


# ----------------------------------------------------------------- health
class Health(Out):
    status: Literal["ok"]


class Readiness(Out):
    status: Literal["ready", "starting"]
    phantoms: int
    scenarios: int
    ray_engine: str
    errors: list[str] = Field(default_factory=list, description="Built-ins that failed to load (the rest is served).")
