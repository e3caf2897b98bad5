"""``capsule-rt``: serve the API, run a channel request locally, a demo, or write openapi.json.

    capsule-rt serve [--host H] [--port P] [--workers N] [--data-dir DIR]
    capsule-rt channel REQUEST.json [--output OUT.json] [--export OUT.npz | OUT.csv]
    capsule-rt demo [--rays N]          (default: the API's own default, 100000)
    capsule-rt openapi [--output openapi.json] [--check]
    capsule-rt plot KIND INPUT.json --output OUT.png|svg|pdf [--receiver NAME]
    capsule-rt sweep SPEC --out DIR [--cluster ADDRESS] [--resume]   (service.sweep_cli)
    capsule-rt experiment NAME --out DIR                             (service.sweep_cli)
    capsule-rt fullwave REQUEST.json --out DIR [--cell-mm 2] [--coarse-factor 1.5] [--margin-mm 20]
    capsule-rt vision render --out DIR [--start-s-m S] [--frames N] [--advance-m D] [--roll-deg R] ...
    capsule-rt vision motion DIR|FRAME.png... [--output OUT.csv|.json] [--estimate both] ...
    capsule-rt localize REQUEST.json [--output OUT.json]            (a POST /v1/localize body)
    capsule-rt localize-evaluate REQUEST.json [--output OUT.json]   (a POST /v1/localize/evaluate body)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any, Sequence

from plots import cli as plots_cli

REPO_ROOT = Path(__file__).resolve().parent.parent


def openapi_text() -> str:
    """The app's OpenAPI document as stable JSON text (sorted keys, 2-space indent, final newline)."""
    from service.app import create_app
    from service.settings import Settings

    app = create_app(Settings(load_builtins=False))
    return json.dumps(app.openapi(), indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def _cmd_openapi(args: argparse.Namespace) -> int:
    text = openapi_text()
    out = Path(args.output)
    if args.check:
        current = out.read_text() if out.exists() else ""
        if current != text:
            print(f"{out} is out of date; run `capsule-rt openapi`", file=sys.stderr)
            return 1
        print(f"{out} is up to date")
        return 0
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, out)
    print(f"wrote {out} ({len(text)} bytes)")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from service.settings import Settings

    if args.data_dir:
        os.environ["CAPSULE_RT_DATA_DIR"] = str(args.data_dir)
    settings = Settings()
    host = args.host or settings.host
    port = args.port or settings.port
    workers = args.workers or settings.workers
    uvicorn.run(
        "service.app:app",
        host=host,
        port=port,
        workers=workers,
        log_level=settings.log_level,
        access_log=False,  # the app logs one JSON line per request itself
        proxy_headers=True,
        timeout_graceful_shutdown=10,
    )
    return 0


def _local_registry():
    from service.registry import Registry
    from service.settings import Settings
    from service.storage import PhantomStore

    settings = Settings()
    registry = Registry(store=PhantomStore(settings.data_dir))
    registry.load_builtins(settings.load_builtins)
    return registry, settings


def _error_json(exc: Exception) -> dict[str, Any]:
    from raytrace.errors import CapsuleRTError
    from service.errors import ServiceError, field_to_loc

    if isinstance(exc, ServiceError):
        return {"detail": [{"loc": exc.loc, "msg": exc.reason, "type": exc.type}]}
    if isinstance(exc, CapsuleRTError) or hasattr(exc, "field"):
        return {"detail": [{"loc": ["body", *field_to_loc(getattr(exc, "field", None))],
                            "msg": getattr(exc, "reason", str(exc)), "type": type(exc).__name__}]}
    return {"detail": [{"loc": [], "msg": str(exc), "type": type(exc).__name__}]}


def run_channel_request(payload: dict) -> dict[str, Any]:
    """Run one POST /v1/channel body locally (no HTTP); returns the response dict."""
    from raytrace import Budget, trace_channel
    from service import channel as ops
    from service.schemas.channel import ChannelRequest, ChannelResponse

    registry, settings = _local_registry()
    req = ChannelRequest.model_validate(payload)
    spec, phantom = ops.to_spec(req, registry, settings)
    budget = Budget(deadline_s=settings.request_deadline_s, max_ray_segments=settings.max_ray_segments)
    result = trace_channel(spec, phantom, budget=budget, config=settings.tracer_config())
    out = ops.result_to_dict(result, req.scenario, req.outputs)
    return json.loads(ChannelResponse.model_validate(out).model_dump_json())


