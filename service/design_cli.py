"""``capsule-rt design``: sensor-layout design from the command line (docs/design.md).

    capsule-rt design coverage SPEC.json --out DIR [--workers N] [--resume]
    capsule-rt design layout SPEC.json --coverage DIR [--out DIR]
    capsule-rt design plot DIR -o map.png [--metric snr_db] [--reduce median] [--layout DIR/result.json]

SPEC is a JSON (or YAML) file: a POST /v1/design/coverage body, or a POST /v1/design/layout body
without ``coverage`` (the coverage directory is given instead). Errors print the API's JSON
(``{"detail": [{"loc", "msg", "type"}]}``) and exit 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

__all__ = ["add_parser"]


def _error(exc: Exception) -> int:
    from service.errors import field_to_loc

    loc = field_to_loc(getattr(exc, "field", None))
    print(json.dumps({"detail": [{"loc": ["spec", *loc], "msg": getattr(exc, "reason", None) or str(exc),
                                  "type": type(exc).__name__}]}, indent=2), file=sys.stderr)
    return 2


def _read(path: str) -> dict:
    """A spec file: JSON by its suffix, else YAML read as the sweeps' specs are (``1e-6`` a number, not the
    string YAML 1.1 makes of it)."""
    from sweeps.spec import parse_text

    return parse_text(Path(path).read_text(), Path(path).suffix.lower())


def _coverage(args: argparse.Namespace) -> int:
    from design.coverage import run_coverage
    from raytrace.errors import InputError

    def progress(state: dict) -> None:
        print(f"{time.strftime('%H:%M:%S')} positions {state['done']}/{state['total']}"
              + (f", about {state['eta_s']:.0f} s left" if state.get("eta_s") else ""), file=sys.stderr)

    try:
        state = run_coverage(None if args.resume else _read(args.spec), args.out, workers=args.workers,
                             resume=args.resume, on_progress=progress)
    except InputError as exc:
        return _error(exc)
    print(json.dumps({k: state.get(k) for k in ("state", "done", "total", "elapsed_s", "error")}))
    return 0 if state["state"] == "done" else 1


def _layout(args: argparse.Namespace) -> int:
    from design.coverage import load
    from design.layout import normalise_layout, report_markdown, run_layout
    from raytrace.errors import InputError
    from sweeps.task import PhantomSource, phantom_for

    try:
        layout = normalise_layout(_read(args.spec))
        record, plan, table = load(args.coverage)
        phantom = phantom_for(PhantomSource(**record["source"]))
        t0 = time.process_time()
        result = run_layout(layout, record, plan, table, phantom,
                            check=lambda stage: print(f"{time.strftime('%H:%M:%S')} {stage}", file=sys.stderr))
    except InputError as exc:
        return _error(exc)
    result["cpu_s"] = time.process_time() - t0
    md = report_markdown(result, layout)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "result.json").write_text(json.dumps(result, indent=1, allow_nan=False))
        (out / "report.md").write_text(md)
    print(md)
    return 0


def _plot(args: argparse.Namespace) -> int:
    import numpy as np

    from design.coverage import CoverageDir, Plan
    from design.maps import UNITS, candidate_values
    from plots.coverage import skin_coverage
    from plots.figure import figure_bytes
    from raytrace.errors import InputError

    try:
        store = CoverageDir(args.coverage)
        plan = Plan.from_dict(store.record()["plan"])
        values = candidate_values(store.table(), len(plan.positions), len(plan.candidates), args.metric,
                                  args.position, args.reduce)
    except InputError as exc:
        return _error(exc)
    site = np.array([bool(s) for s in plan.candidates.site])
    chosen = None
    if args.layout:
        chosen = np.array([s["position_m"] for s in json.loads(Path(args.layout).read_text())["sensors"]])
    scale = 1e9 if args.metric.endswith("delay_s") else 1.0
    which = (f"position {args.position}" if args.position is not None
             else "fraction of positions" if args.metric in ("direct_path", "paths") else args.reduce)
    fig = skin_coverage(plan.candidates.positions_m[~site], values[~site] * scale, label=UNITS[args.metric],
                        sites_m=plan.candidates.positions_m[site], chosen_m=chosen, title=f"{args.metric} ({which})")
    Path(args.output).write_bytes(figure_bytes(fig, Path(args.output).suffix.lstrip(".") or "png"))
    return 0


def add_parser(sub) -> None:
    d = sub.add_parser("design", help="sensor-layout design: coverage over the skin, optimised layouts")
    dsub = d.add_subparsers(dest="design_command", required=True, metavar="WHAT")
    c = dsub.add_parser("coverage", help="coverage of a spec (a POST /v1/design/coverage body) into a directory")
    c.add_argument("spec", nargs="?", help="JSON or YAML spec (not needed with --resume)")
    c.add_argument("--out", required=True, help="the coverage's directory")
    c.add_argument("--workers", type=int, default=None, help="worker processes (default: the CPUs; 0: this one)")
    c.add_argument("--resume", action="store_true", help="go on with the positions still missing")
    c.set_defaults(func=_coverage)
    lay = dsub.add_parser("layout", help="optimise a layout (a POST /v1/design/layout body without coverage)")
    lay.add_argument("spec", help="JSON or YAML layout spec (a POST /v1/design/layout body without coverage)")
    lay.add_argument("--coverage", required=True, help="a done coverage's directory")
    lay.add_argument("--out", help="directory for result.json and report.md")
    lay.set_defaults(func=_layout)
    p = dsub.add_parser("plot", help="the coverage map, the skin unrolled")
    p.add_argument("coverage", help="a coverage's directory")
    p.add_argument("-o", "--output", required=True, help="map.png (or .svg, .pdf)")
    p.add_argument("--metric", default="snr_db",
                   choices=["snr_db", "rx_power_dbm", "path_gain_db", "first_delay_s", "eikonal_delay_s",
                            "direct_path", "paths"],
                   help="the quantity mapped over the skin (default snr_db)")
    p.add_argument("--reduce", default="median", choices=["median", "min", "max", "mean"],
                   help="how each candidate's values over the capsule positions become one (default median)")
    p.add_argument("--position", type=int, default=None, help="one capsule position's values")
    p.add_argument("--layout", help="a layout's result.json: its sensors circled")
    p.set_defaults(func=_plot)
