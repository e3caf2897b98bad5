"""A tiny coverage of the default torso, made once per session for the design tests: one capsule
site, candidates every 50 mm on a band of the skin (plus the 12 sensor sites), 3000 rays, 6 mm travel-time cells."""

from __future__ import annotations

import pytest

TINY_COVERAGE = {
    "phantom": "torso",
    "positions": {"sites": ["small_intestine_1", "transverse_colon"]},
    "candidates": {"spacing_m": 0.05, "region": {"min_m": [-1, -1, 0.0], "max_m": [1, 1, 0.15]}},
    "channel": {"rays": 3000, "max_interactions": 2, "dynamic_range_db": 30},
    "cell_size_m": 0.006,
}


@pytest.fixture(scope="session")
def tiny_coverage(tmp_path_factory):
    from design.coverage import run_coverage

    out = tmp_path_factory.mktemp("design") / "coverage"
    state = run_coverage(TINY_COVERAGE, out, workers=0)
    assert state["state"] == "done", state
    return out
