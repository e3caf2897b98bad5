"""The evidence tables re-measured on the built-in CT abdomen (``abdomen-ct``), beside the torso's
(README, docs/localization.md, docs/tracking.md, docs/vision.md: "On the CT abdomen").

    python -m evaluation.anatomy reach [--write]
    python -m evaluation.anatomy localization [--trials 20 --seed 0 --rays 20000] [--write | --min-gain-db -100]
    capsule-rt experiment abdomen-ct-path-loss --out runs/abd-pl
    python -m evaluation.anatomy path-loss --from runs/abd-pl [--write]
    python -m evaluation.anatomy video [--steps 40 --seed 0 --cache-dir DIR]

**Reach** (:func:`reach_rows`): one trace from every capsule site to every sensor site (:data:`REACH_SETTINGS`)
says which sensors answer and which the capsule reaches by a direct (refraction-only) path; ``--write``
commits it as ``evaluation/data/abdomen-ct_reach.json`` with the phantom's digest
(:func:`raytrace.body.indexgrid.phantom_digest`) and its sensors' positions. The issue's acceptance (every
site answered by every sensor, at least 8 of them direct) is checked on that table by
tests/raytrace/test_abdomen.py, which also re-traces a few sites and compares: the whole table is ~1 min of
CPU, too much for every test run.

**Localization** (:func:`localization_rows`): every capsule site of the phantom (the model's landmarks and
the midpoints of its regions along the journey) through :func:`evaluation.localization.evaluate_localization`
exactly as the torso's acceptance table (TOA by GCC at 402 MHz, 30 dB, 4 mm travel-time cells), each with
the sensors it reaches by a direct path (the reach table). A sensor that hears the capsule only through
reflections or not at all would range a path that is not the capsule's straight line to it; a receiver
array uses the sensors that hear the capsule, and the torso's sensors were placed so that each hears every
capsule directly. The traces use the reach table's 20 000 rays (the torso's table: 100 000) and 6
interactions: with 100 000 rays the direct-path search loses a sensor that 20 000 find
(small_intestine_JIJ -> b3_090: 2 paths at 20 000 rays, none at 100 000; reported, not fixed here).

**Path loss**: the experiment ``abdomen-ct-path-loss`` (sweeps/specs/abdomen-ct-path-loss-402mhz.yaml: the
capsule every 50 mm along the tract, every sensor, 402 MHz) fits the log-distance model and reports the
medians by distance (sweeps.experiments); ``path-loss --write`` commits its links (arc length, receiver,
distance, path gain) as ``evaluation/data/abdomen-ct_path_loss.json``, which tests refit with an independent
least-squares fit and compare with one position traced afresh.

**Video** (:func:`video_pairs`): the capsule journey of docs/tracking.md (2 frames per second, 1.5 mm/s
with stops and peristalsis, rolling) from each of :data:`SEGMENT_STARTS`, ten arc lengths spread over the tract
from the oesophagus to the rectum, ``steps`` frames each, rendered inside the real lumen and every consecutive
pair through the MI estimator (:func:`vision.odometry.pair_estimates`, 192 px, the fisheye's tilt model) as the
tracking evaluation runs it; :func:`pair_table` gives the advance and roll errors per mucosa against the
journeys' truth, in the columns of docs/vision.md's torso numbers.

Not here: the tracking table. :func:`evaluation.tracking.evaluate_tracking` calibrates the RF fixes and the
frame pairs with error models measured on the phantom itself (evaluation.error_models); the abdomen has none
committed yet, and the torso's would be the wrong calibration.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

import raytrace as rt
from raytrace.body.abdomen import ABDOMEN_NAME, abdomen_ct
from raytrace.spec import Antenna

#: Arc lengths [m] along the abdomen's journey where the video journeys start (metadata.journey.sites_s_m):
#: oesophagus -> stomach, duodenum, jejunum, ileum (two: past JIJ and mid-ileum), terminal ileum, ascending,
#: transverse, descending and sigmoid colon.
SEGMENT_STARTS = (0.02, 0.30, 1.00, 1.60, 2.30, 2.85, 3.05, 3.35, 3.75, 4.10)


#: The reach traces: the direct-path search does not depend on the interactions allowed (docs/tracer.md,
#: "Method"); 2 keep the shooting cheap. Fewer rays find fewer direct paths (measured on the first 6 capsule
#: sites: 1 000 rays found 11-23 of the 32 sensors, 20 000 rays 14-25).
REACH_SETTINGS = {"rays": 20_000, "max_interactions": 2}
#: The committed reach table (module docstring).
REACH_TABLE = Path(__file__).resolve().parent / "data" / f"{ABDOMEN_NAME}_reach.json"


def _direct(profile) -> bool:
    return any(all(i.kind == "refraction" for i in p.interactions) for p in profile.paths)


def reach_rows(phantom, capsules: Sequence[str] | None = None) -> dict[str, dict[str, list[str]]]:
    """Per capsule site: ``answered`` (the sensor sites whose profile came back, in order) and ``direct``
    (those it reaches by a refraction-only path), one trace each with :data:`REACH_SETTINGS`."""
    sensors = [n for n, s in phantom.sites.items() if s.kind == "sensor"]
    names = list(capsules or [n for n, s in phantom.sites.items() if s.kind == "capsule"])
    out = {}
    for name in names:
        spec = rt.ChannelSpec(Antenna(site=name), tuple(Antenna(site=s) for s in sensors), phantom=phantom.name,
                              rays=REACH_SETTINGS["rays"], max_interactions=REACH_SETTINGS["max_interactions"])
        result = rt.trace_channel(spec, phantom)
        out[name] = {"answered": [p.receiver for p in result.profiles],
                     "direct": [p.receiver for p in result.profiles if _direct(p)]}
    return out


def reach_table(phantom) -> dict:
    """The committed reach table, refused (ValueError, naming the command that regenerates it) when it was
    made on other geometry, other sensor positions or other settings."""
    from raytrace.body.indexgrid import phantom_digest

    raw = json.loads(REACH_TABLE.read_text())
    sensors = {n: [round(float(x), 9) for x in s.position_m] for n, s in phantom.sites.items() if s.kind == "sensor"}
    if raw["phantom_digest"] != phantom_digest(phantom) or raw["sensors"] != sensors or \
            raw["settings"] != REACH_SETTINGS:
        raise ValueError(f"{REACH_TABLE} was made on another {ABDOMEN_NAME} or with other settings: regenerate it "
                         "with python -m evaluation.anatomy reach --write")
    return raw


def write_reach_table(phantom, rows: dict) -> None:
    from raytrace.body.indexgrid import phantom_digest

    sensors = {n: [round(float(x), 9) for x in s.position_m] for n, s in phantom.sites.items() if s.kind == "sensor"}
    raw = {"command": "python -m evaluation.anatomy reach --write", "phantom": phantom.name,
           "phantom_digest": phantom_digest(phantom), "settings": REACH_SETTINGS, "sensors": sensors, "sites": rows}
    REACH_TABLE.parent.mkdir(parents=True, exist_ok=True)
    tmp = REACH_TABLE.with_suffix(".tmp")
    tmp.write_text(json.dumps(raw, indent=1) + "\n")
    os.replace(tmp, REACH_TABLE)


#: The committed localization table (``python -m evaluation.anatomy localization --write``).
LOCALIZATION_TABLE = Path(__file__).resolve().parent / "data" / f"{ABDOMEN_NAME}_localization.json"
#: The committed path-loss links (module docstring).
PATH_LOSS_TABLE = Path(__file__).resolve().parent / "data" / f"{ABDOMEN_NAME}_path_loss.json"
PATH_LOSS_SPEC = "abdomen-ct-path-loss-402mhz"


def path_loss_links(run_dir) -> dict:
    """The links of a finished ``abdomen-ct-path-loss`` experiment (its ``results.parquet``) and its spec."""
    import pyarrow.parquet as pq

    sweep = Path(run_dir) / PATH_LOSS_SPEC
    rows = pq.read_table(sweep / "results.parquet", columns=["s_m", "receiver", "distance_m", "path_gain_db"])
    spec = json.loads((sweep / "sweep.json").read_text())
    return {"spec": spec.get("spec", spec), "links": rows.to_pydict()}


#: Columns of the localization tables: the torso's (evaluation.localization.TABLE_METHODS).
LOCALIZATION_METHODS = ("nonlinear", "joint_velocity", "model_based")


def localization_record(name: str, ev) -> dict:
    """What the tables need of one site's :class:`evaluation.localization.LocalizationEvaluation`: per method
    the trials' 3-D errors, the RMSE, CEP90 and the position bound; the model-based fix's error from the exact
    first-path delays."""
    methods: dict[str, dict] = {}
    for k in LOCALIZATION_METHODS:
        m = ev.methods[k]
        err = np.linalg.norm(np.asarray(m.estimates_m) - ev.capsule_position_m, axis=1)
        methods[k] = {"errors_m": [float(e) for e in err], "rmse_m": float(m.rmse_m), "cep90_m": float(m.cep90_m),
                      "crlb_m": float(m.crlb_m)}
    methods["model_based"]["first_path_error_m"] = float(ev.methods["model_based"].extra["first_path_error_m"])
    return {"site": name, "sensors": list(ev.sensor_names), "methods": methods}


def localization_tables(records: Sequence[dict]) -> tuple[str, str]:
    """(pooled table, per-site table) in the columns of the torso's (README, docs/localization.md)."""
    mm = 1e3
    labels = {"nonlinear": "constant velocity (NLS, eps_r 27.9)", "joint_velocity": "joint velocity",
              "model_based": "model-based (travel-time fields)"}
    pooled = {k: np.array([e for r in records for e in r["methods"][k]["errors_m"]]) for k in LOCALIZATION_METHODS}
    pooled = {k: v[np.isfinite(v)] for k, v in pooled.items()}
    const = np.sqrt(np.mean(pooled["nonlinear"] ** 2))
    summary = ["| method | mean | RMSE | CEP50 | CEP90 | position CRLB (RMS over sites) | RMSE / CRLB "
               "| constant-velocity RMSE / RMSE |", "|---|---|---|---|---|---|---|---|"]
    for k in LOCALIZATION_METHODS:
        e = pooled[k]
        rmse = np.sqrt(np.mean(e**2))
        bound = np.sqrt(np.mean([r["methods"][k]["crlb_m"] ** 2 for r in records]))
        summary.append(f"| {labels[k]} | {e.mean() * mm:.1f} | {rmse * mm:.1f} | {np.percentile(e, 50) * mm:.1f} "
                       f"| {np.percentile(e, 90) * mm:.1f} | {bound * mm:.3f} | {rmse / bound:.0f} "
                       f"| {const / rmse:.1f} |")
    sites = ["| capsule site | sensors | constant velocity | joint velocity | model-based | model-based CEP90 "
             "| model-based CRLB | model-based, first-path delays | const. / model-based |", "|" + "---|" * 9]
    for r in records:
        c, j, m = (r["methods"][k] for k in LOCALIZATION_METHODS)
        sites.append(f"| {r['site']} | {len(r['sensors'])} | {c['rmse_m'] * mm:.1f} | {j['rmse_m'] * mm:.1f} | "
                     f"{m['rmse_m'] * mm:.1f} | {m['cep90_m'] * mm:.1f} | {m['crlb_m'] * mm:.3f} | "
                     f"{m['first_path_error_m'] * mm:.1f} | {c['rmse_m'] / m['rmse_m']:.1f} |")
    return "\n".join(summary), "\n".join(sites)


