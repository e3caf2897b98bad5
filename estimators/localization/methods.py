"""The position methods, one registry (docs/localization.md, "Position methods").

Every caller that turns a method's name into a fix looks it up here: POST /v1/localize
(``service.operations.localize``), the end-to-end evaluation (``evaluation.localization``) and the
sweeps' localizers (``sweeps.localizers``). An entry says what each sensor must have measured
(``measures``: ranges, delays or path losses) and makes the fix from a :class:`Measurements`;
:func:`locate` checks that the measurements are there and dispatches. A new method is one entry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Literal

from ..errors import EstimatorInputError
from .model_based import model_based_fix
from .multilateration import joint_velocity_fix, linear_fix, nonlinear_fix
from .pathloss import rss_fix
from .results import PositionResult

Measured = Literal["ranges_m", "delays_s", "path_loss_db"]


@dataclass(frozen=True)
class Measurements:
    """One fix's inputs: the sensors' positions [m] (n x 3) and what they measured. A method reads
    the field its entry ``measures`` names (ranges with ``sigma_m``, delays with ``sigma_s``, path
    losses through ``model``); the model-based fix reads ``fields`` (travel-time fields from the
    sensors, estimators.localization.traveltime) instead of the positions. ``loss``: the robust loss
    of the least-squares methods (None: the method's default)."""

    sensors_m: Any = None
    ranges_m: Any = None
    sigma_m: Any = None
    delays_s: Any = None
    sigma_s: Any = None
    path_loss_db: Any = None
    model: Any = "cm2_deep_tissue"
    fields: Any = None
    loss: str | None = None


@dataclass(frozen=True)
class Method:
    """A registered position method: ``fix(measurements)`` -> :class:`PositionResult`."""

    name: str
    measures: Measured
    description: str
    fix: Callable[[Measurements], PositionResult]
    needs_fields: bool = False


def _loss(m: Measurements) -> dict[str, Any]:
    return {} if m.loss is None else {"loss": m.loss}


METHODS: dict[str, Method] = {entry.name: entry for entry in (
    Method("linear", "ranges_m", "closed-form least squares on ranges (thesis Eq 5.2)",
           lambda m: linear_fix(m.sensors_m, m.ranges_m, m.sigma_m)),
    Method("nonlinear", "ranges_m", "weighted nonlinear least squares on ranges",
           lambda m: nonlinear_fix(m.sensors_m, m.ranges_m, m.sigma_m, **_loss(m))),
    Method("joint_velocity", "delays_s", "position and an unknown effective velocity from delays (>= 5 sensors)",
           lambda m: joint_velocity_fix(m.sensors_m, m.delays_s, m.sigma_s, **_loss(m))),
    Method("model_based", "delays_s", "delays on travel-time fields through the phantom (heterogeneity-aware)",
           lambda m: model_based_fix(m.fields, m.delays_s, m.sigma_s, **_loss(m)), needs_fields=True),
    Method("rss", "path_loss_db", "path losses inverted through a path-loss model, then multilaterated",
           lambda m: rss_fix(m.sensors_m, m.path_loss_db, m.model, **_loss(m))),
)}

#: The registered methods' names, in the order the API lists them.
POSITION_METHODS = tuple(METHODS)


def position_method(name: str, field: str = "method") -> Method:
    """The registered method ``name``; an unknown one is an EstimatorInputError naming ``field``."""
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise EstimatorInputError(f"unknown method {name!r} ({' | '.join(METHODS)})", field) from None


def locate(name: str, measurements: Measurements) -> PositionResult:
    """The fix of method ``name`` (:data:`METHODS`) from ``measurements``."""
    entry = position_method(name)
    if getattr(measurements, entry.measures) is None:
        raise EstimatorInputError(f"method {name} needs {entry.measures}", entry.measures)
    if entry.needs_fields and measurements.fields is None:
        raise EstimatorInputError(f"method {name} needs the sensors' travel-time fields", "fields")
    return entry.fix(measurements)
