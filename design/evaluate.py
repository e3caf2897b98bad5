"""End-to-end check of layouts along the tract: trace, range, model-based fix (docs/design.md,
"What the numbers mean").

For every capsule position one trace to the sensors of every layout together (a receiver's paths
do not depend on the other receivers, :mod:`design.coverage`), then per layout the pipeline of
:func:`evaluation.localization.evaluate_localization` with the model-based method: per usable
sensor a seeded Monte Carlo TOA (GCC) run at the link's SNR, and per trial the model-based fix on
travel-time fields of the layout's sensors (:func:`estimators.localization.model_based_fix`,
soft_l1). A sensor is usable at a position under the layout criterion's rule (a path, a direct one
when required, the SNR at least ``min_snr_db``); fewer than four usable sensors give no fix there.
The noise of sensor k at position p is drawn from ``SeedSequence(seed, spawn_key=(p, k))``, k its
index among all the layouts' sensors, so a sensor two layouts share sees the same noise.

Per position: the RMS 3-D error over the trials, and the bound with the sensors' own fields
(travel_time_crlb at the true position: what ``crlb_m`` of the evaluation endpoints is).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from estimators.constants import DEFAULT_RELATIVE_PERMITTIVITY, velocity_m_per_s
from estimators.errors import EstimatorInputError
from estimators.link import LinkBudget
from estimators.localization import TravelTimeFields, model_based_fix, rss_fix, rss_position_crlb, travel_time_crlb
from estimators.profile import PathProfile
from estimators.rss import CM2_MODELS, PathLossModel
from estimators.toa import estimate_toa
from evaluation.fields import sensor_fields
from raytrace import Antenna, ChannelSpec, trace_channel
from raytrace.body.phantom import Phantom

#: Estimators' lowest per-sample SNR [dB]: links below cannot be ranged.
SNR_FLOOR_DB = -50.0
SIGMA_FLOOR_S = 1e-18


def evaluate_layouts(phantom: Phantom, positions_m: np.ndarray, layouts: dict[str, np.ndarray], *, coverage: dict,
                     snr_db: float | None, min_snr_db: float | None, require_direct_path: bool, trials: int = 20,
                     seed: int = 0, rays: int = 100_000, max_interactions: int = 6, ranging: str = "toa",
                     rss_model: str = "cm2_deep_tissue",
                     check: Callable[[int], None] | None = None) -> dict[str, dict]:
    """Per layout name: ``rmse_m`` (P,) (NaN where no fix), ``bound_m`` (P,) (inf where fewer than 4
    usable sensors), ``usable`` (P,) counts, ``errors_m`` (P, trials). ``coverage`` is the coverage's
    spec (frequency, waveform, link, channel polarization, cell size)."""
    from design.coverage import noise_bandwidth_hz, waveform_of

    f = coverage["frequency_hz"]
    waveform = waveform_of(coverage)
    link = LinkBudget(**coverage["link"])
    noise_dbm = link.noise_power_dbm(noise_bandwidth_hz(coverage))
    names = list(layouts)
    points: list[np.ndarray] = []
    index: dict[tuple, int] = {}
    for name in names:
        for p in np.asarray(layouts[name], float):
            key = tuple(np.round(p, 12))
            if key not in index:
                index[key] = len(points)
                points.append(p)
    union = np.asarray(points)
    members = {name: [index[tuple(np.round(p, 12))] for p in np.asarray(layouts[name], float)] for name in names}
    if ranging == "rss":
        return _evaluate_rss(phantom, positions_m, union, members, coverage=coverage, snr_db=snr_db,
                             min_snr_db=min_snr_db, require_direct_path=require_direct_path, trials=trials, seed=seed,
                             rays=rays, max_interactions=max_interactions, model=CM2_MODELS[rss_model], check=check)
    fields = {name: sensor_fields(phantom, union[members[name]], f, coverage["cell_size_m"], delay_kind="phase")  # GCC
              for name in names}
    v = velocity_m_per_s(DEFAULT_RELATIVE_PERMITTIVITY)
    out = _empty_results(names, len(positions_m), trials)
    for p, x in enumerate(np.asarray(positions_m, float)):
        if check is not None:
            check(p)
        result = _trace_at(phantom, x, union, coverage, rays, max_interactions)
        ranges: dict[int, tuple[np.ndarray, float]] = {}
        for k, prof in enumerate(result.profiles):
            if not _usable(prof, require_direct_path, snr_db, min_snr_db, link, noise_dbm):
                continue
            snr = snr_db if snr_db is not None else link.transmit_power_dbm + prof.path_gain_db - noise_dbm
            profile = PathProfile.from_traced(prof.paths, f)
            rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(p, k)))
            r = estimate_toa(profile, method="gcc", waveform=waveform, snr_db=snr, trials=trials, seed=rng,
                             return_estimates=True)[0]
            ranges[k] = (np.asarray(r.estimates_m, float), max(float(r.crlb_m or 0.0) / v, SIGMA_FLOOR_S))
        for name in names:
            rows = [j for j, k in enumerate(members[name]) if k in ranges]
            out[name]["usable"][p] = len(rows)
            if len(rows) < 4:
                continue
            ff = TravelTimeFields([fields[name].fields[j] for j in rows])
            delays = np.stack([ranges[members[name][j]][0] for j in rows], axis=1) / v
            sigma = np.array([ranges[members[name][j]][1] for j in rows])
            _, grad = ff.evaluate(x)
            try:
                out[name]["bound_m"][p] = travel_time_crlb(grad, sigma).rms_m
            except EstimatorInputError:
                pass
            for t in range(trials):
                try:
                    fix = model_based_fix(ff, delays[t], sigma)
                except EstimatorInputError:
                    continue
                out[name]["errors_m"][p, t] = float(np.linalg.norm(fix.position_m - x))
            _rmse(out[name], p)
    return out


def _empty_results(names: list[str], positions: int, trials: int) -> dict[str, dict]:
    """Per layout: RMSE and bound per position (NaN / inf until known), usable sensors, each trial's error."""
    return {name: {"rmse_m": np.full(positions, np.nan), "bound_m": np.full(positions, np.inf),
                   "usable": np.zeros(positions, int), "errors_m": np.full((positions, trials), np.nan)}
            for name in names}


