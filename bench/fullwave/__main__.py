"""``python -m bench.fullwave CASE``: run one full-wave cross-check (bench/fullwave/__init__.py)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from bench.fullwave import CASES, GRID_PHANTOMS
from fullwave.run import compare, gprmax_available


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.fullwave", description=__doc__)
    ap.add_argument("case", choices=sorted(CASES))
    ap.add_argument("--out", help="output directory (default bench/results/fullwave/CASE)")
    ap.add_argument("--cell-mm", type=float, default=2.0)
    ap.add_argument("--coarse-factor", type=float, default=None,
                    help="second run's cells / first's (0: none; default: the case's, bench/fullwave/__init__.py)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--export-only", action="store_true")
    ap.add_argument("--reuse", action="store_true",
                    help="do not re-run a cell size whose identical input already ran in --out (rebuild the report)")
    args = ap.parse_args(argv)
    make, coarse = CASES[args.case]
    spec, phantom, options = make()
    coarse = coarse if args.coarse_factor is None else args.coarse_factor
    options = dataclasses.replace(options, cell_m=args.cell_mm * 1e-3)
    out = Path(args.out or f"bench/results/fullwave/{args.case}")
    run = not args.export_only
    if run and not gprmax_available():
        print("gprMax is not installed (pip install -e '.[fullwave]'); writing the inputs only", file=sys.stderr)
        run = False
    t0 = time.monotonic()
    report = compare(spec, phantom, options, out, coarse_factor=coarse or None, run=run,
                     threads=args.threads, reuse=args.reuse,
                     grid_phantom=GRID_PHANTOMS.get(args.case))
    for r in report["runs"]:
        if r.get("ran"):
            print(f"{r['cell_m'] * 1e3:g} mm cells: gprMax {r['wall_s']:.0f} s", file=sys.stderr)
    print(f"total {time.monotonic() - t0:.0f} s; {out / 'report.md'}", file=sys.stderr)
    sys.stdout.write((out / "report.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