def strong_direct_sensors(phantom, capsule: str, sensors: Sequence[str], min_gain_db: float,
                          rays: int = REACH_SETTINGS["rays"]) -> list[str]:
    """Those of ``sensors`` whose strongest direct (refraction-only) path from ``capsule`` has a gain of at least
    ``min_gain_db`` (one trace, 6 interactions): a link budget's cut instead of every link at the same SNR."""
    spec = rt.ChannelSpec(Antenna(site=capsule), tuple(Antenna(site=s) for s in sensors), phantom=phantom.name,
                          rays=rays, max_interactions=6)
    out = []
    for name, profile in zip(sensors, rt.trace_channel(spec, phantom).profiles):
        gains = [p.gain_db for p in profile.paths if all(i.kind == "refraction" for i in p.interactions)]
        if gains and max(gains) >= min_gain_db:
            out.append(name)
    return out


def localization_rows(*, trials: int = 20, seed: int = 0, rays: int = REACH_SETTINGS["rays"],
                      capsules: Sequence[str] | None = None, min_gain_db: float | None = None, progress=print):
    """(capsule names, their :class:`evaluation.localization.LocalizationEvaluation`s, the sensors of each).
    ``min_gain_db``: only the direct sensors whose direct path is at least that strong
    (:func:`strong_direct_sensors`); a site left with fewer than 5 (joint velocity's minimum) is skipped."""
    from evaluation.localization import TABLE_METHODS, evaluate_localization

    phantom = abdomen_ct()
    names = list(capsules or [n for n, s in phantom.sites.items() if s.kind == "capsule"])
    reach = reach_table(phantom)["sites"]
    kept, rows, used = [], [], []
    for name in names:
        t0 = time.perf_counter()
        sensors = reach[name]["direct"]
        if min_gain_db is not None:
            sensors = strong_direct_sensors(phantom, name, sensors, min_gain_db, rays)
            if len(sensors) < 5:
                progress(f"{name}: {len(sensors)} sensors at >= {min_gain_db:g} dB, skipped")
                continue
        rows.append(evaluate_localization(phantom, name, sensors, methods=("linear", *TABLE_METHODS), trials=trials,
                                          seed=seed, rays=rays))
        kept.append(name)
        used.append(sensors)
        m = rows[-1].methods
        progress(f"{name}: {len(sensors)} sensors, constant velocity {m['nonlinear'].rmse_m * 1e3:.1f} mm, model-based "
                 f"{m['model_based'].rmse_m * 1e3:.1f} mm ({time.perf_counter() - t0:.0f} s)")
    return kept, rows, used


