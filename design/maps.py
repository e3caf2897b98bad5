"""Per-candidate values of a coverage for maps (the plot, the viewer's layer; docs/design.md, "Coverage").

``metric`` is a link column (``snr_db``, ``rx_power_dbm``, ``path_gain_db``, ``first_delay_s``,
``eikonal_delay_s``, ``direct_path``, ``paths``); one capsule position (``position``) or every one
reduced by ``reduce`` (``median``, ``min``, ``max``, ``mean``; links without a path are left out;
``direct_path`` and ``paths`` reduce to the fraction of positions with one / the mean count).
"""

from __future__ import annotations

import numpy as np

from design.coverage import link_arrays
from design.errors import DesignInputError

METRICS = ("snr_db", "rx_power_dbm", "path_gain_db", "first_delay_s", "eikonal_delay_s", "direct_path", "paths")
REDUCTIONS = ("median", "min", "max", "mean")
UNITS = {"snr_db": "SNR [dB]", "rx_power_dbm": "received power [dBm]", "path_gain_db": "path gain [dB]",
         "first_delay_s": "first-arrival delay [ns]", "eikonal_delay_s": "eikonal delay [ns]",
         "direct_path": "positions with a direct path [-]", "paths": "paths [-]"}


def candidate_values(table, positions: int, candidates: int, metric: str = "snr_db", position: int | None = None,
                     reduce: str = "median") -> np.ndarray:
    """(C,) values of ``metric`` (module docstring); NaN where a candidate has none."""
    if metric not in METRICS:
        raise DesignInputError(f"must be one of {', '.join(METRICS)}", "metric")
    if reduce not in REDUCTIONS:
        raise DesignInputError(f"must be one of {', '.join(REDUCTIONS)}", "reduce")
    if len(table) != positions * candidates:
        raise DesignInputError("the coverage is not complete yet", "coverage")
    a = link_arrays(table, positions, candidates)[metric].astype(float)
    if position is not None:
        if not 0 <= position < positions:
            raise DesignInputError(f"must be in [0, {positions - 1}]", "position")
        return a[position]
    if metric in ("direct_path", "paths"):
        return a.mean(axis=0)
    fn = {"median": np.nanmedian, "min": np.nanmin, "max": np.nanmax, "mean": np.nanmean}[reduce]
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return fn(a, axis=0)
