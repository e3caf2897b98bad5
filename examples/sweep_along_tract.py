"""A sweep along the GI tract: the capsule every few centimetres along the default torso's
centreline, every skin sensor, TOA by generalized cross-correlation, and a nonlinear fix per
position (examples/sweep.yaml, docs/sweeps.md); prints the table's size and the median 3-D error
and draws the localization error against the arc length (organ junctions marked).

    python examples/sweep_along_tract.py [--spec examples/sweep.yaml] [--ds-mm 50] [--rays 2000] [--workers 2]
                                         [--out DIR]
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from _common import parser, save

from plots import tract_errors
from raytrace.body.torso import default_torso
from sweeps import load_spec, run_sweep
from sweeps.spec import parse_text

HERE = Path(__file__).resolve().parent


def main(argv=None) -> None:
    p = parser(__doc__)
    p.add_argument("--spec", type=Path, default=HERE / "sweep.yaml")
    p.add_argument("--ds-mm", type=float, default=None, help="capsule spacing along the tract (default: the spec's)")
    p.add_argument("--rays", type=int, default=None, help="rays per trace (default: the spec's)")
    p.add_argument("--trials", type=int, default=None, help="Monte Carlo trials (default: the spec's)")
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    body = parse_text(args.spec.read_text())  # the spec as data (sweeps' YAML reading), to override knobs
    if args.ds_mm:
        body["capsule_positions"]["along_tract"]["ds_m"] = args.ds_mm / 1e3
    if args.rays:
        body["channel"]["rays"] = args.rays
    if args.trials:
        body["trials"] = args.trials
    with tempfile.TemporaryDirectory() as runs:
        summary = run_sweep(load_spec(body), Path(runs) / "sweep", workers=args.workers)
    rows = summary.localization.to_pylist()
    errors = np.array([r["error_m"] for r in rows if r["error_m"] is not None])
    print(f"{summary.results.num_rows} ranging rows, {len(rows)} fixes: median 3-D error "
          f"{np.median(errors) * 1e3:.1f} mm")
    line = default_torso().centrelines["gi_tract"]
    save(tract_errors(rows, junctions_s_m=list(line.junctions_s_m), title="Nonlinear TOA fixes along the GI tract"),
         args.out, "tract_errors.png")


if __name__ == "__main__":
    main()
