"""Circular folds around a winding lumen's mid-line (vision.mucosa.FoldPath): the fold coordinate is the
arc length of the wall point's nearest mid-line point, the fold axis the mid-line's tangent there. Oracles:
a polygonal arc whose arc lengths are written here, and the fold height's closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vision.mucosa import FoldPath, MucosaTexture, texture_for

R_M = 0.05  # the mid-line: a quarter circle of 50 mm radius, a vertex every degree
STEP = math.radians(1.0)
ANGLES = np.arange(0, 91) * STEP
LINE = np.stack([R_M * np.cos(ANGLES), R_M * np.sin(ANGLES), np.zeros(91)], axis=1)
CHORD = 2 * R_M * math.sin(STEP / 2)


def _wall(k: np.ndarray, around: np.ndarray, r: float = 0.01) -> np.ndarray:
    """Points on the tube of radius r around the arc, at vertex k, at angle ``around`` about the arc."""
    theta = k * STEP
    radial = np.stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)], axis=1)
    up = np.array([0.0, 0.0, 1.0])
    return LINE[k] + r * (np.cos(around)[:, None] * radial + np.sin(around)[:, None] * up)


def test_arc_length_and_tangent_of_the_nearest_mid_line_point() -> None:
    path = FoldPath([LINE])
    assert path.length_m == pytest.approx(90 * CHORD, rel=1e-12)
    k = np.arange(2, 89)
    around = np.linspace(-math.pi / 2, math.pi / 2, len(k))
    s, t = path.query(_wall(k, around))
    # a wall point in the plane bisecting the polyline's angle at vertex k, on the convex side of the arc or
    # above it, is nearest to that vertex: s = k chords (on the concave side the nearest points lie on the
    # two segments beside it, equally far)
    np.testing.assert_allclose(s, k * CHORD, atol=1e-12)
    # the tangent of the segment it lies on (the one after the vertex, or the one before: both are within
    # half a degree of the arc's tangent there)
    arc_tangent = np.stack([-np.sin(k * STEP), np.cos(k * STEP), np.zeros(len(k))], axis=1)
    assert np.all(np.einsum("ij,ij->i", t, arc_tangent) > math.cos(STEP))
    # two polylines: the second's arc lengths continue after the first's
    two = FoldPath([LINE[:46], LINE[45:]])
    s2, _ = two.query(_wall(k, around))
    np.testing.assert_allclose(s2, k * CHORD, atol=1e-12)


def test_folds_ring_the_lumen_at_the_arc_length() -> None:
    """With colour, vessels, bumps and the folds' wander off and valleys fully dark, the albedo is the base
    reflectance times the fold height ((1 + cos 2 pi s / spacing) / 2)^p: a function of the arc length
    only, the same around the tube (the convex half of the arc's wall, where that arc length is k chords)."""
    path = FoldPath([LINE])
    texture = MucosaTexture(fold_path=path, colour_variation=0.0, vessel_strength=0.0, bump_mm=0.0, fold_warp=0.0,
                            valley_darkening=1.0, fold_sharpness=2.0, fold_spacing_mm=4.0)
    k = np.repeat(np.arange(3, 88, 7), 12)
    around = np.tile(np.linspace(-math.pi / 2, math.pi / 2, 12), len(np.arange(3, 88, 7)))
    points = _wall(k, around)
    normals = (LINE[k] - points) / np.linalg.norm(LINE[k] - points, axis=1)[:, None]  # facing the lumen
    albedo, _ = texture.shade_inputs(points, normals)
    s_mm = k * CHORD * 1e3
    fold = ((1 + np.cos(2 * math.pi * s_mm / 4.0)) / 2) ** 2
    np.testing.assert_allclose(albedo, np.asarray(texture.base_rgb)[None, :] * fold[:, None], atol=1e-9)


def test_only_phantoms_of_real_anatomy_fold_along_their_mid_line() -> None:
    from raytrace.body.centreline import Centreline

    class Real:
        metadata = {"source": "anatomy"}
        centrelines = {"gi_tract": Centreline([("small_intestine", LINE)])}

    class Torso(Real):
        metadata = {}

    real = texture_for("small_intestine", phantom=Real())
    assert real.fold_path is not None and real.fold_path.length_m == pytest.approx(90 * CHORD)
    assert texture_for("small_intestine", phantom=Torso()).fold_path is None  # the torso keeps its fixed axes
    assert texture_for("small_intestine", phantom=Real(), fold_axis=(0, 0, 1)).fold_path is None
    assert texture_for("stomach", phantom=Real()).fold_path is None  # rugae: no axis
