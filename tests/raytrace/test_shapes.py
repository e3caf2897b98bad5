"""Closed solids the built-in phantoms are made of: closed, outward, the right size.

Oracles: closed-form volumes (ellipsoid 4/3 pi abc; the superquadric of
revolution, via the Beta function; cylinder pi ab h), and exact vertex
positions on the straight side of a rounded cylinder.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import beta

from raytrace.body.shapes import box, lathe, rounded_cylinder, superquadric


@pytest.mark.parametrize("axis", ["x", "y", "z"])
@pytest.mark.parametrize("exponent", [2.0, 4.0, 10.0])
def test_superquadric_closed_outward_and_bounded(axis: str, exponent: float) -> None:
    mesh = superquadric([0.1, -0.2, 0.3], [0.03, 0.02, 0.05], exponent, segments=32, rings=16, axis=axis)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert len(mesh.faces) == 2 * 32 * (16 - 1)
    own = {"z": [0.03, 0.02, 0.05], "x": [0.05, 0.03, 0.02], "y": [0.02, 0.05, 0.03]}[axis]
    np.testing.assert_allclose(mesh.bounds[1] - mesh.bounds[0], 2 * np.array(own), rtol=1e-12)


@pytest.mark.parametrize("exponent", [2.0, 4.0])
def test_superquadric_volume_converges_to_closed_form(exponent: float) -> None:
    # V = 2 pi a b c int_0^1 (1 - t^p)^(2/p) dt = 2 pi a b c B(1/p, 2/p + 1) / p.
    # (p = 2: 4/3 pi abc.) Inscribed facets undershoot by O(1/n^2): at
    # 256 x 128 the deficit is 2.5e-4 for both exponents; tolerance 1e-3.
    a, b, c = 0.03, 0.02, 0.05
    exact = 2 * np.pi * a * b * c * beta(1 / exponent, 2 / exponent + 1) / exponent
    if exponent == 2.0:
        assert exact == pytest.approx(4 / 3 * np.pi * a * b * c, rel=1e-12)
    mesh = superquadric([0, 0, 0], [a, b, c], exponent, segments=256, rings=128)
    assert mesh.volume < exact
    assert mesh.volume == pytest.approx(exact, rel=1e-3)


def test_rounded_cylinder_side_is_the_exact_elliptic_cylinder() -> None:
    a, b, c, rim = 0.16, 0.12, 0.26, 0.03
    mesh = rounded_cylinder([0, 0, 0], [a, b, c], rim_height_m=rim, rim_fraction=0.25,
                            segments=48, rings=24)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert len(mesh.faces) == 2 * 48 * (24 - 1)
    v = mesh.vertices
    side = np.abs(v[:, 2]) <= c - rim + 1e-12
    np.testing.assert_allclose((v[side, 0] / a) ** 2 + (v[side, 1] / b) ** 2, 1.0, rtol=1e-12)
    ends = np.isclose(np.abs(v[:, 2]), c)
    assert ends.sum() > 48  # flat end discs, not a single pole ring
    # Volume between the inscribed polygon prism (side) and the full
    # elliptic cylinder: the rims remove a little, the facets a little more.
    polygon_area = 0.5 * 48 * a * b * np.sin(2 * np.pi / 48)
    assert mesh.volume < polygon_area * 2 * c
    assert mesh.volume > polygon_area * 2 * (c - rim)


def test_shrunken_rounded_cylinder_nests_inside() -> None:
    outer = rounded_cylinder([0, 0, 0], [0.16, 0.12, 0.26], rim_height_m=0.03, rim_fraction=0.25,
                             segments=48, rings=24)
    inner = rounded_cylinder([0, 0, 0], [0.158, 0.118, 0.258], rim_height_m=0.03, rim_fraction=0.25,
                             segments=48, rings=24)
    assert outer.contains(inner.vertices).all()


def test_box_and_bad_arguments() -> None:
    mesh = box([0, 0, 0], [1, 2, 3])
    assert mesh.is_watertight and mesh.volume == pytest.approx(6.0)
    with pytest.raises(ValueError):
        box([0, 0, 0], [1, 0, 3])
    with pytest.raises(ValueError):
        superquadric([0, 0, 0], [1, -1, 1])
    with pytest.raises(ValueError):
        rounded_cylinder([0, 0, 0], [1, 1, 1], rim_height_m=2.0, rim_fraction=0.5)
    with pytest.raises(ValueError):
        lathe([0, 0, 0], 1, 1, [1, 0, -1], [0.5, 1, 0], segments=8)  # no top pole
    with pytest.raises(ValueError):
        superquadric([0, 0, 0], [1, 1, 1], axis="w")
