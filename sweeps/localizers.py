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
============  ==============================================================  ===============

Each uses the receivers that have a value (a range from ``ranges_from``'s method, or a traced
path loss); the range weights are the method's spread over trials (``<method>_std_m``) when every
one is positive, else none. Fewer than 4 usable receivers: no estimate, and the row's ``note``
says why.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.errors import EstimatorInputError
from estimators.localization import linear_fix, nonlinear_fix, rss_fix
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
