"""The position estimators (``estimators.localization``) as sweep localizers (:mod:`sweeps.localization`).

Registered when ``estimators.localization`` is installed (:func:`sweeps.localization.available`
imports this module only then):

============  ==============================================================  ===============
name          estimator                                                       options
============  ==============================================================  ===============
``linear``    ``linear_fix``: closed-form least squares on the ranges         ``ranges_from``
``nonlinear`` ``nonlinear_fix``: weighted nonlinear least squares (robust     ``ranges_from``,
              ``loss`` optional), started from the linear fix                 ``loss``
``rss``       ``rss_fix``: path losses inverted through a path-loss model,    ``model``
              then multilateration on log-distances
``model_      ``model_based_fix``: the ranging's delays (distance / v) on     ``ranges_from``,
based``       travel-time fields through the traced phantom (4 mm cells),     ``delay_kind``,
              built with the index of the delays' kind                        ``loss``
============  ==============================================================  ===============

Each uses the receivers that have a value (a range from ``ranges_from``'s method, or a traced
path loss); the range weights are the method's spread over trials (``<method>_std_m``) when every
one is positive, else none. Fewer than 4 usable receivers: no estimate, and the row's ``note``
says why. ``delay_kind`` (``group`` | ``phase``) defaults to the kind ``ranges_from``'s method
measures (``estimators.localization.measured_delay_kind``: group for ``toa_envelope`` and PDOA,
phase for the carrier-phase TOA methods; docs/localization.md, "Delay kinds").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.constants import velocity_m_per_s
from estimators.errors import EstimatorInputError
from estimators.localization import (
    DELAY_KINDS,
    Measurements,
    check_delay_kind,
    locate,
    measured_delay_kind,
)
from sweeps.base import LocalizationInputs, SweepSpecError, rss_model

__all__: list[str] = []

_LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")


def _fail(reason: str, field: str):
    return SweepSpecError(reason, field=field)


def _usable(values: np.ndarray, what: str) -> np.ndarray:
    ok = np.isfinite(values)
    if ok.sum() < 4:
        raise EstimatorInputError(f"a 3-D fix needs at least 4 receivers with {what}, {int(ok.sum())} have one",
                                  "receivers")
    return ok


def _ranges(name: str):
    def localize(inputs: LocalizationInputs, options: dict[str, Any]):
        ok = _usable(inputs.ranges_m, "a range")
        sigma = inputs.sigma_m[ok]
        weights = sigma if np.all(np.isfinite(sigma) & (sigma > 0)) else None
        return locate(name, Measurements(sensors_m=inputs.receivers_m[ok], ranges_m=inputs.ranges_m[ok],
                                         sigma_m=weights, loss=options.get("loss"))).position_m
    return localize


def _rss(inputs: LocalizationInputs, options: dict[str, Any]):
    ok = _usable(inputs.path_loss_db, "a path")
    return locate("rss", Measurements(sensors_m=inputs.receivers_m[ok], path_loss_db=inputs.path_loss_db[ok],
                                      model=rss_model(options.get("model", "cm2_deep_tissue"), "model"))).position_m


#: Cell edge of the model-based localizer's travel-time grids [m] (as evaluation.fields').
CELL_SIZE_M = 0.004


def _model_based(inputs: LocalizationInputs, options: dict[str, Any]):
    from estimators.localization.fieldstore import fields_for_sensors
    from raytrace.body.indexgrid import grid_key, index_grid

    if inputs.phantom is None:
        raise EstimatorInputError("the model-based fix needs the traced phantom", "phantom")
    ok = _usable(inputs.ranges_m, "a range")
    v = velocity_m_per_s(inputs.relative_permittivity)
    kind = options.get("delay_kind") or measured_delay_kind(options["ranges_from"])
    phantom, f = inputs.phantom, inputs.frequency_hz

    def grid():
        voxels, n = index_grid(phantom, f, CELL_SIZE_M, kind)
        return n, voxels.origin_m, voxels.spacing_m

    # one process per sweep worker already: the fields of a worker are solved in it, cached in memory
    fields = fields_for_sensors(grid_key(phantom, f, CELL_SIZE_M, kind), inputs.receivers_m[ok], grid, workers=1,
                                field="receivers")
    sigma = inputs.sigma_m[ok]
    sigma_s = sigma / v if np.all(np.isfinite(sigma) & (sigma > 0)) else None
    return locate("model_based", Measurements(fields=fields, delays_s=inputs.ranges_m[ok] / v, sigma_s=sigma_s,
                                              loss=options.get("loss"))).position_m


def _validate_model_based(options: dict, where: str) -> dict:
    options = _validate_ranges({"ranges_from", "delay_kind", "loss"})(options, where)
    try:
        measured_delay_kind(options["ranges_from"], f"{where}.ranges_from")
        if "delay_kind" in options:
            check_delay_kind(options["delay_kind"], f"{where}.delay_kind")
    except EstimatorInputError as exc:
        raise _fail(exc.reason, exc.field) from None
    return options


def _validate_ranges(allowed: set[str]):
    def validate(options: dict, where: str) -> dict:
        extra = sorted(set(options) - allowed)
        if extra:
            raise _fail(f"unknown option(s) {', '.join(extra)}; allowed: {', '.join(sorted(allowed))}",
                        f"{where}.{extra[0]}")
        if "ranges_from" not in options:
            raise _fail("required: the ranging method whose distances to use (e.g. toa_gcc)", f"{where}.ranges_from")
        if "loss" in options and options["loss"] not in _LOSSES:
            raise _fail(f"must be one of {', '.join(_LOSSES)}", f"{where}.loss")
        return options
    return validate


def _validate_rss(options: dict, where: str) -> dict:
    extra = sorted(set(options) - {"model"})
    if extra:
        raise _fail(f"unknown option(s) {', '.join(extra)}; allowed: model", f"{where}.{extra[0]}")
    rss_model(options.get("model", "cm2_deep_tissue"), f"{where}.model")
    return options


#: The built-in localizers as (name, fn, validate, description); sweeps.localization registers them
#: when its registry is first read (this module does not import it: no cycle).
BUILTINS = (
    ("linear", _ranges("linear"), _validate_ranges({"ranges_from"}), "closed-form least squares on the ranges"),
    ("nonlinear", _ranges("nonlinear"), _validate_ranges({"ranges_from", "loss"}),
     "weighted nonlinear least squares on the ranges"),
    ("rss", _rss, _validate_rss, "path losses through a path-loss model, multilaterated"),
    ("model_based", _model_based, _validate_model_based,
     "the ranging's delays on travel-time fields through the phantom, built for the delays' kind "
     f"(delay_kind: {' | '.join(DELAY_KINDS)}; default the kind ranges_from measures)"),
)
