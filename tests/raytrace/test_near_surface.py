"""An antenna just under an organ surface: it is refused while its medium, or that surface's own
reflection, is below what the tracer resolves, and beyond that the reflection is found.

A receiver at depth d under a planar skin/air surface sees, besides the direct wave, that
surface's reflection, whose image-method path is the straight line from the transmitter to
the receiver's mirror image (an exact enumeration written here, sharing no code with the
tracer). Within a few microns of the surface the two are one wave to any antenna (their phase
differs by 2 k d, about 1e-3 rad at 10 um and 402 MHz in skin), but a tracer that keeps only
the direct one is 1.9 dB off. Measured before the tolerance was raised (1 um then): on the
normal of this slab the reflection was missing at 2-3 um and found from 4 um; on its
skin/fat/muscle version (bench/fullwave layered) missing at 1-4 um, found from 5 um. Hence
SURFACE_TOLERANCE_M = 10 um, twice the worst measured.
"""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.body.phantom import ANTENNA_CLEARANCE_M, Material, Organ, Phantom
from raytrace.body.shapes import box
from raytrace.errors import AmbiguousPositionError
from raytrace.solver.tracer import trace_channel
from raytrace.spec import Antenna, ChannelSpec

HALF_M = 1.0  # a large slab: the float32 scene resolution is that of a 1 m scene, the coarsest tested


def _slab() -> Phantom:
    """Dry skin filling y in [0, 1] m (lateral half-size 1 m), air at y < 0."""
    return Phantom.build("skin-slab", [Organ("skin", Material(tissue="skin_dry"),
                                             box([-HALF_M, 0.0, -HALF_M], [HALF_M, HALF_M, HALF_M]))])


def _spec(phantom: Phantom, rx_m) -> ChannelSpec:
    tx = Antenna(position_m=np.array([0.0, 0.05, 0.0]), name="tx", polarization=[0, 0, 1], pattern="dipole")
    rx = Antenna(position_m=np.asarray(rx_m, float), name="rx", polarization=[0, 0, 1], pattern="dipole")
    return ChannelSpec(tx, (rx,), phantom=phantom.name, frequency_hz=402e6, max_interactions=2, rays=100_000)


def test_the_clearance_is_ten_microns():
    assert ANTENNA_CLEARANCE_M == 10e-6


@pytest.mark.parametrize("depth_m", [25e-6, 50e-6, 200e-6])
@pytest.mark.parametrize("lateral_m", [0.0, 0.01])
def test_the_surface_reflection_is_found_just_under_the_surface(depth_m, lateral_m):
    ph = _slab()
    rx = np.array([lateral_m, depth_m, 0.0])
    paths = trace_channel(_spec(ph, rx), ph).profiles[0].paths
    tx = np.array([0.0, 0.05, 0.0])
    image = rx * [1.0, -1.0, 1.0]
    direct = [p for p in paths if not p.interactions]
    bounced = [p for p in paths if [(i.kind, i.from_medium, i.to_medium) for i in p.interactions]
               in ([("reflection", "skin", "air")], [("total_internal_reflection", "skin", "air")])]
    assert len(direct) == 1 and len(bounced) == 1, [(p.length_m, p.interactions) for p in paths]
    # lengths: the straight line and the image line, to the Newton refinement's 1e-9 m miss tolerance
    assert direct[0].length_m == pytest.approx(np.linalg.norm(tx - rx), abs=1e-8)
    assert bounced[0].length_m == pytest.approx(np.linalg.norm(tx - image), abs=1e-8)


@pytest.mark.parametrize("depth_m", [0.0, 2e-6, 5e-6, 9.9e-6])
def test_closer_than_the_tolerance_is_refused_naming_the_receiver(depth_m):
    ph = _slab()
    with pytest.raises(AmbiguousPositionError) as info:
        trace_channel(_spec(ph, [0.0, depth_m, 0.0]), ph)
    assert info.value.field == "receivers[0].position_m"


def _tilted_slab(normal: np.ndarray) -> Phantom:
    """A 0.4 m cube of muscle turned so that one face's outward normal is ``normal``, that face
    through the origin."""
    import trimesh

    mesh = trimesh.creation.box(extents=[0.4, 0.4, 0.4])
    mesh.apply_translation([0.0, 0.0, -0.2])  # the +z face through the origin
    mesh.apply_transform(trimesh.geometry.align_vectors([0.0, 0.0, 1.0], normal))
    return Phantom.build("tilted", [Organ("muscle", Material(tissue="muscle"), mesh)])


def _worst_normals(k: int) -> np.ndarray:
    """Unit normals least seen by the probes: the k smallest max_i |n . p_i| over a dense sample
    of the sphere (found here by enumeration, not by the implementation's closed form)."""
    from raytrace.body.phantom import _PROBE_DIRECTIONS

    rng = np.random.default_rng(3)
    n = rng.normal(size=(400_000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    cover = np.abs(n @ np.asarray(_PROBE_DIRECTIONS).T).max(axis=1)
    return n[np.argsort(cover)[:k]]


@pytest.mark.parametrize("normal", list(_worst_normals(2)) + list(np.random.default_rng(5).normal(size=(3, 3))))
def test_the_clearance_holds_for_any_orientation_of_the_surface(normal):
    """Surfaces the probes meet most obliquely (and random ones): inside, 9.9 um under the face, an
    antenna is refused; 21 um under it (beyond 10 um / PROBE_COVER), accepted."""
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    ph = _tilted_slab(normal)
    with pytest.raises(AmbiguousPositionError):
        ph.check_antenna_clearance(-9.9e-6 * normal[None, :], ["rx"])
    ph.check_antenna_clearance(-21e-6 * normal[None, :], ["rx"])
