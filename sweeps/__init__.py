"""CapsuleRT sweeps: grids of channel computations along the GI tract, on a local pool or a Dask cluster.

    from sweeps import load_spec, run_sweep

    spec = load_spec("thesis-ch4-toa-heterogeneous")         # a built-in spec, a .yaml/.json file or a dict
    summary = run_sweep(spec, "out/toa", workers=2)           # or cluster="tcp://scheduler:8786"
    summary.results.to_pylist()                               # one row per (position, frequency, receiver)

Modules, one job each: :mod:`sweeps.spec` (the validated spec), :mod:`sweeps.plan`
(the spec placed in its phantom, cut into tasks), :mod:`sweeps.task` (one task, in a
worker), :mod:`sweeps.engines` (serial, local processes, Dask), :mod:`sweeps.store` (the
sweep directory, atomic Parquet parts), :mod:`sweeps.run` (the coordinator),
:mod:`sweeps.table` (columns and exports), :mod:`sweeps.localization` (per-position
localizers), :mod:`sweeps.pathloss` (a path-loss model fitted to a sweep) and
:mod:`sweeps.experiments` (the thesis' experiments as built-in specs). ``docs/sweeps.md``.
"""

from sweeps.run import SweepSummary, run_sweep
from sweeps.spec import LIMITS, Limits, SweepSpec, SweepSpecError, load_spec

__all__ = ["LIMITS", "Limits", "SweepSpec", "SweepSpecError", "SweepSummary", "load_spec", "run_sweep"]
