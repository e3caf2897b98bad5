"""End-to-end localization: capsule -> trace -> ranges -> position, with error statistics
beside the position bound (docs/localization.md, "End-to-end evaluation").

    evaluate_localization(phantom, capsule, sensors, ranging="gcc", methods=None, ...)
        -> LocalizationEvaluation

One trace from the capsule to every sensor (:func:`raytrace.solver.tracer.trace_channel`); per
sensor a Monte Carlo ranging run over its channel (TOA: ``gcc`` | ``first_peak`` |
``all_peaks`` | ``envelope``; ``pdoa``: multi-tone regression over a band; ``rss``: CM2
inversion with shadowing), seeded per sensor from ``seed``; trial t of every sensor forms
one measurement set, which every requested position method turns into a fix. Delays
become ranges with the constant velocity c / sqrt(relative_permittivity) for the
constant-velocity methods; ``joint_velocity`` and ``model_based`` use the delays
themselves, the model-based fix on travel-time fields of the delays' kind (``delay_kind``: by
default the kind the ranging measures, ``estimators.localization.measured_delay_kind``: group for
``envelope`` and ``pdoa``, phase for the carrier-phase TOA methods). Errors are 3-D distances
|x_hat - x|: mean, RMSE, CEP50 / CEP90 (the 50th / 90th percentiles of the 3-D error, i.e.
spherical error probable), beside the position CRLB at the true position for the same sensors
and per-range sigmas.

Regenerate the acceptance table of docs/localization.md with
``python -m evaluation.localization`` (``--help`` for options).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import raytrace as rt
from estimators.constants import DEFAULT_RELATIVE_PERMITTIVITY, velocity_m_per_s
from estimators.errors import EstimatorInputError
from estimators.localization import (
    METHODS,
    POSITION_METHODS,
    Measurements,
    check_delay_kind,
    joint_velocity_crlb,
    locate,
    measured_delay_kind,
    model_based_fix,
    position_method,
    range_crlb,
    rss_position_crlb,
    travel_time_crlb,
)
from estimators.localization.pathloss import path_loss_model
from estimators.pdoa import estimate_pdoa
from estimators.profile import PathProfile
from estimators.rss import estimate_rss
from estimators.toa import METHODS as TOA_METHODS
from estimators.toa import estimate_toa
from evaluation.fields import DEFAULT_CELL_SIZE_M, sensor_fields
from raytrace import Budget, Phantom

RANGING = (*TOA_METHODS, "pdoa", "rss")
#: The default methods of a delay ranging: every registered one that does not need path losses.
DELAY_METHODS = tuple(m for m in POSITION_METHODS if METHODS[m].measures != "path_loss_db")
#: PDOA band when none is given: the thesis' 400-420 MHz, 21 tones.
DEFAULT_PDOA_BAND = {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}
#: Floor of a per-range sigma used as a weight [m] (noiseless ranging reports 0).
SIGMA_FLOOR_M = 1e-6
MAX_TRIALS = 1000


@dataclass(frozen=True)
class MethodStatistics:
    """One position method over the trials. Errors in metres (module docstring).
    crlb_m: sqrt(trace) of the position CRLB at the true position; gdop / pdop there."""

    method: str
    mean_error_m: float
    rmse_m: float
    cep50_m: float
    cep90_m: float
    bias_m: np.ndarray
    crlb_m: float
    gdop: float
    pdop: float
    converged_fraction: float
    failures: int
    estimates_m: np.ndarray = field(repr=False)
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class LocalizationEvaluation:
    capsule_position_m: np.ndarray
    sensor_positions_m: np.ndarray
    sensor_names: tuple[str, ...]
    ranging: str
    frequency_hz: float
    snr_db: float | None
    trials: int
    seed: int
    relative_permittivity: float
    delays_s: np.ndarray | None  # (trials, sensors)
    ranges_m: np.ndarray  # (trials, sensors) at the constant velocity
    range_sigma_m: np.ndarray  # (sensors,)
    true_distances_m: np.ndarray
    methods: dict[str, MethodStatistics]
    trace_s: float
    cell_size_m: float | None
    delay_kind: str | None = None  # of the delays the model-based fix was given (None: no delays)


def _position(phantom: Phantom, value: Any, field_name: str) -> tuple[np.ndarray, str]:
    if isinstance(value, str):
        site = phantom.sites.get(value)
        if site is None:
            raise EstimatorInputError(f"unknown site {value!r} of phantom {phantom.name!r}", field_name)
        return np.asarray(site.position_m, float), value
    try:
        p = np.asarray(value, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise EstimatorInputError("must be a site name or three numbers (metres)", field_name) from None
    if not np.isfinite(p).all():
        raise EstimatorInputError(f"coordinates must be finite numbers, got {p.tolist()}", field_name)
    return p, ""


def _methods(methods, ranging: str) -> tuple[str, ...]:
    if methods is None:
        return ("rss",) if ranging == "rss" else DELAY_METHODS
    methods = tuple(methods)
    for i, m in enumerate(methods):
        measures = position_method(m, f"methods[{i}]").measures  # the registry (estimators.localization.methods)
        if ranging == "rss" and measures == "delays_s":
            raise EstimatorInputError(f"{m} needs delays; RSS ranging gives distances only", f"methods[{i}]")
        if ranging != "rss" and measures == "path_loss_db":
            raise EstimatorInputError(f"the {m} method needs ranging='rss'", f"methods[{i}]")
    if not methods:
        raise EstimatorInputError("give at least one method", "methods")
    return methods


def evaluate_localization(phantom: Phantom, capsule: Any, sensors: Sequence[Any], *, ranging: str = "gcc",
                          methods: Sequence[str] | None = None, frequency_hz: float = 402e6,
                          snr_db: float | None = 30.0, trials: int = 20, seed: int = 0,
                          relative_permittivity: float = DEFAULT_RELATIVE_PERMITTIVITY,
                          cell_size_m: float = DEFAULT_CELL_SIZE_M, rays: int = 100_000, max_interactions: int = 6,
                          waveform: Any = None, pdoa_band: dict | None = None, rss_model: Any = "cm2_deep_tissue",
                          loss: str = "soft_l1", near_field: bool = True, delay_kind: str | None = None,
                          budget: Budget | None = None, config: rt.TracerConfig | None = None,
                          field_cache_dir: str | Path | None = None) -> LocalizationEvaluation:
    """Run the pipeline of the module docstring.

    capsule: site name or position; sensors: site names and/or positions (>= 4; >= 5 for
    joint_velocity). ranging: a TOA method, ``pdoa`` or ``rss``. methods: subset of
    ``linear``, ``nonlinear``, ``joint_velocity``, ``model_based`` (delay ranging, default all
    four) or ``linear``, ``nonlinear``, ``rss`` (RSS ranging, default ``rss``). waveform: TOA
    waveform (default: the 402 MHz 25 ns burst); pdoa_band: ``{start_hz, stop_hz, points}``;
    rss_model: CM2 name or a (fitted) model. ``loss``: robust loss of the model-based fix.
    ``near_field``: the tracer's dipole near-field term on direct paths (ChannelSpec.near_field;
    its phase biases carrier-phase TOA at a few wavelengths, a physical effect).
    ``delay_kind``: ``group`` or ``phase``, the index of the model-based fields (module docstring);
    None: the kind the ranging measures. Setting the other kind shows what a mismatch costs.
    Raises EstimatorInputError (``capsule``, ``sensors[i]``, ``ranging``, ``methods[i]``,
    ``trials``...) or the tracer's InputError; ``budget`` bounds the trace and is checked
    between sensors' fields and between trials; ``config`` is the tracer's (threads, batches);
    ``field_cache_dir`` keeps the travel-time fields on disk (evaluation.fields.sensor_fields).
    """
    if ranging not in RANGING:
        raise EstimatorInputError(f"unknown ranging {ranging!r} ({' | '.join(RANGING)})", "ranging")
    chosen = _methods(methods, ranging)
    kind = None
    if ranging == "rss" and delay_kind is not None:
        raise EstimatorInputError("RSS ranging measures no delay: leave delay_kind out", "delay_kind")
    if ranging != "rss":
        kind = measured_delay_kind(ranging) if delay_kind is None else check_delay_kind(delay_kind)
    if isinstance(trials, bool) or not isinstance(trials, (int, np.integer)) or not 1 <= trials <= MAX_TRIALS:
        raise EstimatorInputError(f"must be an integer in [1, {MAX_TRIALS}], got {trials!r}", "trials")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise EstimatorInputError(f"must be a non-negative integer, got {seed!r}", "seed")
    x_true, _ = _position(phantom, capsule, "capsule")
    sens, names = [], []
    for i, s in enumerate(sensors):
        p, name = _position(phantom, s, f"sensors[{i}]")
        sens.append(p)
        names.append(name or f"sensor_{i}")
    sens = np.array(sens).reshape(-1, 3)
    if len(sens) < 4:
        raise EstimatorInputError(f"a 3-D fix needs at least 4 sensors, got {len(sens)}", "sensors")
    v = velocity_m_per_s(relative_permittivity)
    band = None
    if ranging == "pdoa":
        b = dict(DEFAULT_PDOA_BAND if pdoa_band is None else pdoa_band)
        band = rt.Band(float(b["start_hz"]), float(b["stop_hz"]), int(b["points"]))

    def check() -> None:
        if budget is not None:
            budget.charge(0)

    t0 = time.perf_counter()
    spec = rt.ChannelSpec(rt.Antenna(x_true, name="capsule"), tuple(rt.Antenna(p, name=n) for p, n in zip(sens, names)),
                          phantom=phantom.name, frequency_hz=frequency_hz, band=band, rays=rays,
                          max_interactions=max_interactions, near_field=near_field)
    result = rt.trace_channel(spec, phantom, budget=budget, config=config)
    trace_s = time.perf_counter() - t0
    true_d = np.linalg.norm(sens - x_true, axis=1)

    generators = [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(len(sens))]
    ranges = np.empty((trials, len(sens)))
    sigma = np.empty(len(sens))
    for j, prof in enumerate(result.profiles):
        check()
        if not prof.paths:
            raise EstimatorInputError("no propagation path reaches this sensor (geometric-optics shadow); "
                                      "move or drop it", f"sensors[{j}]")
        profile = PathProfile.from_traced(prof.paths, frequency_hz, None if band is None else band.frequencies_hz)
        if ranging == "pdoa":
            r = estimate_pdoa(profile, band=band.to_dict(),
                              method="regression", snr_db=snr_db, trials=trials, seed=generators[j],
                              relative_permittivity=relative_permittivity, return_estimates=True, check=check)
            bound = r.crlb_phase_difference_m
        elif ranging == "rss":
            r = estimate_rss(profile, model=path_loss_model(rss_model).name if isinstance(rss_model, str)
                             else "cm2_deep_tissue", trials=trials, seed=generators[j], shadowing=snr_db is not None,
                             return_estimates=True, check=check)
            bound = r.crlb_m
        else:
            r = estimate_toa(profile, method=ranging, waveform=waveform, snr_db=snr_db, trials=trials,
                             seed=generators[j], relative_permittivity=relative_permittivity,
                             return_estimates=True, check=check)[0]
            bound = r.crlb_m
        ranges[:, j] = r.estimates_m
        sigma[j] = max(bound if bound is not None else r.std_m, r.std_m if bound is None else 0.0, SIGMA_FLOOR_M)
    delays = None if ranging == "rss" else ranges / v
    sigma_s = sigma / v

    fields = None
    if "model_based" in chosen:
        fields = sensor_fields(phantom, sens, frequency_hz, cell_size_m, delay_kind=kind, check=check,
                               cache_dir=field_cache_dir)
    model = path_loss_model(rss_model) if ranging == "rss" else None

    stats = {}
    for m in chosen:
        est = np.full((trials, 3), np.nan)
        conv = np.zeros(trials, bool)
        extra: dict = {}
        velocities = []
        for t in range(trials):
            check()
            try:
                fix = locate(m, Measurements(
                    sensors_m=sens, ranges_m=ranges[t], sigma_m=sigma, sigma_s=sigma_s, fields=fields, model=model,
                    delays_s=None if delays is None else delays[t], loss=loss if METHODS[m].needs_fields else None,
                    path_loss_db=None if model is None else model.path_loss_db(ranges[t])))
                if fix.velocity_m_per_s is not None:
                    velocities.append(fix.velocity_m_per_s)
            except EstimatorInputError:
                continue
            est[t] = fix.position_m
            conv[t] = fix.converged
        # the bound at the true position for the same sensors and sigmas
        if m in ("linear", "nonlinear"):
            bound = range_crlb(sens, x_true, sigma) if ranging != "rss" else rss_position_crlb(
                sens, x_true, model.exponent, model.shadowing_db)
        elif m == "joint_velocity":
            v_eff = float(np.median(velocities)) if velocities else v
            extra["velocity_m_per_s"] = v_eff
            extra["relative_permittivity"] = float((299_792_458.0 / v_eff) ** 2)
            bound = joint_velocity_crlb(sens, x_true, v_eff, sigma_s)
        elif m == "model_based":
            _, grad = fields.evaluate(x_true)
            bound = travel_time_crlb(grad, sigma_s)
            extra["discretisation_error_s"] = fields.discretisation_error_s
            # the same fix from the exact first arrivals of the trace (of the fields' kind): the
            # model's own error (grid, first arrival vs traced path) without the ranging's
            # multipath and noise
            first = first_arrivals_s(result.profiles, kind)
            ideal = model_based_fix(fields, first, sigma_s, loss=loss)
            extra["first_path_error_m"] = float(np.linalg.norm(ideal.position_m - x_true))
        else:
            bound = rss_position_crlb(sens, x_true, model.exponent, model.shadowing_db)
        ok = np.isfinite(est).all(axis=1)
        err = np.linalg.norm(est[ok] - x_true, axis=1)
        nan = float("nan")
        stats[m] = MethodStatistics(
            method=m, mean_error_m=float(err.mean()) if len(err) else nan,
            rmse_m=float(np.sqrt(np.mean(err**2))) if len(err) else nan,
            cep50_m=float(np.percentile(err, 50)) if len(err) else nan,
            cep90_m=float(np.percentile(err, 90)) if len(err) else nan,
            bias_m=(est[ok] - x_true).mean(axis=0) if len(err) else np.full(3, nan),
            crlb_m=bound.rms_m, gdop=bound.gdop, pdop=bound.pdop, converged_fraction=float(conv.mean()),
            failures=int((~ok).sum()), estimates_m=est, extra=extra)
    return LocalizationEvaluation(
        capsule_position_m=x_true, sensor_positions_m=sens, sensor_names=tuple(names), ranging=ranging,
        frequency_hz=float(frequency_hz), snr_db=snr_db, trials=int(trials), seed=int(seed),
        relative_permittivity=float(relative_permittivity), delays_s=delays, ranges_m=ranges,
        range_sigma_m=sigma, true_distances_m=true_d, methods=stats, trace_s=trace_s,
        cell_size_m=float(cell_size_m) if fields is not None else None, delay_kind=kind)


def first_arrivals_s(profiles, delay_kind: str) -> np.ndarray:
    """Per receiver profile the earliest delay of its paths of ``delay_kind`` (``phase``: the
    paths' ``delay_s``, ``group``: their ``group_delay_s``); NaN where a receiver has no path."""
    attr = "group_delay_s" if check_delay_kind(delay_kind) == "group" else "delay_s"
    return np.array([min((getattr(p, attr) for p in prof.paths), default=np.nan) for prof in profiles])


# ----------------------------------------------------------------------- acceptance table
TABLE_METHODS = ("nonlinear", "joint_velocity", "model_based")


def acceptance_rows(*, cell_size_m: float = DEFAULT_CELL_SIZE_M, trials: int = 20, seed: int = 0,
                    ranging: str = "gcc", snr_db: float = 30.0, frequency_hz: float = 402e6,
                    rays: int = 100_000) -> list[LocalizationEvaluation]:
    """The default torso, its 6 capsule sites x 12 sensor sites, TOA at 402 MHz, 30 dB."""
    from raytrace.body.torso import BELT_SITES, UPPER_SITES, default_torso

    phantom = default_torso()
    capsules = [n for n, s in phantom.sites.items() if s.kind == "capsule"]
    sensors = [*BELT_SITES, *UPPER_SITES]
    return [evaluate_localization(phantom, c, sensors, ranging=ranging, methods=("linear", *TABLE_METHODS),
                                  frequency_hz=frequency_hz, snr_db=snr_db, trials=trials, seed=seed,
                                  cell_size_m=cell_size_m, rays=rays) for c in capsules]


def markdown_table(rows: Sequence[LocalizationEvaluation], names: Sequence[str]) -> str:
    """RMSE per method [mm] per capsule site, the model-based bound, and their ratios."""
    mm = 1e3
    head = ("| capsule site | constant velocity (NLS) | joint velocity | model-based | model-based CEP90 "
            "| model-based CRLB | model-based, first-path delays | const. / model-based |")
    out = [head, "|" + "---|" * 8]
    for name, r in zip(names, rows):
        c, j, m = (r.methods[k] for k in TABLE_METHODS)
        out.append(f"| {name} | {c.rmse_m * mm:.1f} | {j.rmse_m * mm:.1f} | {m.rmse_m * mm:.1f} | "
                   f"{m.cep90_m * mm:.1f} | {m.crlb_m * mm:.3f} | {m.extra['first_path_error_m'] * mm:.1f} | "
                   f"{c.rmse_m / m.rmse_m:.1f} |")
    allc = [np.sqrt(np.mean([r.methods[k].rmse_m ** 2 for r in rows])) for k in TABLE_METHODS]
    bound = np.sqrt(np.mean([r.methods["model_based"].crlb_m ** 2 for r in rows]))
    ideal = np.sqrt(np.mean([r.methods["model_based"].extra["first_path_error_m"] ** 2 for r in rows]))
    out.append(f"| **all sites (RMS)** | **{allc[0] * mm:.1f}** | **{allc[1] * mm:.1f}** | **{allc[2] * mm:.1f}** | "
               f"| {bound * mm:.3f} | {ideal * mm:.1f} | **{allc[0] / allc[2]:.1f}** |")
    return "\n".join(out)


def summary_table(rows: Sequence[LocalizationEvaluation]) -> str:
    """Per method, every trial of every capsule site pooled: mean 3-D error, RMSE, CEP50, CEP90 [mm],
    the position CRLB (RMS over the sites) and the ratio of the constant-velocity RMSE to the method's."""
    mm = 1e3
    out = ["| method | mean | RMSE | CEP50 | CEP90 | CRLB (RMS over sites) | RMSE / CRLB | const. RMSE / RMSE |",
           "|" + "---|" * 8]
    labels = {"nonlinear": "constant velocity (NLS, eps_r 27.9)", "joint_velocity": "joint velocity",
              "model_based": "model-based (travel-time fields)"}
    pooled = {}
    for k in TABLE_METHODS:
        err = np.concatenate([np.linalg.norm(r.methods[k].estimates_m - r.capsule_position_m, axis=1) for r in rows])
        pooled[k] = err[np.isfinite(err)]
    const = np.sqrt(np.mean(pooled["nonlinear"] ** 2))
    for k in TABLE_METHODS:
        e = pooled[k]
        rmse = np.sqrt(np.mean(e**2))
        bound = np.sqrt(np.mean([r.methods[k].crlb_m ** 2 for r in rows]))
        out.append(f"| {labels[k]} | {e.mean() * mm:.1f} | {rmse * mm:.1f} | {np.percentile(e, 50) * mm:.1f} | "
                   f"{np.percentile(e, 90) * mm:.1f} | {bound * mm:.3f} | {rmse / bound:.0f} | {const / rmse:.1f} |")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="Acceptance table of docs/localization.md: default torso, 6 capsule "
                                             "sites x 12 sensors, TOA at 402 MHz, 30 dB.")
    ap.add_argument("--cell-size-m", type=float, default=DEFAULT_CELL_SIZE_M)
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ranging", default="gcc", choices=RANGING[:-2])
    ap.add_argument("--snr-db", type=float, default=30.0)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows = acceptance_rows(cell_size_m=args.cell_size_m, trials=args.trials, seed=args.seed, ranging=args.ranging,
                           snr_db=args.snr_db)
    from raytrace.body.torso import default_torso

    names = [n for n, s in default_torso().sites.items() if s.kind == "capsule"]
    print(summary_table(rows))
    print()
    print(markdown_table(rows, names))
    lin = np.sqrt(np.mean([r.methods["linear"].rmse_m ** 2 for r in rows]))
    vel = [r.methods["joint_velocity"].extra["relative_permittivity"] for r in rows]
    print(f"\nlinear (closed form) RMS over sites {lin * 1e3:.1f} mm; joint-velocity effective eps_r "
          f"{min(vel):.1f} .. {max(vel):.1f}; ranging {args.ranging}, {args.trials} trials, seed {args.seed}, "
          f"cells {args.cell_size_m * 1e3:g} mm; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
