"""Phantoms from a labelled NIfTI volume the test makes (nested ellipsoids and a closed tube): volumes,
positions and tissues against closed forms; the affine (a mirrored axis, a translation) honoured."""

from __future__ import annotations

import math

import nibabel
import numpy as np
import pytest

from raytrace.body.anatomy import build_phantom

SPACING_MM = 2.0
SHAPE = (80, 72, 100)
# affine: x mirrored (as in RAS volumes read from LPS scanners), an arbitrary translation
AFFINE = np.array([[-SPACING_MM, 0, 0, 90.0], [0, SPACING_MM, 0, -70.0], [0, 0, SPACING_MM, 15.0], [0, 0, 0, 1]])
BODY = ((0.0, 0.0, 110.0), (70.0, 60.0, 90.0))  # world centre, semi-axes [mm]
ORGAN = ((-20.0, 10.0, 90.0), (30.0, 20.0, 25.0))
TUBE = ((25.0, -15.0, 120.0), 8.0, 60.0)  # centre, radius, length along z [mm]


def _world() -> np.ndarray:
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in SHAPE], indexing="ij"), axis=-1).reshape(-1, 3)
    return (ijk @ AFFINE[:3, :3].T + AFFINE[:3, 3]).reshape(*SHAPE, 3)


def make_labels(path) -> None:
    p = _world()
    labels = np.zeros(SHAPE, np.int16)
    (c, a) = BODY
    labels[(((p - c) / a) ** 2).sum(axis=-1) <= 1] = 1
    (c, a) = ORGAN
    labels[(((p - c) / a) ** 2).sum(axis=-1) <= 1] = 2
    (c, r, length) = TUBE
    d = p - c
    labels[(d[..., 0] ** 2 + d[..., 1] ** 2 <= r**2) & (np.abs(d[..., 2]) <= length / 2)] = 3
    image = nibabel.Nifti1Image(labels, AFFINE)
    image.header.set_xyzt_units("mm")
    nibabel.save(image, str(path))


def test_nested_ellipsoids_and_a_tube_from_a_labelmap(tmp_path) -> None:
    make_labels(tmp_path / "labels.nii.gz")
    manifest = {"name": "labelled", "units": "mm", "volume": "labels.nii.gz",
                "labels": {1: "body_trunc", 2: "liver", 3: "colon"},
                "body": {"label": 1, "fill": "muscle"},
                "organs": {"liver": {"label": 2}, "tube": {"label": "colon"}},
                "options": {"smoothing_voxels": 0.5}}
    result = build_phantom(manifest, tmp_path)
    phantom = result.phantom
    organs = {o.name: o for o in phantom.organs}
    assert organs["liver"].material.tissue == "liver" and organs["tube"].material.tissue == "colon"
    parent = {o.name: phantom.medium_name(int(phantom.parent[i])) for i, o in enumerate(phantom.organs)}
    assert parent == {"body": "air", "liver": "body", "tube": "body"}
    # Closed forms. Tolerances: the surface follows the voxels' boundary, whose volume differs from the
    # shape's by the voxels cut by the surface (random signs: a fraction of a percent here), and a Gaussian
    # of 0.5 voxel (1 mm) pulls a convex surface in by about sigma^2 * mean curvature, i.e. 1 mm^2 / 8 mm
    # = 0.13 mm on the tube (3 % of its volume), less on the ellipsoids.
    (_, a) = BODY
    assert organs["body"].mesh.volume == pytest.approx(4 / 3 * math.pi * np.prod(a) * 1e-9, rel=0.02)
    (c_organ, a) = ORGAN
    assert organs["liver"].mesh.volume == pytest.approx(4 / 3 * math.pi * np.prod(a) * 1e-9, rel=0.03)
    (c_tube, r, length) = TUBE
    assert organs["tube"].mesh.volume == pytest.approx(math.pi * r**2 * length * 1e-9, rel=0.05)
    # The affine: centres where the world coordinates put them (within half a voxel); extents its semi-axes.
    np.testing.assert_allclose(organs["liver"].mesh.bounds.mean(axis=0) * 1e3, c_organ, atol=1.0)
    np.testing.assert_allclose(np.ptp(organs["liver"].mesh.bounds, axis=0) * 1e3, 2 * np.asarray(a), atol=2.5)
    np.testing.assert_allclose(organs["tube"].mesh.bounds.mean(axis=0) * 1e3, c_tube, atol=1.0)
    # Surfaces: area of the tube against the closed form (side + two caps), the caps' rims rounded by the
    # smoothing and the side faceted by the voxels (5 %).
    assert organs["tube"].mesh.area == pytest.approx((2 * math.pi * r * length + 2 * math.pi * r**2) * 1e-6, rel=0.08)
    assert any("label 2" in r for r in result.report["organs"][1]["repairs"])
