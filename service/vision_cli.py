"""``capsule-rt vision render`` and ``capsule-rt vision motion``: capsule camera sequences along the
GI-tract centreline and MI motion estimates between their frames, locally (docs/vision.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

from service.local import error_json, local_registry

__all__ = ["add_parsers"]


def _vision_render_seq(args: argparse.Namespace) -> int:
    """Render a capsule moving along the phantom's GI-tract centreline: frame_NNNN.png, and
    sequence.json (the settings and every frame's exact pose) in ``--out``."""
    from raytrace.errors import CapsuleRTError
    from service.errors import ServiceError
    from service.schemas.vision import SensorIn
    from vision.camera import FisheyeCamera
    from vision.errors import VisionInputError
    from vision.mucosa import texture_for
    from vision.png import encode_png
    from vision.sensor import SensorModel
    from vision.sequence import centreline_path, render_sequence

    registry, _ = local_registry()
    try:
        phantom = registry.get(args.phantom)
        length = args.advance_m * (args.frames - 1)
        path, offset, organ = centreline_path(phantom, args.start_s_m, length)
        sensor = SensorIn(salt_pepper=args.salt_pepper, read_noise=args.read_noise, seed=args.seed)
        seq = render_sequence(phantom, path, args.frames, args.advance_m, args.roll_deg,
                              FisheyeCamera(args.fov_deg, args.size_px), start_m=offset,
                              start_roll_deg=args.start_roll_deg,
                              texture=texture_for(organ, seed=args.seed, phantom=phantom),
                              sensor=SensorModel(**sensor.model_dump()), organ=organ)
    except (VisionInputError, CapsuleRTError, ServiceError) as exc:  # a refusal, as the API's error JSON
        print(json.dumps(error_json(exc), indent=2), file=sys.stderr)
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

    from service.operations.vision import advance_of, estimate_pair, frame_from_png
    from service.schemas.vision import MotionOptions
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
    phantom = local_registry()[0].get(truth["phantom"]) if truth else None
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
                                 texture=texture_for(truth["organ"], seed=truth["seed"], phantom=phantom),
                                 exposure=truth["exposure"])
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


def add_parsers(sub) -> None:
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
