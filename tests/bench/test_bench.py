"""The benchmark harness keeps working (it measures, it never asserts speed)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import trimesh

from bench.ceiling import embree_ceiling, fibonacci_directions
from bench.common import ROOT, growth_exponent, run_point
from raytrace.body.phantom import Material, Organ, Phantom


def test_growth_exponent_recovers_a_power_law() -> None:
    x = np.array([1e4, 3e4, 1e5, 3e5])
    assert growth_exponent(x, 2.0 * x**1.5) == pytest.approx(1.5, abs=1e-9)
    assert np.isnan(growth_exponent([1.0], [1.0]))


def test_fibonacci_directions_are_unit_and_balanced() -> None:
    d = fibonacci_directions(10_000)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=1e-3)


def test_ceiling_counts_primary_and_secondary_rays() -> None:
    sphere = trimesh.creation.icosphere(3, radius=0.1)
    phantom = Phantom.build("s", [Organ("body", Material(relative_permittivity=50.0), sphere)])
    out = embree_ceiling(phantom, np.array([0.01, 0.0, 0.0]), rays=2000, repeat=1)
    # Every primary ray from inside a closed sphere hits it, so each spawns one secondary.
    assert out["rays_cast"] == 4000 and out["triangles"] == 1280
    assert min(out["rays_per_s"], out["robust_rays_per_s"], out["embreex_rays_per_s"]) > 0


@pytest.mark.slow
def test_scaling_point_runs_in_a_fresh_process() -> None:
    out = run_point(["--rays", "2000", "--receivers", "2", "--interactions", "2", "--resolution", "24"])
    assert out["receivers"] == 2 and out["triangles"] > 1000
    assert out["peak_rss_mb"] >= out["rss_before_trace_mb"] > 0


def test_peak_memory_of_a_child_excludes_the_parents() -> None:
    """A child's ``ru_maxrss`` inherits the parent's high-water mark through fork + exec (the
    bench's scaling points all reported the bench's own 460 MB): the point's measure must not."""
    ballast = np.ones(400 * 1024 * 1024 // 8)  # the parent holds 400 MB, touched
    code = "from bench.point import peak_rss_mb; print(peak_rss_mb())"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert ballast.sum() > 0
    # a bare interpreter that imported numpy/trimesh/embree: well under the parent's ballast
    assert 5.0 < float(out.stdout) < 300.0


def test_completeness_compares_the_default_with_a_denser_launch() -> None:
    from bench.completeness import completeness

    out = completeness(rays=3000, interactions=2, dense_factor=2)
    assert out["dense_rays"] == 6000 and out["receivers"] == 12
    assert 0 <= out["strongest_missed"] <= out["receivers"]
    assert 0 <= out["strong_found"] <= out["strong_paths"] and out["strong_paths"] >= 1