def _cmd_channel(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from raytrace.errors import CapsuleRTError
    from service.errors import ServiceError

    try:
        payload = json.loads(Path(args.file).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        print(json.dumps({"detail": [{"loc": ["file"], "msg": str(exc), "type": "invalid_file"}]}), file=sys.stderr)
        return 2
    try:
        out = run_channel_request(payload)
    except ValidationError as exc:
        items = [{"loc": ["body", *e["loc"]], "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
        print(json.dumps({"detail": items}, indent=2), file=sys.stderr)
        return 2
    except (CapsuleRTError, ServiceError, ValueError) as exc:
        print(json.dumps(_error_json(exc), indent=2), file=sys.stderr)
        return 2
    text = json.dumps(out, indent=2) + "\n"
    if args.output:
        Path(args.output).write_text(text)
    elif not args.export:
        sys.stdout.write(text)
    if args.export:
        try:
            export_outputs(out, Path(args.export))
        except (OSError, ValueError) as exc:
            print(json.dumps({"detail": [{"loc": ["export"], "msg": str(exc), "type": "export_failed"}]}),
                  file=sys.stderr)
            return 2
    return 0


def run_localize_request(payload: dict, *, evaluate: bool = False) -> dict[str, Any]:
    """Run one POST /v1/localize (or /v1/localize/evaluate) body locally (no HTTP); the response dict."""
    from raytrace import Budget
    from service.routes import localize as loc

    registry, settings = _local_registry()
    model, run, response = ((loc.LocalizeEvaluateRequest, loc.evaluate, loc.LocalizeEvaluateResponse) if evaluate
                            else (loc.LocalizeRequest, loc.localize, loc.LocalizeResponse))
    req = model.model_validate(payload)
    budget = Budget(deadline_s=settings.request_deadline_s, max_ray_segments=settings.max_ray_segments)
    return json.loads(response.model_validate(run(req, registry, settings, budget)).model_dump_json())


def _cmd_localize(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from estimators.errors import EstimatorInputError
    from raytrace.errors import CapsuleRTError
    from service.errors import ServiceError

    try:
        payload = json.loads(Path(args.file).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        print(json.dumps({"detail": [{"loc": ["file"], "msg": str(exc), "type": "invalid_file"}]}), file=sys.stderr)
        return 2
    try:
        out = run_localize_request(payload, evaluate=args.command == "localize-evaluate")
    except ValidationError as exc:
        items = [{"loc": ["body", *e["loc"]], "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
        print(json.dumps({"detail": items}, indent=2), file=sys.stderr)
        return 2
    except (CapsuleRTError, ServiceError, EstimatorInputError) as exc:
        print(json.dumps(_error_json(exc), indent=2), file=sys.stderr)
        return 2
    text = json.dumps(out, indent=2) + "\n"
    if args.output:
        Path(args.output).write_text(text)
    else:
        sys.stdout.write(text)
    return 0


def export_outputs(response: dict[str, Any], path: Path) -> None:
    """Write a channel response's per-receiver ``cfr`` / ``cir`` / ``taps`` to ``path``: ``.npz``
    (numpy: ``<receiver>/cfr_frequency_hz``, ``<receiver>/cfr`` complex, ``<receiver>/cir_time_s``,
    ``<receiver>/cir``, ``<receiver>/taps_l``, ``<receiver>/taps_delay_s``, ``<receiver>/taps``) or
    ``.csv`` (one row per value: ``receiver,output,index,frequency_hz,delay_s,re,im``; ``delay_s`` is
    the time of a cir sample or the delay of a tap, absolute unless the request normalised delays)."""
    import csv

    import numpy as np

    arrays: dict[str, np.ndarray] = {}
    rows: list[tuple] = []
    for prof in response["profiles"]:
        name = prof["receiver"]
        if prof.get("cfr"):
            c = prof["cfr"]
            h = np.asarray(c["re"]) + 1j * np.asarray(c["im"])
            arrays[f"{name}/cfr_frequency_hz"], arrays[f"{name}/cfr"] = np.asarray(c["frequency_hz"]), h
            rows += [(name, "cfr", i, f, "", z.real, z.imag) for i, (f, z) in enumerate(zip(c["frequency_hz"], h))]
        if prof.get("cir"):
            c = prof["cir"]
            h = np.asarray(c["re"]) + 1j * np.asarray(c["im"])
            arrays[f"{name}/cir_time_s"], arrays[f"{name}/cir"] = np.asarray(c["time_s"]), h
            rows += [(name, "cir", i, "", t, z.real, z.imag) for i, (t, z) in enumerate(zip(c["time_s"], h))]
        if prof.get("taps"):
            c = prof["taps"]
            h = np.asarray(c["re"]) + 1j * np.asarray(c["im"])
            arrays[f"{name}/taps_l"], arrays[f"{name}/taps_delay_s"] = np.asarray(c["l"]), np.asarray(c["delay_s"])
            arrays[f"{name}/taps"] = h
            rows += [(name, "taps", ell, "", d, z.real, z.imag) for ell, d, z in zip(c["l"], c["delay_s"], h)]
    if not arrays:
        raise ValueError("the response holds no channel outputs: add \"outputs\" (cfr, cir, taps) and a band "
                         "to the request")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        np.savez(path, **arrays)
    elif suffix == ".csv":
        with path.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["receiver", "output", "index", "frequency_hz", "delay_s", "re", "im"])
            w.writerows((r[0], r[1], r[2], r[3] if r[3] == "" else repr(float(r[3])),
                         r[4] if r[4] == "" else repr(float(r[4])), repr(float(r[5])), repr(float(r[6])))
                        for r in rows)
    else:
        raise ValueError(f"unknown export format {path.suffix!r}: use .npz or .csv")
def _cmd_fullwave(args: argparse.Namespace) -> int:
    """Export a channel request to gprMax, run it at two cell sizes and compare with the tracer
    (fullwave.run; docs/validation.md)."""
    import raytrace as rt
    from fullwave.model import FdtdOptions
    from fullwave.run import compare, gprmax_available
    from raytrace.errors import CapsuleRTError

    try:
        payload = json.loads(Path(args.file).read_text())
        scenario = payload.pop("scenario", None)
        base = rt.get_scenario(scenario).spec if scenario else None
        spec = rt.ChannelSpec.from_dict(payload, base)
        phantom = rt.get_phantom(spec.phantom)
        options = FdtdOptions(cell_m=args.cell_mm * 1e-3, margin_m=args.margin_mm * 1e-3, pml_cells=args.pml_cells)
    except (OSError, json.JSONDecodeError, CapsuleRTError, ValueError) as exc:
        detail = _error_json(exc) if isinstance(exc, CapsuleRTError) else {"detail": str(exc)}
        print(json.dumps(detail), file=sys.stderr)
        return 2
    run = not args.export_only
    if run and not gprmax_available():
        print("gprMax is not installed (pip install 'capsule-rt[fullwave]'); writing the inputs only", file=sys.stderr)
        run = False
    report = compare(spec, phantom, options, Path(args.out), coarse_factor=args.coarse_factor or None, run=run,
                     threads=args.threads)
    for r in report["runs"]:
        if r.get("ran"):
            print(f"{r['cell_m'] * 1e3:g} mm cells: gprMax {r['wall_s']:.0f} s", file=sys.stderr)
    sys.stdout.write((Path(args.out) / "report.md").read_text())
    return 0


def _table(rows: Sequence[Sequence[Any]], header: Sequence[str]) -> str:
    cells = [[str(c) for c in header]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    line = "  ".join("-" * w for w in widths)
    out = ["  ".join(c.rjust(w) for c, w in zip(cells[0], widths)), line]
    out += ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in cells[1:]]
    return "\n".join(out)


_KIND = {"reflection": "R", "refraction": "T", "total_internal_reflection": "TIR"}


def _demo_case(title: str, payload: dict) -> None:
    from service import ranging
    from service.schemas.ranging import PdoaRequest, ToaRequest
    from service.settings import Settings

    print(f"\n=== {title} ===")
    out = run_channel_request(payload)
    stats = out["stats"]
    print(f"phantom {out['phantom']}, {out['frequency_hz'] / 1e6:g} MHz, transmitter in {out['transmitter']['medium']} "
          f"at {[round(x, 4) for x in out['transmitter']['position_m']]} m; "
          f"{stats['rays_launched']} rays, {stats['paths_found']} paths, {stats['elapsed_s']:.2f} s")
    settings = Settings()
    for prof in out["profiles"]:
        print(f"\nreceiver {prof['receiver']} ({prof['medium']}), "
              f"geometric distance {prof['geometric_distance_m'] * 1e3:.2f} mm, "
              f"path gain {prof['path_gain_db']:.1f} dB, rms delay spread {prof['rms_delay_spread_s'] * 1e12:.1f} ps")
        rows = []
        for k, p in enumerate(prof["paths"]):
            kinds = "-".join(_KIND[i["kind"]] for i in p["interactions"]) or "direct"
            rows.append((k, f"{p['delay_s'] * 1e9:.4f}", f"{p['gain_db']:.1f}", f"{p['length_m'] * 1e3:.2f}", kinds))
        if rows:
            print(_table(rows, ["path", "delay [ns]", "gain [dB]", "length [mm]", "interactions (R/T/TIR)"]))
        else:
            print("  (no path found)")
            continue
        truth = prof["geometric_distance_m"]
        toa = ranging.toa(ToaRequest(profile=prof, method="all", trials=50, seed=1, true_distance_m=truth), settings)
        band = {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}
        try:
            pdoa = ranging.pdoa(PdoaRequest(profile=prof, method="regression", band=band, trials=50, seed=1,
                                            true_distance_m=truth), settings)
            results = toa["results"] + pdoa["results"]
        except Exception as exc:  # noqa: BLE001 - show what worked
            print(f"  PDOA unavailable: {exc}")
            results = toa["results"]
        rows = [
            (r["method"], f"{r['distance_m'] * 1e3:.2f}", f"{(r['error_m'] or 0) * 1e3:+.2f}",
             f"{r['std_m'] * 1e3:.3f}", "-" if r["crlb_m"] is None else f"{r['crlb_m'] * 1e3:.4f}")
            for r in results
        ]
        print(_table(rows, ["method", "distance [mm]", "error [mm]", "std [mm]", "CRLB [mm]"]))


def _cmd_demo(args: argparse.Namespace) -> int:
    registry, _ = _local_registry()
    cases = []
    # without --rays the requests carry none: the API's (and the scenarios') own default, what a
    # user of the API gets (a sparser launch can miss a sensor's strongest path)
    rays = {} if args.rays is None else {"rays": args.rays}
    if "thesis-fig-5-6" in registry.scenarios:
        cases.append(("thesis-fig-5-6 (thesis Fig 5.5/5.6)", {"scenario": "thesis-fig-5-6", **rays}))
    if "torso-small-intestine" in registry.scenarios:
        cases.append(("default torso, capsule in the small intestine (scenario torso-small-intestine)",
                      {"scenario": "torso-small-intestine", **rays}))
    elif "torso" in registry.builtins:
        torso = registry.builtins["torso"]
        capsule = next((n for n, s in torso.sites.items() if s.kind == "capsule"), None)
        sensors = [n for n, s in torso.sites.items() if s.kind == "sensor"][:4]
        if capsule and sensors:
            cases.append((
                f"default torso, capsule at {capsule}",
                {"phantom": "torso", "transmitter": {"site": capsule}, "receivers": [{"site": n} for n in sensors],
                 "max_interactions": 4, **rays},
            ))
    if not cases:
        print("no built-in scenario or phantom available", file=sys.stderr)
        return 1
    for title, payload in cases:
        _demo_case(title, payload)
    return 0


# ----------------------------------------------------------------- vision (docs/vision.md)
def _vision_render_seq(args: argparse.Namespace) -> int:
    """Render a capsule moving along the phantom's GI-tract centreline: frame_NNNN.png, and
    sequence.json (the settings and every frame's exact pose) in ``--out``."""
    from raytrace.errors import CapsuleRTError
    from service.errors import ServiceError
    from service.routes.vision import SensorIn
    from vision.camera import FisheyeCamera
    from vision.errors import VisionInputError
    from vision.mucosa import texture_for
    from vision.png import encode_png
    from vision.sensor import SensorModel
    from vision.sequence import centreline_path, render_sequence

    registry, _ = _local_registry()
    try:
        phantom = registry.get(args.phantom)
        length = args.advance_m * (args.frames - 1)
        path, offset, organ = centreline_path(phantom, args.start_s_m, length)
        sensor = SensorIn(salt_pepper=args.salt_pepper, read_noise=args.read_noise, seed=args.seed)
        seq = render_sequence(phantom, path, args.frames, args.advance_m, args.roll_deg,
                              FisheyeCamera(args.fov_deg, args.size_px), start_m=offset,
                              start_roll_deg=args.start_roll_deg, texture=texture_for(organ, seed=args.seed),
                              sensor=SensorModel(**sensor.model_dump()), organ=organ)
    except (VisionInputError, CapsuleRTError, ServiceError) as exc:  # a refusal, as the API's error JSON
        print(json.dumps(_error_json(exc), indent=2), file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames = []
    for k, (frame, s_path, roll) in enumerate(zip(seq.frames, seq.truth.s_m, seq.truth.roll_deg)):
        name = f"frame_{k:04d}.png"
        (out / name).write_bytes(encode_png(frame.to_uint8()))
        frames.append({"file": name, "s_m": float(args.start_s_m + s_path - offset), "roll_deg": float(roll),
                       "position_m": [float(v) for v in frame.pose.position_m],
                       "direction": [float(v) for v in frame.pose.direction],
                       "up": [float(v) for v in frame.pose.basis[1]]})
    meta = {"phantom": args.phantom, "organ": organ, "camera": {"fov_deg": args.fov_deg, "size_px": args.size_px},
            "advance_m": args.advance_m, "roll_deg": args.roll_deg, "exposure": seq.metadata["exposure"],
            "seed": args.seed, "frames": frames}
    (out / "sequence.json").write_text(json.dumps(meta, indent=2) + "\n")
    print(f"wrote {len(frames)} frames ({organ}, s = {frames[0]['s_m']:.4f} to {frames[-1]['s_m']:.4f} m) "
          f"and sequence.json to {out}")
    return 0


def _vision_frames(inputs: Sequence[str]) -> list[Path]:
    paths: list[Path] = []
    for item in inputs:
        p = Path(item)
        paths += sorted(p.glob("*.png")) if p.is_dir() else [p]
    return paths


def _vision_motion_seq(args: argparse.Namespace) -> int:
    """Estimate rotation and scale between consecutive frames; with the sequence.json of
    ``vision render`` beside them, also the advance (through each reference frame's rendered
    geometry) and the errors against the ground truth."""
    from pydantic import ValidationError

    from service.routes.vision import MotionOptions, advance_of, estimate_pair, frame_from_png
    from vision.camera import FisheyeCamera, Pose
    from vision.errors import VisionInputError
    from vision.mucosa import texture_for
    from vision.render import render_frame

    paths = _vision_frames(args.frames)
    if len(paths) < 2:
        print("need at least two PNG frames (a directory of them, or the files in order)", file=sys.stderr)
        return 2
    try:
        options = MotionOptions.model_validate({"estimate": args.estimate, "strategy": args.strategy,
                                                "search": args.search, "bins": args.bins, **json.loads(args.options)})
    except (ValidationError, ValueError) as exc:
        print(f"--options: {exc}", file=sys.stderr)
        return 2
    truth_file = Path(args.sequence) if args.sequence else paths[0].parent / "sequence.json"
    truth = json.loads(truth_file.read_text()) if truth_file.exists() else None
    by_file = {f["file"]: f for f in truth["frames"]} if truth else {}
    phantom = _local_registry()[0].get(truth["phantom"]) if truth else None
    rows = []
    for a, b in zip(paths[:-1], paths[1:]):
        row: dict[str, Any] = {"reference": a.name, "moving": b.name}
        try:
            ref, mov = frame_from_png(a.read_bytes(), "reference"), frame_from_png(b.read_bytes(), "moving")
            est = estimate_pair(ref, mov, options)
        except VisionInputError as exc:
            row["error"] = f"{exc.field}: {exc.reason}"
            rows.append(row)
            continue
        row.update(rotation_deg=est.rotation_deg, scale=est.scale, mutual_information=est.mutual_information,
                   iterations=est.iterations)
        ta, tb = by_file.get(a.name), by_file.get(b.name)
        if ta and tb:
            pose = Pose(ta["position_m"], ta["direction"], 0.0, ta["up"])
            frame = render_frame(phantom, pose, FisheyeCamera(**truth["camera"]), organ=truth["organ"],
                                 texture=texture_for(truth["organ"], seed=truth["seed"]), exposure=truth["exposure"])
            row["advance_m"], note = advance_of(frame, est.scale)
            row.update(true_roll_deg=tb["roll_deg"] - ta["roll_deg"], true_advance_m=tb["s_m"] - ta["s_m"])
            row["roll_error_deg"] = est.rotation_deg - row["true_roll_deg"]
            if row["advance_m"] is not None:
                row["advance_error_m"] = row["advance_m"] - row["true_advance_m"]
        rows.append(row)
        print(" ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()),
              file=sys.stderr)
    out = Path(args.output) if args.output else None
    if out is not None and out.suffix == ".csv":
        import csv

        keys = list(dict.fromkeys(k for r in rows for k in r))
        with out.open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=keys)
            writer.writeheader()
            writer.writerows(rows)
    else:
        text = json.dumps({"options": options.model_dump(), "pairs": rows}, indent=2) + "\n"
        out.write_text(text) if out is not None else sys.stdout.write(text)
    return 1 if any("error" in r for r in rows) else 0


def _add_vision_parsers(sub) -> None:
    v = sub.add_parser("vision", help="capsule camera sequences and MI motion estimates (docs/vision.md)")
    vsub = v.add_subparsers(dest="vision_command", required=True, metavar="WHAT")
    r = vsub.add_parser("render", help="render frames of a capsule moving along the GI-tract centreline")
    r.add_argument("--out", required=True, help="directory for frame_NNNN.png and sequence.json (poses)")
    r.add_argument("--phantom", default="torso", help="phantom id with a GI-tract centreline (default torso)")
    r.add_argument("--start-s-m", type=float, default=0.37,
                   help="arc length of the first frame on the centreline [m] (default 0.37, ascending colon)")
    r.add_argument("--frames", type=int, default=10, help="number of frames (default 10)")
    r.add_argument("--advance-m", type=float, default=0.0015, help="advance between frames [m] (default 0.0015)")
    r.add_argument("--roll-deg", type=float, default=2.0, help="roll between frames [deg] (default 2)")
    r.add_argument("--start-roll-deg", type=float, default=0.0, help="roll of the first frame [deg] (default 0)")
    r.add_argument("--fov-deg", type=float, default=150.0, help="fisheye field of view [deg] (default 150)")
    r.add_argument("--size-px", type=int, default=256, help="pixels a side (default 256)")
    r.add_argument("--salt-pepper", type=float, default=0.0, help="fraction of salt-and-pepper pixels (default 0)")
    r.add_argument("--read-noise", type=float, default=0.0, help="Gaussian read noise, fraction of full scale")
    r.add_argument("--seed", type=int, default=0, help="seed of the mucosa texture and the noise (default 0)")
    r.set_defaults(func=_vision_render_seq)
    m = vsub.add_parser("motion", help="rotation, scale (and advance, errors) between consecutive frames")
    m.add_argument("frames", nargs="+", help="a directory of PNG frames (sorted by name), or PNG files in order")
    m.add_argument("--output", "-o", default=None, help="write the estimates to this .csv or .json (default: "
                   "JSON on stdout)")
    m.add_argument("--sequence", default=None, help="sequence.json of `vision render` (default: the one beside "
                   "the frames, if any): adds the advance and the errors against the ground truth")
    m.add_argument("--estimate", default="both", choices=["both", "rotation", "scale"], help="what to estimate")
    m.add_argument("--strategy", default="joint", choices=["joint", "in_turn"], help="coarse bracketing")
    m.add_argument("--search", default="fibonacci", choices=["fibonacci", "golden"], help="1-D search")
    m.add_argument("--bins", type=int, default=64, help="grey-level bins per frame (default 64)")
    m.add_argument("--options", default="{}", help="more estimator options as JSON (schema MotionOptions of "
                   "POST /v1/vision/motion), e.g. '{\"cutoff\": 0.1}'")
    m.set_defaults(func=_vision_motion_seq)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="capsule-rt", description="CapsuleRT in-body channel emulator.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", help="what to do")
    s = sub.add_parser("serve", help="run the HTTP API (uvicorn)")
    s.add_argument("--host", default=None, help="bind address (default CAPSULE_RT_HOST or 127.0.0.1)")
    s.add_argument("--port", type=int, default=None, help="port (default CAPSULE_RT_PORT or 8000)")
    s.add_argument("--workers", type=int, default=None, help="worker processes (default CAPSULE_RT_WORKERS or 1)")
    s.add_argument("--data-dir", default=None, help="upload directory (default CAPSULE_RT_DATA_DIR or ./data)")
    s.set_defaults(func=_cmd_serve)
    c = sub.add_parser("channel", help="run a POST /v1/channel body locally and print the response JSON")
    c.add_argument("file", help="JSON file with the request body")
    c.add_argument("--output", "-o", default=None, help="write the response here instead of stdout")
    c.add_argument("--export", default=None, help="also write the request's channel outputs (cfr / cir / taps) "
                   "to this .npz or .csv file")
    c.set_defaults(func=_cmd_channel)
    d = sub.add_parser("demo", help="trace thesis-fig-5-6 and a default-torso case; print paths and TOA/PDOA")
    d.add_argument("--rays", type=int, default=None,
                   help="rays launched per trace (default: the API's default, 100000; fewer is faster but "
                   "may miss weak or grazing paths)")
    d.set_defaults(func=_cmd_demo)
    o = sub.add_parser("openapi", help="write openapi.json (stable key order)")
    o.add_argument("--output", "-o", default=str(REPO_ROOT / "openapi.json"),
                   help="where to write it (default: openapi.json at the repository root)")
    o.add_argument("--check", action="store_true", help="exit 1 if the file differs instead of writing it")
    o.set_defaults(func=_cmd_openapi)
    plots_cli.add_parser(sub)
    from service import sweep_cli

    sweep_cli.add_parsers(sub)
    __import__("service.routes.tracking", fromlist=["add_parser"]).add_parser(sub)
    f = sub.add_parser("fullwave", help="export a channel request to gprMax, run it and compare with the tracer")
    f.add_argument("file", help="JSON file with a POST /v1/channel body (ChannelSpec)")
    f.add_argument("--out", required=True, help="directory for the gprMax inputs, outputs and report.{json,md}")
    f.add_argument("--cell-mm", type=float, default=2.0, help="FDTD cell edge [mm] (default 2)")
    f.add_argument("--coarse-factor", type=float, default=1.5,
                   help="second run's cells are this much larger, for the discretisation estimate (0: no second run)")
    f.add_argument("--margin-mm", type=float, default=20.0, help="margin around the antennas' box [mm] (default 20)")
    f.add_argument("--pml-cells", type=int, default=10, help="absorbing-layer thickness [cells] (default 10)")
    f.add_argument("--threads", type=int, default=2, help="OpenMP threads for gprMax (default 2)")
    f.add_argument("--export-only", action="store_true", help="write the gprMax inputs, do not run them")
    f.set_defaults(func=_cmd_fullwave)
    _add_vision_parsers(sub)
    lz = sub.add_parser("localize", help="a position fix from a POST /v1/localize body (sensors with ranges, delays "
                        "or received powers); prints the response JSON", description="The capsule's position from "
                        "the sensors of REQUEST.json by the method it names (docs/localization.md); the answer is "
                        "POST /v1/localize's.")
    lz.add_argument("file", help="JSON file with the request body: {\"sensors\": [{\"position_m\" or \"site\", "
                    "\"range_m\" | \"delay_s\" | \"rss_dbm\", \"sigma_m\"?}, ...], \"method\": ...}")
    lz.add_argument("--output", "-o", default=None, help="write the response JSON here instead of stdout")
    lz.set_defaults(func=_cmd_localize)
    le = sub.add_parser("localize-evaluate", help="trace, range and locate a POST /v1/localize/evaluate body; prints "
                        "the per-method error statistics beside the position bound", description="One trace from "
                        "the capsule to the sensors, Monte Carlo ranging, a fix per trial and method "
                        "(docs/localization.md, \"End-to-end evaluation\"); the answer is POST "
                        "/v1/localize/evaluate's.")
    le.add_argument("file", help="JSON file with the request body: {\"capsule\": {\"site\": ...}, \"sensors\": "
                    "[...], \"ranging\": \"gcc\", \"methods\": [...], \"trials\": 20, ...}")
    le.add_argument("--output", "-o", default=None, help="write the response JSON here instead of stdout")
    le.set_defaults(func=_cmd_localize)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
