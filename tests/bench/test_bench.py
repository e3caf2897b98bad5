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


def test_sionna_room_matches_paths_to_the_oracle_within_float32() -> None:
    """bench/sionna_room.py counts a tool's path as an oracle path when the reflection count
    agrees, the delay is within 1 ps and the points within 1 mm (Sionna computes in float32):
    a float32-rounded copy matches, a path 1 cm off or with another count does not, and an
    oracle path is counted once however many copies were returned."""
    from bench.sionna_room import matched

    pts = np.array([[3.0, 0.2, -0.4], [-1.0, 2.5, 0.3]])
    oracle = [[{"n": 2, "delay_s": 3.3e-8, "points_m": pts}, {"n": 0, "delay_s": 1e-8, "points_m": np.zeros((0, 3))}]]
    f32 = {"n": 2, "delay_s": float(np.float32(3.3e-8)), "points_m": pts.astype(np.float32).tolist()}
    off = {"n": 2, "delay_s": 3.3e-8, "points_m": (pts + [0.01, 0.0, 0.0]).tolist()}
    los = {"n": 0, "delay_s": 1e-8 + 2e-12, "points_m": []}
    assert matched([[f32, f32]], oracle) == 1
    assert matched([[off, los]], oracle) == 0
    assert matched([[off, dict(los, delay_s=1e-8)]], oracle) == 1


def test_sionna_room_receivers_are_inside_the_room_and_apart() -> None:
    from bench.sionna_room import ROOM_HI, ROOM_LO, SPHERE_CENTRE, SPHERE_RADIUS, TX, receiver_positions

    rx = receiver_positions(64)
    assert len(rx) == 64 and np.array_equal(rx, receiver_positions(64))  # seeded
    assert (rx > ROOM_LO).all() and (rx < ROOM_HI).all()
    assert (np.linalg.norm(rx - TX, axis=1) > 0.5).all()
    assert (np.linalg.norm(rx - SPHERE_CENTRE, axis=1) > SPHERE_RADIUS + 0.3).all()


def test_sionna_room_says_why_when_sionna_cannot_run(monkeypatch, capsys) -> None:
    """Without Dr.Jit's LLVM the script exits with status 2 and the reason, installing nothing."""
    from bench import sionna_room

    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/nonexistent/libLLVM.so")
    monkeypatch.setattr(sionna_room, "sionna_python", lambda: pytest.fail("must not install"))
    assert sionna_room.main(["--receivers", "1"]) == 2
    assert "DRJIT_LIBLLVM_PATH=/nonexistent/libLLVM.so does not exist" in capsys.readouterr().err


def test_readme_table_is_rewritten_between_its_markers(tmp_path, monkeypatch) -> None:
    """bench/readme.py replaces only what lies between the markers, and refuses a file without them."""
    import pytest

    from bench import readme

    monkeypatch.setattr(readme, "table", lambda report: "| a | 1 | — |")
    path = tmp_path / "README.md"
    path.write_text(f"# x\n\nbefore\n{readme.START}\nold table\n{readme.END}\nafter\n")
    readme.write({}, str(path))
    assert path.read_text() == f"# x\n\nbefore\n{readme.START}\n| a | 1 | — |\n{readme.END}\nafter\n"
    path.write_text("no markers\n")
    with pytest.raises(ValueError, match="markers"):
        readme.write({}, str(path))
