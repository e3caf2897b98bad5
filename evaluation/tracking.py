"""The capsule journey on the default torso, tracked from RF fixes, from video, and from both
(docs/tracking.md, "Evaluation").

    evaluate_tracking(journey=JourneySpec(...), trackers=("rf", "video", "fused", "fused_pf"), runs=1, ...)
        -> TrackingEvaluation

1. **Journey** (:func:`tracking.simulate_journey`) along the torso's ``gi_tract`` centreline.
2. **RF fixes.** The tract is cut into a grid every ``rf_grid_m`` (5 mm); the grid positions around
   the journey's are traced by the sweep engine (every sensor site, TOA GCC at 402 MHz, 30 dB,
   ``rays`` rays, ``max_interactions`` (6: the first arrivals need 5-7 refractions,
   docs/localization.md "Delay kinds")), cached per position in memory and with ``cache_dir`` on
   disk (:func:`evaluation.error_models.rf_links`). At step k the GCC delays are interpolated
   linearly in s between the two grid positions around the capsule and go through the model-based
   fix on phase-index fields (GCC measures the carrier-phase delay): the fix's error varies
   continuously along the tract, as the body's bias does. Each run adds a draw of the delays' noise
   (linearised: the fix's own receiver-noise covariance). The fix is then **calibrated with the
   measured RF error model** (:func:`evaluation.error_models.rf_error_model`, measured on the same
   torso at positions between these grid points): the mean error of the organ it projects into is
   subtracted, that organ's measured covariance is declared as the fix's correlated bias and the
   receiver noise as its white part.
3. **Visual motion.** ``visual_source="rendered"``: the capsule camera's frames rendered along the
   journey and every consecutive pair through the MI estimator (:func:`vision.odometry.pair_estimates`,
   192 px, the fisheye's tilt, cached per pair with ``cache_dir``). ``visual_source="model"`` (the
   default, what ``/v1/track/evaluate`` runs): the **measured visual error model**
   (:func:`evaluation.error_models.visual_error_model`, frames rendered on this torso along another
   journey): each pair's advance and roll errors are drawn from the calibration pairs of the same
   mucosa with the nearest true advances, outliers included. Either way the filters are told the
   advance corrected for the estimator's measured relative bias and the model's declared sigmas per
   mucosa, and pairs straddling a junction (a scene cut) give nothing.
4. **Trackers**, all with the speed range measured on a journey of the same parameters and another
   seed (:func:`speed_range_m_per_s`: advances outside it are dropped) and the same prior:
   s ~ N(truth + e0, 5 mm) at rest +- 3 mm/s, where e0 is drawn from that same N(0, 5 mm) (the prior
   is as good as it says, no better); the video's 0.9999 gate (fold-aliased pairs), gates that
   cannot starve (tracking.TrackerConfig). The RF fixes' error is mostly the body's bias, correlated
   along the tract, and each tracker takes it in the way that suits it: ``rf`` alone must follow the
   capsule with every fix and carries the bias as a smooth Gauss-Markov state with the measured
   correlation length (``rf_correlation_length_m``, 3.2 mm); the fused trackers know the motion from
   the video and use a fix only once per measured decorrelation length (``rf_min_spacing_m``, 15 mm),
   declared white with the organ's measured covariance (fixes closer than that carry little new
   information, and the bias's shape between them no longer matters).
   ``rf``: Kalman on RF fixes alone; ``video``: Kalman on visual motion alone (dead reckoning from
   the prior); ``fused``: Kalman on both; ``fused_pf``: the particle filter on both.
5. **Runs**: ``runs`` Monte Carlo runs of the same journey, each with its own prior draw, RF noise
   and (model source) visual errors; the RF traces are shared.

Per tracker: RMSE along the tract (arc length) and in 3-D (the reported point against the capsule),
pooled over runs and steps; and its consistency (tracking.average_band): the averaged NEES of s
(chi-square(1)), each run counted as one independent value (a run's error is its prior draw and the
body's bias along its path, which neither the runs nor the steps average away: the widest band),
the averaged NIS of the used RF fixes (chi-square(1) for the Kalman filter's projected fix, (3) for
the particle filter's 3-D fix) and of the used advances (chi-square(1)), each against its two-sided
95 % band. Plus the raw RF fixes' 3-D error.

``python -m evaluation.tracking`` prints the table of docs/tracking.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from evaluation.error_models import (
    RF_SETTINGS,
    RfErrorModel,
    RfFixer,
    VisualErrorModel,
    rf_error_model,
    rf_links,
    visual_error_model,
)
from evaluation.fields import DEFAULT_CELL_SIZE_M
from tracking import TRACKERS as FILTER_TRACKS
from tracking import (
    ConsistencyBand,
    Journey,
    JourneySpec,
    Observation,
    RfFix,
    Track,
    TrackerConfig,
    TrackingInputError,
    VisualMotion,
    average_band,
    simulate_journey,
)

#: The journey's trackers and the filter (tracking.TRACKERS) each runs.
FILTERS = {"rf": "kalman", "video": "kalman", "fused": "kalman", "fused_pf": "particle"}
TRACKERS = tuple(FILTERS)
#: Visual measurements: "rendered" (frames rendered along the journey, MI estimates) or "model"
#: (the measured error model of rendered frames on this phantom).
VISUAL_SOURCES = ("rendered", "model")
#: A pair whose advance is beyond this chi-square(1) quantile of the filter's prediction is ignored
#: (an outlier: the small bowel's periodic folds aliased, docs/tracking.md).
VISUAL_GATE = 0.9999
#: The prior of every tracker: its standard deviation in s [m] (and the spread its mean is drawn with).
PRIOR_SIGMA_M = 5e-3
#: Most grid positions traced by one evaluation (work bound).
MAX_RF_POSITIONS = 200
#: Most Monte Carlo runs of one evaluation.
MAX_RUNS = 100
#: Particles of the fused particle filter in the evaluation.
PARTICLES = 2000


@dataclass(frozen=True)
class TrackingEvaluation:
    journey: Journey
    tracks: dict[str, Track]  # the first run's
    rmse_along_m: dict[str, float]
    rmse_3d_m: dict[str, float]
    rf_fix_rmse_3d_m: float
    rf_projection_rmse_along_m: float
    visual_pairs: int
    rf_positions_traced: int
    consistency: dict[str, dict[str, ConsistencyBand]] = field(default_factory=dict)
    cep90_3d_m: dict[str, float] = field(default_factory=dict)  # 90th percentile of the 3-D error, pooled
    runs: int = 1
    settings: dict = field(default_factory=dict)
    elapsed_s: float = 0.0


def _rf_fixes(line, truth: Journey, rf_grid_m: float, links: dict, fixer: RfFixer, model: RfErrorModel,
              check: Callable[[], None] = lambda: None) -> list[tuple | None]:
    """Per step (calibrated position, bias covariance, noise covariance) of the RF fix, or None
    (module docstring, 2). The delays at the capsule are interpolated linearly in s between the two
    grid positions around it, so the fix's error varies continuously along the tract, as the body's
    bias does."""
    out: list[tuple | None] = [None] * len(truth.s_m)
    for k, s in enumerate(truth.s_m):
        lo = min(np.floor(s / rf_grid_m) * rf_grid_m, line.length_m)
        hi = min(lo + rf_grid_m, line.length_m)
        a, b = links[round(float(lo), 9)], links[round(float(hi), 9)]
        f = 0.0 if hi <= lo else float((s - lo) / (hi - lo))
        rec = {"distance_m": (1 - f) * np.asarray(a["distance_m"], float) + f * np.asarray(b["distance_m"], float),
               "std_m": (1 - f) * np.asarray(a["std_m"], float) + f * np.asarray(b["std_m"], float)}
        check()
        got = fixer.fix(rec)
        if got is None:
            continue
        organ = line.organ_at(float(line.project(got[0])))
        p, bias = model.calibrated(organ, got[0])
        out[k] = (p, bias, got[1])
    return out


def _noisy(fixes: list[tuple | None], rng: np.random.Generator) -> list[RfFix | None]:
    """The run's RF fixes: each step's fix plus a draw of its receiver noise (its covariance's
    Cholesky factor times a standard normal: the linearised effect of the delays' noise)."""
    out: list[RfFix | None] = []
    for f in fixes:
        if f is None:
            out.append(None)
            continue
        p, bias, noise = f
        noise = 0.5 * (noise + noise.T) + 1e-18 * np.eye(3)
        out.append(RfFix(p + np.linalg.cholesky(noise) @ rng.standard_normal(3), noise, bias))
    return out


#: Margin on the speeds a journey of another seed reaches, for the trackers' speed range.
SPEED_MARGIN = 1.5


def speed_range_m_per_s(line, spec: JourneySpec) -> tuple[float, float]:
    """The speeds along the tract the capsule can have, measured on the journey model itself: the
    lowest and highest per-step speed of a journey with the same parameters and another seed
    (seed + 1), widened by :data:`SPEED_MARGIN` (for the defaults about -1.3 and 4 mm/s: peristalsis
    pulls the capsule back at up to 1.2 mm/s). A frame pair matched one fold period off reports
    -2 to -3 mm in half a second, a speed no journey has."""
    other = simulate_journey(line, JourneySpec(**{**spec.__dict__, "seed": spec.seed + 1}))
    v = np.diff(other.s_m) / spec.dt_s
    return (SPEED_MARGIN * min(float(v.min()), 0.0), SPEED_MARGIN * max(float(v.max()), 0.0))


def _visual(truth: Journey, junctions: np.ndarray, model: VisualErrorModel, rng: np.random.Generator,
            rendered: list | None) -> list[VisualMotion | None]:
    """Per step the visual motion from the previous one (module docstring, 3), declared by the model."""
    out: list[VisualMotion | None] = [None] * len(truth.s_m)
    for k in range(1, len(truth.s_m)):
        lo, hi = sorted((truth.s_m[k - 1], truth.s_m[k]))
        if np.any((junctions > lo) & (junctions <= hi)):
            continue  # a scene cut
        organ = truth.organ[k]
        if rendered is not None:
            p = rendered[k]
            if p is None or not np.isfinite(p.advance_m):
                continue
            d_hat, r_hat = float(p.advance_m), float(p.rotation_deg)
        else:
            d = float(truth.s_m[k] - truth.s_m[k - 1])
            e, re = model.draw(organ, d, rng)
            d_hat, r_hat = d + e, float(truth.roll_deg[k] - truth.roll_deg[k - 1]) + re
        corrected, sigma, roll_sigma = model.declared(organ, d_hat)
        out[k] = VisualMotion(corrected, sigma, r_hat, roll_sigma)
    return out


def evaluate_tracking(journey: JourneySpec | None = None, trackers: Sequence[str] = TRACKERS, *, phantom=None,
                      rf_grid_m: float = 5e-3, rays: int = RF_SETTINGS["rays"],
                      max_interactions: int = RF_SETTINGS["max_interactions"], trials: int = RF_SETTINGS["trials"],
                      cell_size_m: float = DEFAULT_CELL_SIZE_M, runs: int = 1, config: TrackerConfig | None = None,
                      cache_dir: str | Path | None = None, check: Callable[[], None] | None = None,
                      visual_source: str = "model", odometry=None, rf_model: RfErrorModel | None = None,
                      visual_model: VisualErrorModel | None = None,
                      field_cache_dir: str | Path | None = None) -> TrackingEvaluation:
    """The pipeline of the module docstring. ``check`` is called between stages (a budget's
    deadline or cancellation may raise there). ``rf_model`` / ``visual_model``: the measured models
    (default: the phantom's committed ones); a test may hand mis-set ones to see the consistency
    checks fail. Raises TrackingInputError naming the field."""
    from raytrace.body.torso import default_torso

    t0 = time.perf_counter()
    check = check or (lambda: None)
    trackers = tuple(trackers)
    for i, name in enumerate(trackers):
        if name not in TRACKERS:
            raise TrackingInputError(f"unknown tracker {name!r}; one of {', '.join(TRACKERS)}", f"trackers[{i}]")
    if not trackers:
        raise TrackingInputError("give at least one tracker", "trackers")
    if visual_source not in VISUAL_SOURCES:
        raise TrackingInputError(f"must be one of {', '.join(VISUAL_SOURCES)}, got {visual_source!r}",
                                 "visual_source")
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or not 1 <= runs <= MAX_RUNS:
        raise TrackingInputError(f"must be an integer in [1, {MAX_RUNS}], got {runs!r}", "runs")
    phantom = phantom or default_torso()
    line = phantom.centrelines["gi_tract"]
    spec = journey or JourneySpec()
    truth = simulate_journey(line, spec)
    need_rf = any(t != "video" for t in trackers)
    need_video = any(t != "rf" for t in trackers)
    rf_model = rf_model or rf_error_model(phantom.name)
    if need_video:
        visual_model = visual_model or visual_error_model(phantom.name)
    links: dict = {}
    fixer = None
    base = None
    if need_rf:
        lo = np.minimum(np.floor(truth.s_m / rf_grid_m) * rf_grid_m, line.length_m)
        hi = np.minimum(lo + rf_grid_m, line.length_m)
        unique = sorted({round(float(g), 9) for g in np.concatenate([lo, hi])})
        if len(unique) > MAX_RF_POSITIONS:
            raise TrackingInputError(f"the journey visits {len(unique)} RF grid positions, at most "
                                     f"{MAX_RF_POSITIONS}; shorten it or widen rf_grid_m", "journey.steps")
        links = dict(zip(unique, rf_links(phantom, unique, rays=rays, max_interactions=max_interactions,
                                          trials=trials, seed=RF_SETTINGS["seed"], cache_dir=cache_dir,
                                          check=check)))
        check()
        fixer = RfFixer(phantom, links[unique[0]]["receivers"], cell_size_m, field_cache_dir, check=check)
        base = _rf_fixes(line, truth, rf_grid_m, links, fixer, rf_model, check)
    rendered = None
    if need_video:
        if visual_source == "rendered":
            from vision.odometry import OdometrySettings, pair_estimates

            rendered = pair_estimates(phantom, truth.s_m, truth.roll_deg, odometry or OdometrySettings(),
                                      cache_dir=cache_dir, check=check)
    check()

    junctions = np.asarray(line.junctions_s_m)
    speeds = speed_range_m_per_s(line, spec)
    uses = {"rf": (True, False), "video": (False, True), "fused": (True, True), "fused_pf": (True, True)}
    errors = {n: {"along": [], "3d": []} for n in trackers}
    series = {n: {"nees": [], "nis_rf": [], "nis_visual": []} for n in trackers}
    dof_rf = {}
    tracks: dict[str, Track] = {}
    fix_err, proj_err, pairs = [], [], 0
    for run in range(runs):
        rng = np.random.default_rng(np.random.SeedSequence([spec.seed, 24, run]))
        fixes = _noisy(base, rng) if need_rf else [None] * spec.steps
        visual = (_visual(truth, junctions, visual_model, rng, rendered) if need_video
                  else [None] * spec.steps)
        s0 = float(np.clip(truth.s_m[0] + PRIOR_SIGMA_M * rng.standard_normal(), 0.0, line.length_m))
        cfg = config or TrackerConfig(initial_s_m=s0, initial_s_sigma_m=PRIOR_SIGMA_M, speed_range_m_per_s=speeds,
                                      visual_gate_probability=VISUAL_GATE, particles=PARTICLES,
                                      seed=int(rng.integers(2**31)))
        for name in trackers:
            use_rf, use_vis = uses[name]
            if config is None and use_rf:  # how each tracker takes the RF bias (module docstring, 4)
                cfg = (dataclasses.replace(cfg, rf_correlation_length_m=rf_model.correlation_length_m,
                                           rf_min_spacing_m=0.0) if name == "rf" else
                       dataclasses.replace(cfg, rf_correlation_length_m=None,
                                           rf_min_spacing_m=rf_model.decorrelation_m))
            obs = [Observation(float(truth.t_s[k]), fixes[k] if use_rf else None, visual[k] if use_vis else None)
                   for k in range(spec.steps)]
            track = FILTER_TRACKS[FILTERS[name]](line, obs, cfg, name=name)
            if run == 0:
                tracks[name] = track
            errors[name]["along"].append(track.s_m - truth.s_m)
            errors[name]["3d"].append(np.linalg.norm(track.position_m - truth.position_m, axis=1))
            var = track.extra["state_covariance"][:, 0, 0]
            series[name]["nees"].append((track.s_m - truth.s_m) ** 2 / np.maximum(var, 1e-30))
            series[name]["nis_rf"].append(track.extra["nis_rf"])
            series[name]["nis_visual"].append(track.extra["nis_visual"])
            dof_rf[name] = track.extra["nis_rf_dof"]
            check()
        have = [f is not None for f in fixes]
        if any(have):
            p = np.array([f.position_m for f in fixes if f is not None])
            fix_err.append(np.linalg.norm(p - truth.position_m[have], axis=1))
            proj_err.append(np.asarray(line.project(p)) - truth.s_m[have])
        pairs = sum(v is not None for v in visual)

    def rms(chunks) -> float:
        return float(np.sqrt(np.mean(np.concatenate(chunks) ** 2))) if chunks else float("nan")

    consistency = {}
    for name in trackers:
        use_rf, use_vis = uses[name]
        entry = {"nees": average_band(series[name]["nees"], 1, correlated="runs")}
        if use_rf:
            entry["nis_rf"] = average_band(series[name]["nis_rf"], dof_rf[name], correlated=False)
        if use_vis:
            entry["nis_visual"] = average_band(series[name]["nis_visual"], 1, correlated=False)
        consistency[name] = entry
    return TrackingEvaluation(
        journey=truth, tracks=tracks,
        rmse_along_m={n: rms(errors[n]["along"]) for n in trackers},
        rmse_3d_m={n: rms(errors[n]["3d"]) for n in trackers},
        cep90_3d_m={n: float(np.percentile(np.concatenate(errors[n]["3d"]), 90)) for n in trackers},
        rf_fix_rmse_3d_m=rms(fix_err), rf_projection_rmse_along_m=rms(proj_err),
        visual_pairs=pairs, rf_positions_traced=len(links), consistency=consistency, runs=int(runs),
        settings={"rf_grid_m": rf_grid_m, "rays": rays, "max_interactions": max_interactions, "trials": trials,
                  "cell_size_m": cell_size_m, "rf_correlation_length_m": rf_model.correlation_length_m,
                  "rf_min_spacing_m": rf_model.decorrelation_m,
                  "speed_range_m_per_s": speeds,
                  "rf_fixes_per_run": int(sum(len(e) for e in fix_err) / max(len(fix_err), 1)),
                  "visual": "measured error model of rendered frames (evaluation.error_models)"
                  if visual_source == "model" else "rendered frames, MI estimates"},
        elapsed_s=time.perf_counter() - t0)


LABELS = {"rf": "RF only (Kalman)", "video": "video only (Kalman)", "fused": "RF + video (Kalman)",
          "fused_pf": "RF + video (particle filter)"}


def markdown_table(ev: TrackingEvaluation) -> str:
    """RMSE along the tract and in 3-D per tracker, and its averaged NEES / NIS against their 95 % bands."""
    mm = 1e3

    def band(b: ConsistencyBand | None) -> str:
        if b is None or not b.samples:
            return ""
        return f"{b.average:.2f} [{b.lower:.2f}, {b.upper:.2f}]{'' if b.inside else ' **out**'}"

    out = ["| tracker | RMSE along the tract [mm] | RMSE in 3-D [mm] | NEES of s [95 % band] | NIS of RF fixes "
           "[band] | NIS of advances [band] |", "|---|---|---|---|---|---|"]
    for name in ev.rmse_3d_m:
        c = ev.consistency.get(name, {})
        out.append(f"| {LABELS[name]} | {ev.rmse_along_m[name] * mm:.1f} | {ev.rmse_3d_m[name] * mm:.1f} | "
                   f"{band(c.get('nees'))} | {band(c.get('nis_rf'))} | {band(c.get('nis_visual'))} |")
    out.append(f"| raw RF fixes (model-based, calibrated), projected | {ev.rf_projection_rmse_along_m * mm:.1f} | "
               f"{ev.rf_fix_rmse_3d_m * mm:.1f} | | | |")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="docs/tracking.md's table: the default torso journey tracked by RF, "
                                             "video and both.")
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--runs", type=int, default=20, help="Monte Carlo runs (prior draw, RF noise, visual errors)")
    ap.add_argument("--rays", type=int, default=RF_SETTINGS["rays"])
    ap.add_argument("--cache-dir", default=None, help="keep the traced RF positions (and the rendered frame pairs' "
                                                      "estimates) here between runs")
    ap.add_argument("--visual", choices=VISUAL_SOURCES, default="rendered",
                    help="visual motion from frames rendered along the journey (default) or the measured error model")
    args = ap.parse_args(argv)
    ev = evaluate_tracking(JourneySpec(steps=args.steps, seed=args.seed), rays=args.rays, cache_dir=args.cache_dir,
                           visual_source=args.visual, runs=args.runs)
    print(markdown_table(ev))
    j = ev.journey
    print(f"\njourney: {args.steps} steps of {j.spec.dt_s} s, seed {args.seed}, s {j.s_m.min():.3f}..{j.s_m.max():.3f} "
          f"m through {', '.join(dict.fromkeys(j.organ))}; {ev.rf_positions_traced} RF grid positions, "
          f"{ev.settings['rf_fixes_per_run']} fixes and {ev.visual_pairs} visual pairs per run, {ev.runs} runs, "
          f"visual: {args.visual}; {ev.elapsed_s:.0f} s")


if __name__ == "__main__":
    main()
