"""The path-loss reports' medians by distance (sweeps.experiments._median_path_loss): links without a
path are left out, each link falls in the bin [lo, hi) of its distance, empty bins are not reported.
Oracle: numpy's median of the same links, picked here by hand."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from sweeps.experiments import CM2, PATH_LOSS_BINS_M, _median_path_loss


def test_medians_per_distance_bin() -> None:
    distance = [0.08, 0.09, 0.095, 0.10, 0.12, 0.15, 0.30, 0.05, 0.45]
    gain = [-40.0, -50.0, None, -61.0, -70.0, -80.0, -99.0, -10.0, -150.0]
    rows = _median_path_loss(pa.table({"distance_m": distance, "path_gain_db": gain}))
    assert [r["bin"] for r in rows] == ["70-100", "100-130", "130-160", "250-310"]
    # 70-100 mm: 40 and 50 dB (the 95 mm link has no path; 100 mm belongs to the next bin)
    assert rows[0]["links"] == 2 and rows[0]["median_db"] == pytest.approx(np.median([40.0, 50.0]))
    assert rows[1]["links"] == 2 and rows[1]["median_db"] == pytest.approx(np.median([61.0, 70.0]))
    assert rows[2]["median_db"] == 80.0 and rows[3]["median_db"] == 99.0
    lo, hi = PATH_LOSS_BINS_M[0]
    assert rows[0]["cm2_db"] == pytest.approx(float(CM2.path_loss_db(0.5 * (lo + hi))))