def _trace_at(phantom: Phantom, x: np.ndarray, union: np.ndarray, coverage: dict, rays: int, max_interactions: int):
    """One trace from the capsule at ``x`` to every sensor of every layout (the coverage's channel knobs)."""
    spec = ChannelSpec(Antenna(position_m=x, polarization=coverage["channel"]["capsule_polarization"]),
                       tuple(Antenna(position_m=s, name=f"s{k}") for k, s in enumerate(union)),
                       phantom=phantom.name, frequency_hz=coverage["frequency_hz"], rays=rays,
                       max_interactions=max_interactions, near_field=coverage["channel"]["near_field"])
    return trace_channel(spec, phantom)


def _rmse(result: dict, p: int) -> None:
    """Position ``p``'s RMSE over the trials that gave a fix (NaN when none did)."""
    e = result["errors_m"][p]
    if np.isfinite(e).any():
        result["rmse_m"][p] = float(np.sqrt(np.nanmean(e**2)))


def _usable(prof, require_direct_path: bool, snr_db, min_snr_db, link: LinkBudget, noise_dbm: float) -> bool:
    if not prof.paths:
        return False
    if require_direct_path and not any(all(i.kind == "refraction" for i in q.interactions) for q in prof.paths):
        return False
    snr = snr_db if snr_db is not None else link.transmit_power_dbm + prof.path_gain_db - noise_dbm
    return not ((min_snr_db is not None and snr < min_snr_db) or snr < SNR_FLOOR_DB)


def _evaluate_rss(phantom: Phantom, positions_m, union: np.ndarray, members: dict[str, list[int]], *, coverage: dict,
                  snr_db, min_snr_db, require_direct_path: bool, trials: int, seed: int, rays: int,
                  max_interactions: int, model: PathLossModel, check) -> dict[str, dict]:
    """:func:`evaluate_layouts` with RSS: path loss -path_gain_db of the trace plus N(0, sigma_dB^2)
    shadowing per trial (seeded per position and sensor as the TOA noise is), the RSS fix."""
    from design.coverage import noise_bandwidth_hz

    link = LinkBudget(**coverage["link"])
    noise_dbm = link.noise_power_dbm(noise_bandwidth_hz(coverage))
    out = _empty_results(list(members), len(positions_m), trials)
    for p, x in enumerate(np.asarray(positions_m, float)):
        if check is not None:
            check(p)
        result = _trace_at(phantom, x, union, coverage, rays, max_interactions)
        losses: dict[int, np.ndarray] = {}
        for k, prof in enumerate(result.profiles):
            if _usable(prof, require_direct_path, snr_db, min_snr_db, link, noise_dbm):
                rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(p, k)))
                losses[k] = -prof.path_gain_db + rng.normal(0.0, model.shadowing_db, trials)
        for name, idx in members.items():
            rows = [k for k in idx if k in losses]
            out[name]["usable"][p] = len(rows)
            if len(rows) < 4:
                continue
            sensors = union[rows]
            out[name]["bound_m"][p] = rss_position_crlb(sensors, x, model.exponent, model.shadowing_db).rms_m
            for t in range(trials):
                try:
                    fix = rss_fix(sensors, [losses[k][t] for k in rows], model)
                except EstimatorInputError:
                    continue
                out[name]["errors_m"][p, t] = float(np.linalg.norm(fix.position_m - x))
            _rmse(out[name], p)
    return out
