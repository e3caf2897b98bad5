"""Ranging requests -> estimators calls -> response dicts (no HTTP; shared with the CLI)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from raytrace.solver.budget import Budget
from service import costs
from service.admission import admit, lower_or_refuse
from service.errors import Unprocessable
from service.schemas.ranging import PdoaRequest, ProfileIn, RangingCommon, RssRequest, ToaRequest
from service.settings import Settings


def path_profile(profile: ProfileIn):
    """Build an ``estimators.profile.PathProfile`` from a request profile.

    Hand-made profiles default to gains without the propagation phase (the
    delay carries it); channel profiles say ``gains_include_delay_phase: true``
    with their carrier as ``reference_frequency_hz``, and the estimators
    remove it once (estimators.profile docstring). Per-frequency gains are used when every
    path lists the same distinct frequencies (in any order); otherwise they are ignored, like
    the other channel fields a profile may carry."""
    from estimators.profile import PathProfile

    delays = np.array([p.delay_s for p in profile.paths], float)
    gains = np.array([complex(p.gain.re, p.gain.im) for p in profile.paths])
    # a channel profile's group delays give the first-order dispersive model when it has no band
    # gains (estimators.profile); a hand-made profile may give them too (with its reference frequency)
    group = None
    if all(p.group_delay_s is not None for p in profile.paths):
        group = np.array([p.group_delay_s for p in profile.paths], float)
    band_f = band_g = None
    with_band = [sorted(p.band_gains, key=lambda b: b.frequency_hz) for p in profile.paths if p.band_gains]
    if with_band and len(with_band) == len(profile.paths):
        freqs = [tuple(b.frequency_hz for b in bg) for bg in with_band]
        distinct = len(set(freqs[0])) == len(freqs[0])
        if distinct and all(f == freqs[0] for f in freqs):
            band_f = np.array(freqs[0], float)
            band_g = np.array([[complex(b.gain.re, b.gain.im) for b in bg] for bg in with_band])
    return PathProfile(
        delays_s=delays,
        gains=gains,
        band_frequencies_hz=band_f,
        band_gains=band_g,
        gains_include_delay_phase=profile.gains_include_delay_phase,
        reference_frequency_hz=profile.reference_frequency_hz,
        group_delays_s=group,
    )


def _link(req: RangingCommon) -> dict[str, Any] | None:
    """The request's link as the estimators take it; refuses a link next to an explicit snr_db."""
    if req.link is None:
        return None
    if "snr_db" in req.model_fields_set:
        raise Unprocessable("give snr_db or link, not both (the link budget sets the SNR)", loc=["body", "link"])
    return req.link.model_dump()


def _check_trials(req: RangingCommon, settings: Settings) -> None:
    """A given ``trials`` over this server's limit is refused; the default is capped to it (the
    served schema says so: its default and maximum follow the setting)."""
    given = req.trials if "trials" in req.model_fields_set else None
    req.trials = lower_or_refuse(given, "max_trials", settings, ("trials",), default=req.trials)


def _stop(budget: Budget | None):
    """The estimators' stop protocol (``estimators._checks.Check``) over a request budget: the
    deadline, and a cancellation (the client went away) end the loops at their next chunk."""
    return None if budget is None else (lambda: budget.charge(0))


def _toa_waveform(req: ToaRequest) -> dict[str, Any]:
    waveform = req.waveform.model_dump(exclude_none=True)
    if waveform["kind"] == "gaussian_pulse":
        waveform.pop("duration_s", None)
    else:
        waveform.pop("bandwidth_hz", None)
    return waveform


def _check_toa_work(req: ToaRequest, profile, waveform: dict[str, Any], settings: Settings) -> None:
    """Refuse, before any work, a TOA request over ``max_ranging_samples`` (settings): the
    synthesis costs samples x paths, the Monte Carlo samples x trials (estimators.toa_samples),
    through the one rule (:func:`service.costs.toa`, :func:`service.admission.admit`)."""
    from estimators import toa_samples

    admit(costs.toa(toa_samples(profile, waveform), len(req.profile.paths), req.trials, settings), settings)