def video_pairs(phantom, *, steps: int = 40, seed: int = 0, starts: Sequence[float] = SEGMENT_STARTS,
                cache_dir=None, progress=print) -> list[tuple]:
    """Per start: (the journey, its pairs' estimates) (module docstring)."""
    from tracking import JourneySpec, simulate_journey
    from vision.odometry import OdometrySettings, pair_estimates

    line = phantom.centrelines["gi_tract"]
    out = []
    for k, start in enumerate(starts):
        t0 = time.perf_counter()
        journey = simulate_journey(line, JourneySpec(steps=steps, seed=seed + k, start_m=float(start)))
        pairs = pair_estimates(phantom, journey.s_m.tolist(), journey.roll_deg.tolist(), OdometrySettings(),
                               cache_dir=cache_dir)
        out.append((journey, pairs))
        progress(f"journey from {start:.2f} m ({line.organ_at(float(start))}): {steps} frames, "
                 f"{time.perf_counter() - t0:.0f} s")
    return out


def pair_table(journeys: Sequence[tuple]) -> str:
    """The frame pairs' advance and roll errors per mucosa (every journey's pairs, against its truth): median
    relative advance error, the share beyond 1 mm, roll error median and 90th percentile."""
    rows: dict[str, list] = {}
    for j, pairs in journeys:
        for k, p in enumerate(pairs):
            if p is None or not np.isfinite(p.advance_m):
                continue
            d = float(j.s_m[k] - j.s_m[k - 1])
            if abs(d) < 1e-5:
                continue
            kind = "colon" if p.organ == "large_intestine" else p.organ
            rows.setdefault(kind, []).append((d, p.advance_m - d, p.rotation_deg - (j.roll_deg[k] - j.roll_deg[k - 1])))
    out = ["| mucosa | pairs | median abs(e)/d | abs(e) > 1 mm | roll error, median / 90th pct |",
           "|---|---:|---:|---:|---:|"]
    for kind, values in rows.items():
        true, err, roll = (np.array(v) for v in zip(*values))
        out.append(f"| {kind.replace('_', ' ')} | {len(true)} | {np.median(np.abs(err) / np.abs(true)) * 100:.1f} % | "
                   f"{np.mean(np.abs(err) > 1e-3) * 100:.1f} % | {np.median(np.abs(roll)):.2f} / "
                   f"{np.percentile(np.abs(roll), 90):.2f} deg |")
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="table", required=True)
    rch = sub.add_parser("reach", help="per capsule site: the sensors that answer and those reached directly")
    rch.add_argument("--write", action="store_true", help=f"commit it as {REACH_TABLE.name}")
    loc = sub.add_parser("localization", help="per capsule site: constant velocity, joint velocity, model-based")
    loc.add_argument("--trials", type=int, default=20)
    loc.add_argument("--seed", type=int, default=0)
    loc.add_argument("--rays", type=int, default=REACH_SETTINGS["rays"])
    loc.add_argument("--write", action="store_true", help=f"commit it as {LOCALIZATION_TABLE.name}")
    loc.add_argument("--min-gain-db", type=float, default=None,
                     help="use only the direct sensors whose direct path is at least this strong (a link budget's "
                          "cut; sites left with fewer than 5 are skipped); not with --write")
    pl = sub.add_parser("path-loss", help="commit the links of a finished abdomen-ct-path-loss experiment")
    pl.add_argument("--from", dest="run_dir", required=True, help="the experiment's --out directory")
    pl.add_argument("--write", action="store_true", help=f"commit them as {PATH_LOSS_TABLE.name}")
    vid = sub.add_parser("video", help="frame pairs rendered in the real lumen along ten journeys: MI errors")
    vid.add_argument("--steps", type=int, default=40)
    vid.add_argument("--seed", type=int, default=0)
    vid.add_argument("--cache-dir", default=None, help="keep the frame pairs' estimates")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.table == "reach":
        phantom = abdomen_ct()
        rows = reach_rows(phantom)
        total = sum(s.kind == "sensor" for s in phantom.sites.values())
        print("| capsule site | sensors answering | reached directly |\n|---|---:|---:|")
        for name, row in rows.items():
            print(f"| {name} | {len(row['answered'])} of {total} | {len(row['direct'])} |")
        counts = [len(r["direct"]) for r in rows.values()]
        print(f"\n{ABDOMEN_NAME}: {len(rows)} capsule sites, {min(counts)}-{max(counts)} sensors reached directly; "
              f"{REACH_SETTINGS}; {time.perf_counter() - t0:.0f} s")
        if args.write:
            write_reach_table(phantom, rows)
            print(f"wrote {REACH_TABLE}")
    elif args.table == "localization":
        from raytrace.body.indexgrid import phantom_digest

        if args.write and args.min_gain_db is not None:
            ap.error("--write commits the table of every direct sensor: leave --min-gain-db out")
        names, rows, used = localization_rows(trials=args.trials, seed=args.seed, rays=args.rays,
                                              min_gain_db=args.min_gain_db)
        records = [localization_record(n, r) for n, r in zip(names, rows)]
        summary, sites = localization_tables(records)
        print(summary, sites, sep="\n\n")
        counts = [len(u) for u in used]
        cut = "" if args.min_gain_db is None else f" at >= {args.min_gain_db:g} dB"
        print(f"\n{ABDOMEN_NAME}: {len(names)} capsule sites, {min(counts)}-{max(counts)} sensors each (those with a "
              f"direct path{cut}); TOA gcc, {args.trials} trials, seed {args.seed}, {args.rays} rays; "
              f"{time.perf_counter() - t0:.0f} s")
        if args.write:
            raw = {"command": "python -m evaluation.anatomy localization --write", "phantom": ABDOMEN_NAME,
                   "phantom_digest": phantom_digest(abdomen_ct()),
                   "settings": {"trials": args.trials, "seed": args.seed, "rays": args.rays, "ranging": "gcc",
                                "snr_db": 30.0, "frequency_hz": 402e6},
                   "sites": records}
            tmp = LOCALIZATION_TABLE.with_suffix(".tmp")
            tmp.write_text(json.dumps(raw, indent=1) + "\n")
            os.replace(tmp, LOCALIZATION_TABLE)
            print(f"wrote {LOCALIZATION_TABLE}")
    elif args.table == "path-loss":
        from raytrace.body.indexgrid import phantom_digest

        measured = path_loss_links(args.run_dir)
        raw = {"command": "capsule-rt experiment abdomen-ct-path-loss --out DIR; "
                          "python -m evaluation.anatomy path-loss --from DIR --write",
               "phantom": ABDOMEN_NAME, "phantom_digest": phantom_digest(abdomen_ct()), **measured}
        links: dict[str, list] = measured["links"]
        have = sum(g is not None for g in links["path_gain_db"])
        print(f"{len(links['s_m'])} links, {have} with a path, from {args.run_dir}")
        if args.write:
            tmp = PATH_LOSS_TABLE.with_suffix(".tmp")
            tmp.write_text(json.dumps(raw) + "\n")
            os.replace(tmp, PATH_LOSS_TABLE)
            print(f"wrote {PATH_LOSS_TABLE}")
    else:
        journeys = video_pairs(abdomen_ct(), steps=args.steps, seed=args.seed, cache_dir=args.cache_dir)
        print(pair_table(journeys))
        print(f"\n{ABDOMEN_NAME}: {len(journeys)} journeys of {args.steps} frames from "
              f"{', '.join(f'{s:g}' for s in SEGMENT_STARTS)} m, seeds {args.seed}..{args.seed + len(journeys) - 1}, "
              f"192 px, tilt model; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
