"""``capsule-rt sweep`` and ``capsule-rt experiment``: sweeps from the command line (``docs/sweeps.md``).

    capsule-rt sweep SPEC --out DIR [--workers N | --cluster ADDRESS] [--resume] [--export csv,json]
    capsule-rt sweep --list
    capsule-rt experiment NAME --out DIR [--workers N | --cluster ADDRESS] [--resume]

SPEC is a .yaml / .json file or a built-in spec's name. A progress bar (tqdm, on stderr)
follows the tasks; a summary table per frequency and ranging method ends the run. Errors
print the same JSON as the API's (``{"detail": [{"loc", "msg", "type"}]}``) and exit 2; a
sweep that ends with failures exits 1.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

__all__ = ["add_parsers"]


def _error(exc: Exception) -> int:
    from service.errors import field_to_loc

    loc = field_to_loc(getattr(exc, "field", None))
    msg = getattr(exc, "reason", None) or str(exc)
    print(json.dumps({"detail": [{"loc": ["spec", *loc], "msg": msg, "type": type(exc).__name__}]}, indent=2),
          file=sys.stderr)
    return 2


class _Bar:
    """tqdm over traces (positions x frequencies), fed from the coordinator's progress states."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.bar = None

    def __call__(self, state: dict[str, Any]) -> None:
        from tqdm import tqdm

        if self.bar is None:
            self.bar = tqdm(total=state["total"], initial=state["done"], desc=self.label, unit="trace",
                            file=sys.stderr, dynamic_ncols=True)
        self.bar.update(state["done"] - self.bar.n)
        self.bar.set_postfix(tasks=f"{state['tasks_done']}/{state['tasks_total']}",
                             failures=state["failure_count"], refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _run_one(spec, out: Path, args: argparse.Namespace, label: str):
    from sweeps import run_sweep

    bar = _Bar(label)
    try:
        return run_sweep(spec, out, workers=args.workers, cluster=args.cluster, resume=args.resume, on_progress=bar)
    finally:
        bar.close()


def _print_summary(summary, spec) -> None:
    from sweeps.report import SUMMARY_COLUMNS, format_table, method_summary

    st = summary.state
    print(f"\nsweep {spec['name'] or summary.root.name}: {st['state']}, {st['done']}/{st['total']} traces, "
          f"{summary.results.num_rows} rows, {st['elapsed_s']:.1f} s on {st['engine']}; results in "
          f"{summary.root / 'results.parquet'}")
    table = summary.results
    if table.num_rows:
        paths = [p for p in table.column("paths").to_pylist()]
        print(f"links with a path: {sum(p > 0 for p in paths)}/{len(paths)}, paths per link "
              f"{min(paths)}-{max(paths)}")
    if spec.methods and table.num_rows:
        print(format_table(method_summary(table, spec.methods), SUMMARY_COLUMNS))
    for f in st["failures"][:10]:
        print(f"failure: {json.dumps(f, sort_keys=True)}")
    if st["failure_count"] > 10:
        print(f"... {st['failure_count'] - 10} more failures in {summary.root / 'state.json'}")


def _export(summary, formats: str) -> None:
    from sweeps.store import atomic_write
    from sweeps.table import to_csv_bytes, to_json_bytes

    for fmt in [f.strip() for f in formats.split(",") if f.strip()]:
        data = {"csv": to_csv_bytes, "json": to_json_bytes}[fmt](summary.results)
        atomic_write(summary.root / f"results.{fmt}", data)
        print(f"wrote {summary.root / f'results.{fmt}'}")


def _cmd_sweep(args: argparse.Namespace) -> int:
    from raytrace.errors import CapsuleRTError
    from sweeps import load_spec
    from sweeps.experiments import builtin_specs

    if args.list:
        for name, path in sorted(builtin_specs().items()):
            text = path.read_text()
            desc = next((ln.strip() for ln in text.splitlines()[2:4] if ln.strip()), "")
            print(f"{name:32s} {desc}")
        return 0
    if not args.spec or not args.out:
        print("capsule-rt sweep: SPEC and --out are required (or --list)", file=sys.stderr)
        return 2
    try:
        spec = load_spec(args.spec)
        summary = _run_one(spec, Path(args.out), args, spec["name"] or Path(args.spec).stem)
    except (CapsuleRTError, ValueError) as exc:
        return _error(exc)
    _print_summary(summary, spec)
    if args.export:
        _export(summary, args.export)
    return 0 if summary.state["state"] == "done" else 1


def _cmd_experiment(args: argparse.Namespace) -> int:
    from raytrace.errors import CapsuleRTError
    from sweeps import load_spec
    from sweeps.experiments import EXPERIMENTS, write_report

    if args.name not in EXPERIMENTS:
        print(f"unknown experiment {args.name!r}; built-in: {', '.join(EXPERIMENTS)}", file=sys.stderr)
        return 2
    exp = EXPERIMENTS[args.name]
    out = Path(args.out)
    tables, status = {}, 0
    for name in exp.specs:
        try:
            spec = load_spec(name)
            summary = _run_one(spec, out / name, args, name)
        except (CapsuleRTError, ValueError) as exc:
            return _error(exc)
        _print_summary(summary, spec)
        tables[name] = summary.results
        status |= summary.state["state"] != "done"
    print()
    print(write_report(exp.name, out, tables))
    print(f"wrote {out / 'report.md'} and {out / 'report.json'}")
    return int(status)


EXPERIMENT_HELP = "run one of the thesis' experiments and report ours beside its numbers"


def add_parsers(sub, experiment: bool = True) -> None:
    """Register ``sweep`` and ``experiment`` on ``capsule-rt``'s subparsers (``experiment`` False:
    the latter by name only, without importing the sweeps to list its choices)."""
    s = sub.add_parser("sweep", help="run a sweep (positions x receivers x frequencies) with progress and a summary",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    s.add_argument("spec", nargs="?", help="sweep spec: a .yaml/.json file or a built-in name (see --list)")
    s.add_argument("--out", "-o", help="output directory: one sweep (results.parquet, parts/, state.json)")
    s.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: the CPUs of this machine; 0 = in this process)")
    s.add_argument("--cluster", default=None,
                   help="address of an existing Dask scheduler (tcp://host:8786) to run the tasks on instead")
    s.add_argument("--resume", action="store_true",
                   help="continue the sweep already in --out (same spec): only missing tasks are computed")
    s.add_argument("--export", default="", help="also write results.csv and/or results.json (e.g. csv,json)")
    s.add_argument("--list", action="store_true", help="list the built-in specs and exit")
    s.set_defaults(func=_cmd_sweep)
    if not experiment:
        sub.add_parser("experiment", help=EXPERIMENT_HELP)
        return
    from sweeps.experiments import EXPERIMENTS

    e = sub.add_parser("experiment", help=EXPERIMENT_HELP)
    e.add_argument("name", choices=sorted(EXPERIMENTS), help="experiment: " + "; ".join(
        f"{n}: {x.description}" for n, x in EXPERIMENTS.items()))
    e.add_argument("--out", "-o", required=True, help="output directory (one sub-directory per sweep, report.md)")
    e.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: the CPUs of this machine; 0 = in this process)")
    e.add_argument("--cluster", default=None, help="address of an existing Dask scheduler to run the tasks on")
    e.add_argument("--resume", action="store_true", help="continue the experiment's sweeps already in --out")
    e.set_defaults(func=_cmd_experiment)
