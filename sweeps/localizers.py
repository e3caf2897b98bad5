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
    check_delay_kind,
    linear_fix,
    measured_delay_kind,
    model_based_fix,
    nonlinear_fix,
    rss_fix,
)
from sweeps.localization import LocalizationInputs, register

__all__: list[str] = []

_LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")


def _fail(reason: str, field: str):
    from sweeps.spec import SweepSpecError

    return SweepSpecError(reason, field=field)


def _usable(values: np.ndarray, what: str) -> np.ndarray:
    ok = np.isfinite(values)
    if ok.sum() < 4:
        raise EstimatorInputError(f"a 3-D fix needs at least 4 receivers with {what}, {int(ok.sum())} have one",
                                  "receivers")
    return ok


def _ranges(fix):
    def localize(inputs: LocalizationInputs, options: dict[str, Any]):
        ok = _usable(inputs.ranges_m, "a range")
        sigma = inputs.sigma_m[ok]
        weights = sigma if np.all(np.isfinite(sigma) & (sigma > 0)) else None
        kwargs = {"loss": options["loss"]} if "loss" in options else {}
        return fix(inputs.receivers_m[ok], inputs.ranges_m[ok], weights, **kwargs).position_m
    return localize


def _rss(inputs: LocalizationInputs, options: dict[str, Any]):
    from sweeps.spec import rss_model

    ok = _usable(inputs.path_loss_db, "a path")
    return rss_fix(inputs.receivers_m[ok], inputs.path_loss_db[ok],
                   model=rss_model(options.get("model", "cm2_deep_tissue"), "model")).position_m


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
    kwargs = {"loss": options["loss"]} if "loss" in options else {}
    return model_based_fix(fields, inputs.ranges_m[ok] / v, sigma_s, **kwargs).position_m


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
    from sweeps.spec import rss_model

    extra = sorted(set(options) - {"model"})
    if extra:
        raise _fail(f"unknown option(s) {', '.join(extra)}; allowed: model", f"{where}.{extra[0]}")
    rss_model(options.get("model", "cm2_deep_tissue"), f"{where}.model")
    return options


register("linear", _ranges(linear_fix), validate=_validate_ranges({"ranges_from"}),
         description="closed-form least squares on the ranges")
register("nonlinear", _ranges(nonlinear_fix), validate=_validate_ranges({"ranges_from", "loss"}),
         description="weighted nonlinear least squares on the ranges")
register("rss", _rss, validate=_validate_rss, description="path losses through a path-loss model, multilaterated")
register("model_based", _model_based, validate=_validate_model_based,
         description="the ranging's delays on travel-time fields through the phantom, built for the delays' kind "
                     f"(delay_kind: {' | '.join(DELAY_KINDS)}; default the kind ranges_from measures)")
