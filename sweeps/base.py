"""What the sweep spec (sweeps.spec), its localizers (sweeps.localization, sweeps.localizers) and the
path-loss fits (sweeps.pathloss) share: the spec's error, the value checks that raise it, a path-loss
model from its spec entry, the ranging columns' names and what a localizer sees. Below all of them
(it imports none), so they import each other without a cycle (tests/test_architecture.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from estimators.rss import CM2_MODELS, REFERENCE_DISTANCE_M, PathLossModel
from raytrace.errors import InputError


class SweepSpecError(InputError):
    """A sweep spec that cannot run; ``field`` is the dotted path of the bad value."""


def _fail(reason: str, field: str) -> SweepSpecError:
    return SweepSpecError(reason, field=field)


def _mapping(value: Any, field: str, allowed: set[str] | None = None) -> Mapping:
    if not isinstance(value, Mapping):
        raise _fail(f"expected an object, got {type(value).__name__}", field)
    if allowed is not None:
        unknown = sorted(set(value) - allowed)
        if unknown:
            raise _fail(f"unknown field(s) {', '.join(unknown)}; allowed: {', '.join(sorted(allowed))}",
                        f"{field}.{unknown[0]}" if field else unknown[0])
    return value


def _number(value: Any, field: str, *, positive: bool = False, nonnegative: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(f"must be a number, got {value!r}", field)
    x = float(value)
    if not math.isfinite(x):
        raise _fail(f"must be finite, got {value!r}", field)
    if positive and x <= 0:
        raise _fail(f"must be > 0, got {x:g}", field)
    if nonnegative and x < 0:
        raise _fail(f"must be >= 0, got {x:g}", field)
    return x


def rss_model(value: Any, field: str = "ranging.rss.model") -> PathLossModel:
    """A path-loss model from a CM2 name or a fitted model's mapping."""
    if isinstance(value, str):
        if value not in CM2_MODELS:
            raise _fail(f"unknown model {value!r} ({' | '.join(CM2_MODELS)} or a fitted model object)", field)
        return CM2_MODELS[value]
    value = _mapping(value, field, {"name", "path_loss_d0_db", "exponent", "shadowing_db", "reference_distance_m"})
    for key in ("path_loss_d0_db", "exponent", "shadowing_db"):
        if key not in value:
            raise _fail("required", f"{field}.{key}")
    name = value.get("name", "fitted")
    if not isinstance(name, str) or not name:
        raise _fail("a name is a non-empty string", f"{field}.name")
    return PathLossModel(
        name=name,
        path_loss_d0_db=_number(value["path_loss_d0_db"], f"{field}.path_loss_d0_db"),
        exponent=_number(value["exponent"], f"{field}.exponent", positive=True),
        shadowing_db=_number(value["shadowing_db"], f"{field}.shadowing_db", nonnegative=True),
        reference_distance_m=_number(value.get("reference_distance_m", REFERENCE_DISTANCE_M),
                                     f"{field}.reference_distance_m", positive=True),
    )


def method_columns(ranging: Mapping) -> list[str]:
    """The ranging methods of a normalised ranging dict, as table column prefixes, in order."""
    out = [f"toa_{m}" for m in ranging.get("toa", {}).get("methods", [])]
    out += [f"pdoa_{m}" for m in ranging.get("pdoa", {}).get("methods", [])]
    if "rss" in ranging:
        out.append("rss")
    return out


@dataclass(frozen=True)
class LocalizationInputs:
    """What a localizer sees for one capsule position and one carrier (arrays over receivers).

    ``ranges_m`` is the ranging method's mean distance per receiver (NaN where it has none),
    ``path_loss_db`` the traced path loss, ``sigma_m`` the method's spread over trials;
    ``receivers_m`` the receiver positions. ``centreline`` (or None) lets a localizer
    constrain its estimate to the tract; ``phantom`` (or None) is the traced phantom (the
    model-based localizer builds its travel-time fields through it)."""

    frequency_hz: float
    receivers_m: np.ndarray
    ranges_m: np.ndarray
    sigma_m: np.ndarray
    path_loss_db: np.ndarray
    relative_permittivity: float
    centreline: Any = None
    extra: dict = field(default_factory=dict)
    phantom: Any = None
