"""``python -m bench.fullwave CASE``: run one full-wave cross-check; ``python -m bench.fullwave table``: every
case at its two cell sizes and the one table of docs/validation.md (bench/fullwave/__init__.py); ``python -m
bench.fullwave exact``: the planar cases' reports against the exact layered field."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from bench.fullwave import CASES, GRID_PHANTOMS
from fullwave.run import compare, gprmax_available

#: Where every case writes its runs by default (``--out`` for one case, ``--out-dir`` for the table).
RESULTS = Path("bench/results/fullwave")


def run_case(name: str, out: Path, *, cell_mm: float = 2.0, coarse_factor: float | None = None, threads: int = 2,
             export_only: bool = False, reuse: bool = False) -> dict:
    """One case's :func:`fullwave.run.compare` report (at ``cell_mm`` and the case's second cell size)."""
    make, coarse = CASES[name]
    spec, phantom, options = make()
    coarse = coarse if coarse_factor is None else coarse_factor
    options = dataclasses.replace(options, cell_m=cell_mm * 1e-3)
    run = not export_only
    if run and not gprmax_available():
        print("gprMax is not installed (pip install -e '.[fullwave]'); writing the inputs only", file=sys.stderr)
        run = False
    return compare(spec, phantom, options, out, coarse_factor=coarse or None, run=run, threads=threads, reuse=reuse,
                   grid_phantom=GRID_PHANTOMS.get(name))


def table(reports: dict[str, dict]) -> str:
    """One Markdown table of every case and receiver: tracer - FDTD (gain, phase, group delay, envelope) at
    both cell sizes, the receiver's validity flags (docs/validation.md, "Every full-wave case")."""
    lines = ["| case | receiver | FDTD dB | tracer - FDTD: dB | deg | group delay ps | envelope ps | validity |",
             "|---|---|---|---|---|---|---|---|"]
    for name, report in reports.items():
        runs = [r for r in report["runs"] if r.get("ran")]
        if not runs:
            continue
        cells = " / ".join(f"{r['cell_m'] * 1e3:g}" for r in runs)
        for i, row in enumerate(runs[0]["receivers"]):
            rows = [r["receivers"][i] for r in runs]

            def both(key: str, scale: float, fmt: str) -> str:
                return " / ".join(format(r[key] * scale, fmt) for r in rows)

            flags = ", ".join(row.get("validity", ())) or "-"
            lines.append(f"| {name} ({cells} mm) | {row['receiver']} | {row['fdtd']['gain_db']:.2f} | "
                         f"{both('gain_error_db', 1.0, '+.2f')} | {both('phase_error_deg', 1.0, '+.1f')} | "
                         f"{both('group_delay_error_s', 1e12, '+.0f')} | {both('envelope_error_s', 1e12, '+.0f')} | "
                         f"{flags} |")
    return "\n".join(lines) + "\n"


def exact_table(out_dir: Path) -> str:
    """The planar cases' finished reports against the exact layered field (bench/fullwave/layered_exact.py):
    the ranges of tracer - exact (first cell size) and FDTD - exact (each cell size), docs/validation.md."""
    import json

    from bench.fullwave import PLANAR_LAYERS
    from bench.fullwave.layered_exact import case_rows, summary

    lines = ["| case | tracer - exact: dB / deg / group delay ps | FDTD - exact, 2 mm | FDTD - exact, 1.5 mm |",
             "|---|---|---|---|"]
    for name, layers in PLANAR_LAYERS.items():
        path = out_dir / name / "report.json"
        if path.exists():
            lines.append(summary(name, case_rows(json.loads(path.read_text()), layers)))
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.fullwave", description=__doc__)
    ap.add_argument("case", choices=sorted(CASES) + ["table", "exact"])
    ap.add_argument("--out", help="output directory of one case (default bench/results/fullwave/CASE)")
    ap.add_argument("--out-dir", default=str(RESULTS), help="the table's cases' parent directory")
    ap.add_argument("--cell-mm", type=float, default=2.0)
    ap.add_argument("--coarse-factor", type=float, default=None,
                    help="second run's cells / first's (0: none; default: the case's, bench/fullwave/__init__.py)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--export-only", action="store_true")
    ap.add_argument("--reuse", action="store_true",
                    help="do not re-run a cell size whose identical input already ran (rebuild the report)")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    knobs = dict(cell_mm=args.cell_mm, coarse_factor=args.coarse_factor, threads=args.threads,
                 export_only=args.export_only, reuse=args.reuse)
    if args.case == "exact":
        text = exact_table(Path(args.out_dir))
        (Path(args.out_dir) / "exact.md").write_text(text)
        sys.stdout.write(text)
        return 0
    if args.case == "table":
        reports = {name: run_case(name, Path(args.out_dir) / name, **knobs) for name in CASES}
        text = table(reports)
        (Path(args.out_dir) / "table.md").write_text(text)
        print(f"total {time.monotonic() - t0:.0f} s; {Path(args.out_dir) / 'table.md'}", file=sys.stderr)
        sys.stdout.write(text)
        return 0
    out = Path(args.out or Path(args.out_dir) / args.case)
    report = run_case(args.case, out, **knobs)
    for r in report["runs"]:
        if r.get("ran"):
            print(f"{r['cell_m'] * 1e3:g} mm cells: gprMax {r['wall_s']:.0f} s", file=sys.stderr)
    print(f"total {time.monotonic() - t0:.0f} s; {out / 'report.md'}", file=sys.stderr)
    sys.stdout.write((out / "report.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
