"""The capsule journey on the default torso, tracked from RF fixes, from video, and from both
(docs/tracking.md, "Evaluation").

    evaluate_tracking(journey=JourneySpec(...), trackers=("rf", "video", "fused", "fused_pf"), ...)
        -> TrackingEvaluation

1. **Journey** (:func:`tracking.simulate_journey`) along the torso's ``gi_tract`` centreline.
2. **RF fixes.** The tract is cut into a grid every ``rf_grid_m`` (5 mm); the grid positions the
   journey visits are traced by the sweep engine (``sweeps.run_sweep``: every sensor site, TOA GCC
   at 402 MHz, 30 dB, ``rays`` rays, ``max_interactions``), in one sweep for the positions not yet
   cached; each position's mean ranges and spreads are kept in memory and, with ``cache_dir``, on
   disk (one JSON per grid position and settings). At step k, the delays of the nearest grid
   position, with Gaussian noise of the sweep's spread per sensor, go into the model-based fix
   (``estimators.localization.model_based_fix`` on the travel-time fields of
   ``evaluation.fields.sensor_fields``, 4 mm cells) -- the heterogeneity-aware fix of
   docs/localization.md -- and the fix is moved by the offset from that grid position to the
   capsule (at most half the grid, against a fix error of ~15 mm). Its covariance is the fix's
   own plus ``rf_model_sigma_m``^2 per axis: the model-based fix's measured RMS error on this
   torso (14.3 mm in 3-D over the six capsule sites, docs/localization.md, so 14.3 / sqrt 3 per
   axis), since the fix's own covariance holds only the receiver noise (hundredths of a mm).
3. **Visual motion.** ``visual_source="rendered"`` (the CLI's default): the capsule camera's frames
   rendered along the journey and every consecutive pair through the MI estimator with the
   fisheye's tilt (:func:`vision.odometry.pair_estimates`, 192 px, cached per pair with
   ``cache_dir``), declared per mucosa (:data:`RENDERED_DECLARED`) and gated
   (:data:`RENDERED_GATE`), both measured on the journey of seed 1 (docs/tracking.md).
   ``visual_source="model"`` (the function's default, what ``/v1/track/evaluate`` runs): the
   estimator's measured error model (docs/vision.md, Evaluation (b)): advance d (1 + e) with
   e ~ N(-1 %, 4 %) per pair plus 0.02 mm, roll + N(0, 0.05 deg); declared to the filters as
   sigma = 5 % |d| + 0.05 mm and 0.1 deg. Either way, pairs straddling a junction of the
   centreline (where the phantom's separate organs make the position jump: a scene cut for the
   camera) give no measurement.
4. **Trackers** (same prior: the journey's start +- 5 mm, at rest +- 3 mm/s): ``rf`` Kalman on RF
   fixes alone, ``video`` Kalman on visual motion alone (dead reckoning from the prior), ``fused``
   Kalman on both, ``fused_pf`` the particle filter on both.

RMSE along the tract (arc length) and in 3-D (the reported point against the capsule) per tracker,
plus the raw RF fixes' 3-D error and their projections' error along the tract.

``python -m evaluation.tracking`` prints the table of docs/tracking.md.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from estimators.constants import DEFAULT_RELATIVE_PERMITTIVITY, velocity_m_per_s
from estimators.errors import EstimatorInputError
from estimators.localization import model_based_fix
from estimators.localization.traveltime import TravelTimeFields
from evaluation.fields import DEFAULT_CELL_SIZE_M, sensor_fields
from tracking import (
    Journey,
    JourneySpec,
    Observation,
    RfFix,
    Track,
    TrackerConfig,
    TrackingInputError,
    VisualMotion,
    kalman_track,
    particle_track,
    rmse_3d_m,
    rmse_along_m,
    simulate_journey,
)

TRACKERS = ("rf", "video", "fused", "fused_pf")
#: The model-based fix's RMS 3-D error on the default torso (docs/localization.md), per axis [m].
RF_MODEL_SIGMA_M = 14.3e-3 / np.sqrt(3.0)
#: The MI estimator's measured advance error on rendered sequences (docs/vision.md (b)).
VISUAL_BIAS, VISUAL_REL_SIGMA, VISUAL_ABS_SIGMA_M, VISUAL_ROLL_SIGMA_DEG = -0.01, 0.04, 2e-5, 0.05
#: What the filters are told about the visual measurements.
DECLARED_REL, DECLARED_ABS_M, DECLARED_ROLL_DEG = 0.05, 5e-5, 0.1
#: Visual measurements: "rendered" (frames rendered along the journey, MI estimates) or "model"
#: (the measured error model above).
VISUAL_SOURCES = ("rendered", "model")
#: Rendered frames: what the filters are told, per kind of mucosa (relative, absolute [m], roll
#: [deg]), measured on rendered journeys of other seeds (docs/tracking.md, "Measurements").
RENDERED_DECLARED = {"small_intestine": (0.15, 1e-4, 0.5), "colon": (0.06, 3e-5, 0.08),
                     "stomach": (0.15, 1e-4, 0.5)}
#: Rendered frames: a pair whose advance is beyond this chi-square(1) quantile of the filter's
#: prediction is ignored (an outlier: the small bowel's periodic folds aliased, docs/tracking.md).
RENDERED_GATE = 0.9999
FREQUENCY_HZ = 402e6
#: Most grid positions traced by one evaluation (work bound).
MAX_RF_POSITIONS = 200

_MEMORY: dict[str, dict] = {}


@dataclass(frozen=True)
class TrackingEvaluation:
    journey: Journey
    tracks: dict[str, Track]
    rmse_along_m: dict[str, float]
    rmse_3d_m: dict[str, float]
    rf_fix_rmse_3d_m: float
    rf_projection_rmse_along_m: float
    visual_pairs: int
    rf_positions_traced: int
    settings: dict = field(default_factory=dict)
    elapsed_s: float = 0.0


def _settings_key(settings: dict) -> str:
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]


def rf_links(phantom, s_grid_m: Sequence[float], *, rays: int, max_interactions: int, trials: int, seed: int,
             cache_dir: str | Path | None = None, check: Callable[[], None] | None = None) -> list[dict]:
    """Per grid arc length: ``{"receivers": [...], "distance_m": [...], "std_m": [...]}`` (TOA GCC at
    eps_r 27.9; NaN where a receiver has no path), from the sweep engine, cached per position.
    ``check`` is called after every traced position (a budget's deadline, a disconnected client)."""
    from sweeps import load_spec, run_sweep

    settings = {"phantom": phantom.name, "rays": rays, "max_interactions": max_interactions, "trials": trials,
                "seed": seed, "frequency_hz": FREQUENCY_HZ}
    key = _settings_key(settings)
    disk = None if cache_dir is None else Path(cache_dir) / "rf" / key
    out: dict[float, dict] = {}
    missing = []
    for s in s_grid_m:
        name = f"{key}:{s:.6f}"
        if name in _MEMORY:
            out[s] = _MEMORY[name]
        elif disk is not None and (disk / f"s-{s:.6f}.json").exists():
            out[s] = _MEMORY[name] = json.loads((disk / f"s-{s:.6f}.json").read_text())
        else:
            missing.append(s)
    if missing:
        spec = load_spec({"phantom": phantom.name, "capsule_positions": [{"s_m": float(s)} for s in missing],
                          "frequencies_hz": [FREQUENCY_HZ],
                          "channel": {"rays": rays, "max_interactions": max_interactions},
                          "ranging": {"toa": {"methods": ["gcc"], "snr_db": 30.0}}, "trials": trials, "seed": seed,
                          "chunk_positions": 1})  # one position per task (the chunking never changes a number)
        progress = None if check is None else (lambda _state: check())
        with tempfile.TemporaryDirectory() as tmp:
            rows = run_sweep(spec, Path(tmp) / "sweep", phantom=phantom, workers=0,
                             on_progress=progress).results.to_pylist()
        for i, s in enumerate(missing):
            mine = sorted((r for r in rows if r["position_index"] == i), key=lambda r: r["receiver_index"])
            rec = {"receivers": [r["receiver"] for r in mine],
                   "distance_m": [np.nan if r["toa_gcc_distance_m"] is None else r["toa_gcc_distance_m"] for r in mine],
                   "std_m": [np.nan if r["toa_gcc_std_m"] is None else r["toa_gcc_std_m"] for r in mine]}
            out[s] = _MEMORY[f"{key}:{s:.6f}"] = rec
            if disk is not None:
                disk.mkdir(parents=True, exist_ok=True)
                (disk / f"s-{s:.6f}.json").write_text(json.dumps(rec, allow_nan=True))
    return [out[s] for s in s_grid_m]


def evaluate_tracking(journey: JourneySpec | None = None, trackers: Sequence[str] = TRACKERS, *, phantom=None,
                      rf_grid_m: float = 5e-3, rays: int = 20_000, max_interactions: int = 4, trials: int = 10,
                      cell_size_m: float = DEFAULT_CELL_SIZE_M, rf_model_sigma_m: float = RF_MODEL_SIGMA_M,
                      config: TrackerConfig | None = None, cache_dir: str | Path | None = None,
                      check: Callable[[], None] | None = None, visual_source: str = "model",
                      odometry=None) -> TrackingEvaluation:
    """The pipeline of the module docstring. ``check`` is called between stages (a budget's
    deadline or cancellation may raise there). Raises TrackingInputError naming the field."""
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
    phantom = phantom or default_torso()
    line = phantom.centrelines["gi_tract"]
    spec = journey or JourneySpec()
    truth = simulate_journey(line, spec)
    rng = np.random.default_rng(np.random.SeedSequence([spec.seed, 24]))

    need_rf = any(t != "video" for t in trackers)
    fixes: list[RfFix | None] = [None] * spec.steps
    grid_idx = np.rint(truth.s_m / rf_grid_m).astype(int)
    grid_s = np.minimum(grid_idx * rf_grid_m, line.length_m)
    traced = 0
    if need_rf:
        unique = sorted(set(grid_s.tolist()))
        if len(unique) > MAX_RF_POSITIONS:
            raise TrackingInputError(f"the journey visits {len(unique)} RF grid positions, at most "
                                     f"{MAX_RF_POSITIONS}; shorten it or widen rf_grid_m", "journey.steps")
        links = dict(zip(unique, rf_links(phantom, unique, rays=rays, max_interactions=max_interactions,
                                          trials=trials, seed=spec.seed, cache_dir=cache_dir, check=check)))
        traced = len(unique)
        check()
        names = links[unique[0]]["receivers"]
        sensors = np.array([phantom.sites[n].position_m for n in names])
        all_fields = sensor_fields(phantom, sensors, FREQUENCY_HZ, cell_size_m)
        subsets: dict[tuple, TravelTimeFields] = {}
        v = velocity_m_per_s(DEFAULT_RELATIVE_PERMITTIVITY)
        for k in range(spec.steps):
            if k % 50 == 0:
                check()
            rec = links[float(grid_s[k])]
            d = np.asarray(rec["distance_m"], float)
            sd = np.asarray(rec["std_m"], float)
            ok = np.isfinite(d) & np.isfinite(sd)
            if ok.sum() < 4:
                continue
            key = tuple(np.flatnonzero(ok))
            if key not in subsets:
                subsets[key] = TravelTimeFields([all_fields.fields[i] for i in key])
            noisy = d[ok] + rng.standard_normal(ok.sum()) * sd[ok]
            try:
                fix = model_based_fix(subsets[key], noisy / v, np.maximum(sd[ok], 1e-6) / v)
            except EstimatorInputError:
                continue
            offset = truth.position_m[k] - line.point_m(float(grid_s[k]))
            fixes[k] = RfFix(fix.position_m + offset,
                             fix.covariance_m2 + rf_model_sigma_m ** 2 * np.eye(3))

    if visual_source == "rendered":
        visual = rendered_visual(phantom, truth, odometry, cache_dir, check)
    else:
        visual = model_visual(truth, np.asarray(line.junctions_s_m), rng)
    check()

    cfg = config or TrackerConfig(initial_s_m=float(truth.s_m[0]), initial_s_sigma_m=5e-3,
                                  visual_gate_probability=RENDERED_GATE if visual_source == "rendered" else None)
    uses = {"rf": (True, False), "video": (False, True), "fused": (True, True), "fused_pf": (True, True)}
    tracks: dict[str, Track] = {}
    for name in trackers:
        use_rf, use_vis = uses[name]
        obs = [Observation(float(truth.t_s[k]), fixes[k] if use_rf else None, visual[k] if use_vis else None)
               for k in range(spec.steps)]
        tracker = particle_track if name == "fused_pf" else kalman_track
        tracks[name] = tracker(line, obs, cfg, name=name)
        check()
    have = np.array([f is not None for f in fixes])
    if have.any():
        p = np.array([f.position_m for f in fixes if f is not None])
        fix_rmse = float(np.sqrt(np.mean(np.sum((p - truth.position_m[have]) ** 2, axis=1))))
        proj_rmse = float(np.sqrt(np.mean((np.asarray(line.project(p)) - truth.s_m[have]) ** 2)))
    else:
        fix_rmse = proj_rmse = float("nan")
    return TrackingEvaluation(
        journey=truth, tracks=tracks,
        rmse_along_m={n: rmse_along_m(t, truth.s_m) for n, t in tracks.items()},
        rmse_3d_m={n: rmse_3d_m(t, truth.position_m) for n, t in tracks.items()},
        rf_fix_rmse_3d_m=fix_rmse, rf_projection_rmse_along_m=proj_rmse,
        visual_pairs=sum(v is not None for v in visual), rf_positions_traced=traced,
        settings={"rf_grid_m": rf_grid_m, "rays": rays, "max_interactions": max_interactions, "trials": trials,
                  "cell_size_m": cell_size_m, "rf_model_sigma_m": rf_model_sigma_m, "rf_fixes": int(have.sum()),
                  "visual": "measured error model (docs/vision.md)" if visual_source == "model" else
                  "rendered frames, MI estimates"},
        elapsed_s=time.perf_counter() - t0)


def model_visual(truth: Journey, junctions: np.ndarray, rng: np.random.Generator) -> list[VisualMotion | None]:
    """Visual motion drawn from the MI estimator's measured error model (module doc, 3)."""
    visual: list[VisualMotion | None] = [None] * len(truth.s_m)
    for k in range(1, len(truth.s_m)):
        lo, hi = sorted((truth.s_m[k - 1], truth.s_m[k]))
        if np.any((junctions > lo) & (junctions <= hi)):
            continue  # a scene cut
        d = truth.s_m[k] - truth.s_m[k - 1]
        d_hat = d * (1.0 + VISUAL_BIAS + VISUAL_REL_SIGMA * rng.standard_normal()) \
            + VISUAL_ABS_SIGMA_M * rng.standard_normal()
        r_hat = truth.roll_deg[k] - truth.roll_deg[k - 1] + VISUAL_ROLL_SIGMA_DEG * rng.standard_normal()
        visual[k] = VisualMotion(float(d_hat), DECLARED_REL * abs(float(d_hat)) + DECLARED_ABS_M,
                                 float(r_hat), DECLARED_ROLL_DEG)
    return visual


def rendered_visual(phantom, truth: Journey, odometry=None, cache_dir: str | Path | None = None,
                    check: Callable[[], None] | None = None) -> list[VisualMotion | None]:
    """Visual motion from frames rendered along the journey and the MI estimator
    (:func:`vision.odometry.pair_estimates`); declared sigmas per kind of mucosa
    (:data:`RENDERED_DECLARED`); a pair without an advance (scale outside what advances give) or at
    a scene cut gives none."""
    from vision.odometry import OdometrySettings, pair_estimates

    pairs = pair_estimates(phantom, truth.s_m, truth.roll_deg, odometry or OdometrySettings(),
                           cache_dir=cache_dir, check=check)
    out: list[VisualMotion | None] = [None] * len(pairs)
    for k, p in enumerate(pairs):
        if p is None or not np.isfinite(p.advance_m):
            continue
        kind = "colon" if "colon" in p.organ else p.organ
        rel, abs_m, roll_sd = RENDERED_DECLARED.get(kind, RENDERED_DECLARED["small_intestine"])
        out[k] = VisualMotion(float(p.advance_m), rel * abs(float(p.advance_m)) + abs_m, float(p.rotation_deg),
                              roll_sd)
    return out


def markdown_table(ev: TrackingEvaluation) -> str:
    mm = 1e3
    labels = {"rf": "RF only (Kalman)", "video": "video only (Kalman)", "fused": "RF + video (Kalman)",
              "fused_pf": "RF + video (particle filter)"}
    out = ["| tracker | RMSE along the tract [mm] | RMSE in 3-D [mm] |", "|---|---|---|"]
    for name in ev.tracks:
        out.append(f"| {labels[name]} | {ev.rmse_along_m[name] * mm:.1f} | {ev.rmse_3d_m[name] * mm:.1f} |")
    out.append(f"| raw RF fixes (model-based), projected | {ev.rf_projection_rmse_along_m * mm:.1f} | "
               f"{ev.rf_fix_rmse_3d_m * mm:.1f} |")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="docs/tracking.md's table: the default torso journey tracked by RF, "
                                             "video and both.")
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rays", type=int, default=20_000)
    ap.add_argument("--cache-dir", default=None, help="keep the traced RF positions (and the rendered frame pairs' "
                                                      "estimates) here between runs")
    ap.add_argument("--visual", choices=VISUAL_SOURCES, default="rendered",
                    help="visual motion from frames rendered along the journey (default) or the error model")
    args = ap.parse_args(argv)
    ev = evaluate_tracking(JourneySpec(steps=args.steps, seed=args.seed), rays=args.rays, cache_dir=args.cache_dir,
                           visual_source=args.visual)
    print(markdown_table(ev))
    j = ev.journey
    print(f"\njourney: {args.steps} steps of {j.spec.dt_s} s, s {j.s_m.min():.3f}..{j.s_m.max():.3f} m through "
          f"{', '.join(dict.fromkeys(j.organ))}; {ev.rf_positions_traced} RF grid positions traced, "
          f"{ev.settings['rf_fixes']} fixes, {ev.visual_pairs} visual pairs; {ev.elapsed_s:.0f} s")


if __name__ == "__main__":
    main()
