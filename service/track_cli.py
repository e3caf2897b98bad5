"""``capsule-rt track``: a POST /v1/track body run in this process, or the journey experiment
(docs/tracking.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from service.local import local_registry, run_file_request


def _cmd_track(args: argparse.Namespace) -> int:
    if args.evaluate:
        from evaluation.tracking import evaluate_tracking, markdown_table
        from tracking import JourneySpec

        ev = evaluate_tracking(JourneySpec(steps=args.steps, seed=args.seed), rays=args.rays,
                               cache_dir=args.cache_dir)
        print(markdown_table(ev))
        if args.plot:
            from plots.figure import figure_bytes
            from plots.tracking import tracking_trajectory

            series = [{"name": n, "s_m": t.s_m.tolist(), "s_sigma_m": t.s_sigma_m.tolist()}
                      for n, t in ev.tracks.items()]
            fig = tracking_trajectory(ev.journey.t_s.tolist(), ev.journey.s_m.tolist(), series)
            Path(args.plot).write_bytes(figure_bytes(fig, Path(args.plot).suffix.lstrip(".") or "png"))
        return 0
    if not args.file:
        import json
        import sys

        print(json.dumps({"detail": [{"loc": ["file"], "msg": "give a POST /v1/track body, or --evaluate",
                                      "type": "missing"}]}), file=sys.stderr)
        return 2
    from raytrace.errors import CapsuleRTError
    from raytrace.solver.budget import Budget
    from service.operations.tracking import run_track
    from service.schemas.tracking import TrackRequest

    out = run_file_request(args.file, lambda body: run_track(TrackRequest.model_validate(body), local_registry()[0],
                                                             Budget()), (CapsuleRTError,))
    if out is None:
        return 2
    import json
    import sys

    sys.stdout.write(json.dumps(out, indent=1) + "\n")
    return 0


def add_parser(sub) -> None:
    """``capsule-rt track BODY.json`` (a POST /v1/track body, run locally) or ``--evaluate``."""
    t = sub.add_parser("track", help="track the capsule from a POST /v1/track body, or run the journey evaluation")
    t.add_argument("file", nargs="?", help="JSON file with a POST /v1/track body")
    t.add_argument("--evaluate", action="store_true",
                   help="run the default torso journey experiment (docs/tracking.md)")
    t.add_argument("--steps", type=int, default=400, help="journey steps (with --evaluate)")
    t.add_argument("--seed", type=int, default=0, help="journey seed (with --evaluate)")
    t.add_argument("--rays", type=int, default=20_000, help="rays per RF trace (with --evaluate)")
    t.add_argument("--cache-dir", default=None, help="keep traced RF grid positions here between runs")
    t.add_argument("--plot", default=None, help="write the trajectory plot here (.png, .svg, .pdf)")
    t.set_defaults(func=_cmd_track)