def _num(x: Any) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _result(r: Any, **extra: Any) -> dict[str, Any]:
    out = {
        "method": str(getattr(r, "method", "")),
        "distance_m": float(r.distance_m),
        "delay_s": _num(getattr(r, "delay_s", None)),
        "std_m": float(r.std_m),
        "error_m": _num(getattr(r, "error_m", None)),
        "rmse_m": _num(getattr(r, "rmse_m", None)),
        "crlb_m": _num(getattr(r, "crlb_m", None)),
        "trials": int(r.trials),
        "max_unambiguous_range_m": _num(getattr(r, "max_unambiguous_range_m", None)),
        "crlb_phase_difference_m": _num(getattr(r, "crlb_phase_difference_m", None)),
        "wrapped": getattr(r, "wrapped", None),
        "wrap_reason": getattr(r, "wrap_reason", None),
        "model": getattr(r, "model", None),
        "path_loss_db": _num(getattr(r, "path_loss_db", None)),
        "median_distance_m": _num(getattr(r, "median_distance_m", None)),
        "snr_db": _num(getattr(r, "snr_db", None)),
        "channel_model": getattr(r, "channel_model", None),
        "band_coverage": _num(getattr(r, "band_coverage", None)),
    }
    out.update(extra)
    for key in ("distance_m", "std_m"):
        if not math.isfinite(out[key]):
            raise Unprocessable(
                f"the estimator produced a non-finite {key}; the profile or SNR leaves nothing to range on",
                loc=["body", "profile"],
            )
    return out


def toa(req: ToaRequest, settings: Settings, budget: Budget | None = None) -> dict[str, Any]:
    from estimators.toa import estimate_toa

    _check_trials(req, settings)
    waveform = _toa_waveform(req)
    profile = path_profile(req.profile)
    _check_toa_work(req, profile, waveform, settings)
    results = estimate_toa(
        profile,
        method=req.method,
        waveform=waveform,
        snr_db=req.snr_db,
        trials=req.trials,
        seed=req.seed,
        relative_permittivity=req.relative_permittivity,
        true_distance_m=req.true_distance_m,
        link=_link(req),
        check=_stop(budget),
    )
    return _response([_result(r) for r in results], "gcc" if req.method == "all" else req.method)


def _response(results: list[dict[str, Any]], primary: str | None) -> dict[str, Any]:
    if not results:
        raise Unprocessable("the estimator returned no result", loc=["body", "method"])
    top = next((r for r in results if r["method"] == primary), results[0])
    return {**top, "results": results}


def _tones(req: PdoaRequest) -> np.ndarray:
    """The request's distinct tones, increasing; two_tone measures between the lowest and the
    highest (as it does with a band's two ends)."""
    f = np.sort(np.asarray(req.frequencies_hz, float))
    return f[[0, -1]] if req.method == "two_tone" else f


def pdoa_cost(req: PdoaRequest, settings: Settings):
    """PDOA's cost: the profile's response at every tone, then every trial's noisy tones
    (:func:`service.costs.tones`); tones from the request, or at most the band limit (the profile's band)."""
    if req.frequencies_hz is not None:
        n, loc = len(req.frequencies_hz), ("frequencies_hz",)
    elif req.band is not None:
        n, loc = req.band.points, ("band", "points")
    else:
        n, loc = settings.max_band_points, ("profile",)
    return costs.tones(len(req.profile.paths), n, req.trials, settings, loc)


def pdoa(req: PdoaRequest, settings: Settings, budget: Budget | None = None) -> dict[str, Any]:
    from estimators.pdoa import estimate_pdoa

    _check_trials(req, settings)
    if req.band is not None and req.band.points > settings.max_band_points:
        raise Unprocessable(f"{req.band.points} exceeds this server's limit of {settings.max_band_points}",
                            loc=["body", "band", "points"])
    if req.frequencies_hz is not None and len(req.frequencies_hz) > settings.max_band_points:
        raise Unprocessable(f"{len(req.frequencies_hz)} tones exceed this server's limit of {settings.max_band_points}",
                            loc=["body", "frequencies_hz"])
    admit(pdoa_cost(req, settings), settings)
    result = estimate_pdoa(
        path_profile(req.profile),
        frequencies_hz=None if req.frequencies_hz is None else _tones(req),
        band=None if req.band is None else req.band.model_dump(),
        method=req.method,
        snr_db=req.snr_db,
        trials=req.trials,
        seed=req.seed,
        duration_s=req.duration_s,
        relative_permittivity=req.relative_permittivity,
        true_distance_m=req.true_distance_m,
        link=_link(req),
        check=_stop(budget),
    )
    return _response([_result(result)], req.method)


def rss(req: RssRequest, settings: Settings, budget: Budget | None = None) -> dict[str, Any]:
    from estimators.rss import estimate_rss

    _check_trials(req, settings)
    admit(costs.tones(0 if req.profile is None else len(req.profile.paths), 1, req.trials, settings, ("trials",)),
          settings)
    result = estimate_rss(
        None if req.profile is None else path_profile(req.profile),
        rss_dbm=req.rss_dbm,
        transmit_power_dbm=req.transmit_power_dbm,
        model=req.model,
        trials=req.trials,
        seed=req.seed,
        true_distance_m=req.true_distance_m,
        shadowing=req.shadowing,
        check=_stop(budget),
    )
    return _response([_result(result)], None)
