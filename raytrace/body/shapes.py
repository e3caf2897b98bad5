"""Closed, outward-oriented triangle meshes of simple smooth solids.

Every builtin phantom is made of these: solids of revolution with an
elliptic cross-section (:func:`lathe`): superquadrics (an ellipsoid for
exponent 2, a capsule-like rounded elliptic tube for larger exponents),
rounded elliptic cylinders (straight side, flat ends, rounded rims), and
axis-aligned boxes.

Superquadric, axis along z, semi-axes (a, b, c), exponent p::

    (x^2 / a^2 + y^2 / b^2)^(p/2) + |z / c|^p = 1

i.e. the cross-section at height z is an ellipse of semi-axes
``(a rho, b rho)`` with ``rho = (1 - |z/c|^p)^(1/p)``. It is sampled with the
usual superquadric parametrisation ``z = c sgn(cos phi) |cos phi|^(2/p)``,
``rho = sin(phi)^(2/p)``, which puts rings densely where the profile bends
(the rounded rim of a capsule) and sparsely along its straight side. No
sharp edge exists anywhere, so the smooth vertex normals the tracer
interpolates are meaningful everywhere (a flat-capped cylinder would blend
cap and side normals over the whole first row of side triangles).

Nesting property used by the phantoms: shrinking every semi-axis (same
exponent, same centre) gives a solid strictly inside the original one,
analytically. The faceted meshes are inscribed in the analytic surfaces, so
two nested surfaces stay nested when their gap exceeds the chord sagitta
(about ``r pi^2 / (2 n^2)`` for ``n`` segments around a radius ``r``);
:class:`~raytrace.body.phantom.Phantom` validation checks it for every build.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import trimesh


def superquadric(
    center_m: Sequence[float],
    semi_axes_m: Sequence[float],
    exponent: float = 2.0,
    *,
    segments: int = 48,
    rings: int = 24,
    axis: str = "z",
) -> trimesh.Trimesh:
    """Watertight, outward-oriented superquadric of revolution (see module doc).

    ``semi_axes_m`` are (a, b, c) along the mesh's own x, y and symmetry axis
    (``axis``: see :func:`lathe`). ``segments`` points around each ring,
    ``rings - 1`` rings between the two poles: ``2 * segments * (rings - 1)``
    triangles.
    """
    a, b, c = (float(v) for v in semi_axes_m)
    if min(a, b, c) <= 0 or rings < 2 or exponent < 1.0:
        raise ValueError("superquadric needs positive semi-axes, rings >= 2, exponent >= 1")
    phi = np.pi * np.arange(0, rings + 1) / rings  # poles included, top to bottom
    cos_phi = np.cos(phi)
    z = c * np.sign(cos_phi) * np.abs(cos_phi) ** (2.0 / exponent)
    rho = np.abs(np.sin(phi)) ** (2.0 / exponent)
    rho[0] = rho[-1] = 0.0
    return lathe(center_m, a, b, z, rho, segments=segments, axis=axis)


def rounded_cylinder(
    center_m: Sequence[float],
    semi_axes_m: Sequence[float],
    *,
    rim_height_m: float,
    rim_fraction: float,
    segments: int = 48,
    rings: int = 24,
    axis: str = "z",
) -> trimesh.Trimesh:
    """Elliptic cylinder with flat ends joined to the side by rounded rims.

    Semi-axes (a, b, c): the side ``|z| <= c - rim_height_m`` is exactly the
    elliptic cylinder of semi-axes (a, b) (straight, so any cross-section
    there is the same polygon); each rim is a quarter ellipse in the
    (rho, z) profile from rho = 1 down to ``1 - rim_fraction`` over
    ``rim_height_m``, tangent to the side and to the flat end disc (C1: no
    crease, smooth normals stay meaningful). ``rings - 1`` rings between the
    poles as in :func:`superquadric`, so the triangle count is the same
    ``2 * segments * (rings - 1)``.

    Nesting: shrinking a, b and c by a positive amount at the same rim
    height and fraction gives a solid strictly inside.
    """
    a, b, c = (float(v) for v in semi_axes_m)
    r, f = float(rim_height_m), float(rim_fraction)
    if min(a, b, c) <= 0 or not (0 < r < c) or not (0 < f < 1) or rings < 8:
        raise ValueError("rounded_cylinder needs 0 < rim_height < c, 0 < rim_fraction < 1, rings >= 8")
    n_cap = max(2, rings // 8)
    n_rim = max(2, rings // 8)
    n_side = rings - 2 * n_cap - 2 * n_rim
    cap_rho = (1.0 - f) * np.arange(0, n_cap) / n_cap  # pole .. last cap ring
    t = 0.5 * np.pi * (1.0 - np.arange(0, n_rim + 1) / n_rim)  # pi/2 .. 0
    rim_rho = 1.0 - f * (1.0 - np.cos(t))
    rim_z = (c - r) + r * np.sin(t)
    side_z = (c - r) * (1.0 - 2.0 * np.arange(1, n_side) / n_side)
    z = np.concatenate([np.full(n_cap, c), rim_z, side_z, -rim_z[::-1], np.full(n_cap, -c)])
    rho = np.concatenate([cap_rho, rim_rho, np.ones(n_side - 1), rim_rho[::-1], cap_rho[::-1]])
    return lathe(center_m, a, b, z, rho, segments=segments, axis=axis)


def lathe(
    center_m: Sequence[float],
    a: float,
    b: float,
    z: np.ndarray,
    rho: np.ndarray,
    *,
    segments: int,
    axis: str = "z",
) -> trimesh.Trimesh:
    """Closed solid whose cross-section at height ``z[k]`` is the ellipse of
    semi-axes ``(a rho[k], b rho[k])``; ``rho`` must be 0 exactly at the first
    (top, largest z) and last (bottom) profile points: the poles.

    With ``axis="x"`` the symmetry axis is mapped to world x (own x -> world
    y, own y -> world z), with ``axis="y"`` to world y (own x -> z, own y ->
    x): cyclic permutations, so orientation is preserved.
    """
    z = np.asarray(z, float)
    rho = np.asarray(rho, float)
    if segments < 3 or len(z) < 3 or rho[0] != 0.0 or rho[-1] != 0.0 or np.any(rho[1:-1] <= 0):
        raise ValueError("lathe needs segments >= 3 and a profile with poles at both ends only")
    zi, ri = z[1:-1], rho[1:-1]
    theta = 2.0 * np.pi * np.arange(segments) / segments
    ring_xyz = np.stack(
        [
            a * ri[:, None] * np.cos(theta)[None, :],
            b * ri[:, None] * np.sin(theta)[None, :],
            np.broadcast_to(zi[:, None], (len(zi), segments)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    vertices = np.concatenate([[[0.0, 0.0, z[0]]], ring_xyz, [[0.0, 0.0, z[-1]]]])
    top, bottom = 0, len(vertices) - 1
    n_ring = len(zi)
    j = np.arange(segments)
    jn = (j + 1) % segments

    def ring(r: int, k: np.ndarray) -> np.ndarray:
        return 1 + r * segments + k

    faces = [np.stack([np.full(segments, top), ring(0, j), ring(0, jn)], axis=1)]
    for r in range(n_ring - 1):
        faces.append(np.stack([ring(r, j), ring(r + 1, j), ring(r + 1, jn)], axis=1))
        faces.append(np.stack([ring(r, j), ring(r + 1, jn), ring(r, jn)], axis=1))
    faces.append(np.stack([np.full(segments, bottom), ring(n_ring - 1, jn), ring(n_ring - 1, j)], axis=1))
    # theta runs counter-clockwise seen from +z and rings go downwards, so
    # (ring r, ring r+1, ring r+1 next) is counter-clockwise seen from
    # outside: outward normals (checked by the tests through the volume sign).
    faces = np.concatenate(faces)
    if axis == "x":
        vertices = vertices[:, [2, 0, 1]]
    elif axis == "y":
        vertices = vertices[:, [1, 2, 0]]
    elif axis != "z":
        raise ValueError(f"axis must be 'x', 'y' or 'z', got {axis!r}")
    return trimesh.Trimesh(vertices + np.asarray(center_m, float), faces, process=False)


def box(lower_m: Sequence[float], upper_m: Sequence[float]) -> trimesh.Trimesh:
    """Axis-aligned box between two corners: 12 outward-oriented triangles."""
    lower = np.asarray(lower_m, float)
    upper = np.asarray(upper_m, float)
    if not np.all(upper > lower):
        raise ValueError("box needs upper > lower on every axis")
    extents = upper - lower
    transform = np.eye(4)
    transform[:3, 3] = (upper + lower) / 2.0
    return trimesh.creation.box(extents=extents, transform=transform)
