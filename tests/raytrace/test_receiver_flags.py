"""Per-receiver validity flags (raytrace.solver.validity.receiver_flags) on a planar layered body.

Skin (2 mm) / fat (20 mm) / muscle, air in front, the transmitter 30 mm behind the fat: the
geometry of docs/validation.md's layered FDTD cases, built here. The oracle for which receiver
carries which flag is the closed-form geometry written in this file: Snell's law on the layers'
real refractive indices (the real part of sqrt of the Gabriel permittivity at the carrier) gives the
angle of the direct path in every layer for a given lateral offset (bisection on the ray
parameter), and plain distances give the rest. Offsets are chosen well clear of each
threshold (several degrees or millimetres), so the tracer's exact lossy path and the test's
lossless Snell path cannot fall on different sides.

The geometric-optics flags are those of a direct path evaluated by stationary phase (here: the
near-field term off). With the term on, dipoles' direct paths through these parallel layers are the
layers' exact generalized-ray integral (raytrace/solver/stratified.py) and carry none of them;
through layers tilted beyond CURVED_DEG (but within the stack's PARALLEL_DEG) they carry
``curved_layers``.
"""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.body.phantom import Material, Organ, Phantom
from raytrace.body.shapes import box
from raytrace.physics.tissues import DEFAULT_FAT, complex_relative_permittivity
from raytrace.solver.stratified import PARALLEL_DEG
from raytrace.solver.tracer import trace_channel
from raytrace.solver.validity import (
    AIR_NEAR_BODY_M,
    CURVED_DEG,
    GRAZING_DEG,
    NEAR_FIELD_WAVELENGTHS,
    OBLIQUE_TISSUE_DEG,
)
from raytrace.spec import Antenna, ChannelSpec

F_HZ = 402e6
SKIN_M, FAT_M, TX_DEPTH_M = 0.002, 0.020, 0.030
LAYERS = (("skin", "skin_dry", SKIN_M), ("fat", DEFAULT_FAT, FAT_M), ("muscle", "muscle", TX_DEPTH_M))


def _phantom() -> Phantom:
    organs, front = [], 0.0
    for k, (name, tissue, thick) in enumerate(LAYERS):
        h = 1.0 - 0.01 * k
        organs.append(Organ(name, Material(tissue=tissue), box([-h, front, -h], [h, h, h])))
        front += thick
    return Phantom.build("layers", organs)


def _n(tissue: str) -> float:
    return float(np.sqrt(complex_relative_permittivity(tissue, F_HZ)).real)


def snell_angles_deg(lateral_m: float, air_m: float = 0.0) -> dict[str, float]:
    """Angle from the normal in each medium of the direct path from the transmitter (on the
    normal, TX_DEPTH_M into the muscle) to a point ``lateral_m`` aside and ``air_m`` in front of
    the skin (0: at the skin surface): n_i sin(theta_i) = p for all layers, sum t_i tan(theta_i)
    = lateral, solved for p by bisection."""
    media = [(name, thick) for name, _, thick in LAYERS] + ([("air", air_m)] if air_m > 0 else [])
    tissue = {name: t for name, t, _ in LAYERS}
    ns = [1.0 if name == "air" else _n(tissue[name]) for name, _ in media]
    lo, hi = 0.0, min(ns) * (1 - 1e-12)

    def reach(p: float) -> float:
        return sum(t * p / np.sqrt(n * n - p * p) for n, (_, t) in zip(ns, media))

    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if reach(mid) < lateral_m else (lo, mid)
    p = 0.5 * (lo + hi)
    return {name: float(np.degrees(np.arcsin(p / n))) for n, (name, _) in zip(ns, media)}


def _flags(receivers_m, near_field: bool = True) -> list[tuple[str, ...]]:
    ph = _phantom()
    tx = Antenna(position_m=np.array([0.0, SKIN_M + FAT_M + TX_DEPTH_M, 0.0]), name="tx",
                 polarization=[0, 0, 1], pattern="dipole")
    rxs = tuple(Antenna(position_m=np.asarray(r, float), name=f"r{i}", polarization=[0, 0, 1], pattern="dipole")
                for i, r in enumerate(receivers_m))
    spec = ChannelSpec(tx, rxs, phantom=ph.name, frequency_hz=F_HZ, max_interactions=2, rays=50_000,
                       near_field=near_field)
    return [p.validity for p in trace_channel(spec, ph).profiles]


def test_contact_sensors_are_flagged_once_the_fat_is_crossed_beyond_the_threshold():
    offsets = (0.0, 0.010, 0.020, 0.030, 0.050)
    fat_deg = [snell_angles_deg(x)["fat"] for x in offsets]
    # the chosen offsets straddle the threshold by several degrees (16.6, 31.8 | 44.5, 61.4 deg)
    assert all(abs(a - OBLIQUE_TISSUE_DEG) > 3.0 for a in fat_deg), fat_deg
    flags = _flags([[x, 0.0005, 0.0] for x in offsets], near_field=False)
    for a, f in zip(fat_deg, flags):
        assert ("near_critical_angle" in f) == (a > OBLIQUE_TISSUE_DEG), (a, f)
        assert "grazing_exit" not in f and "in_air_near_body" not in f and "no_direct_path" not in f
    assert all(f == () for f in _flags([[x, 0.0005, 0.0] for x in offsets], near_field=True))


def test_receivers_in_air_near_the_body_and_grazing_exits():
    # on the normal 10 mm and 300 mm off the skin; 60 mm aside at 10 mm (exit near 77 deg)
    pts = [[0.0, -0.010, 0.0], [0.0, -0.300, 0.0], [0.060, -0.010, 0.0], [0.020, -0.010, 0.0]]
    exits = [snell_angles_deg(abs(p[0]), -p[1])["air"] for p in pts]
    assert abs(exits[2] - GRAZING_DEG) > 3.0 and abs(exits[3] - GRAZING_DEG) > 3.0, exits
    flags = _flags(pts, near_field=False)
    for p, a, f in zip(pts, exits, flags):
        assert ("in_air_near_body" in f) == (-p[1] < AIR_NEAR_BODY_M), (p, f)
        assert ("grazing_exit" in f) == (a > GRAZING_DEG), (p, a, f)
    assert all(f == () for f in _flags(pts, near_field=True))


@pytest.mark.parametrize("near_field", [True, False])
def test_near_field_flag(near_field):
    """Within NEAR_FIELD_WAVELENGTHS wavelengths of the transmitter (in the muscle: c / (f n)):
    flagged when the direct path is not the exact dipole field, i.e. when the near-field term is
    off; with it on, a straight path in one medium is the exact dipole field and a path through the
    parallel layers their exact integral: neither is flagged."""
    wavelength = 299_792_458.0 / (F_HZ * _n("muscle"))
    tx_y = SKIN_M + FAT_M + TX_DEPTH_M
    same_medium = [0.0, tx_y + 0.05, 0.0]  # 50 mm deeper in the muscle: straight path
    across = [0.0, 0.0005, 0.0]  # through fat and skin
    far = [0.0, tx_y + NEAR_FIELD_WAVELENGTHS * wavelength + 0.02, 0.0]  # beyond the range
    flags = _flags([same_medium, across, far], near_field=near_field)
    assert ("near_field" in flags[0]) == (not near_field)
    assert ("near_field" in flags[1]) == (not near_field)
    assert "near_field" not in flags[2]


@pytest.mark.parametrize("tilt_deg", [10.0, 25.0, 50.0])
def test_tilted_layers_are_flagged_curved_or_left_to_geometric_optics(tilt_deg):
    """A 40 mm muscle block in the fat, turned by ``tilt_deg`` about the z axis, its front face 40 mm
    under the skin on the normal (the skin and the fat's front stay at y = 0 and 2 mm); the
    transmitter 10 mm inside the block, a contact sensor on the normal. Within CURVED_DEG: no flag;
    between CURVED_DEG and PARALLEL_DEG: ``curved_layers``; beyond: geometric optics with its own
    flags (``near_field`` through the interfaces)."""
    assert CURVED_DEG < 25.0 < PARALLEL_DEG < 50.0 and 10.0 < CURVED_DEG
    import trimesh

    organs = [Organ("skin", Material(tissue="skin_dry"), box([-1.0, 0.0, -1.0], [1.0, 1.0, 1.0])),
              Organ("fat", Material(tissue=DEFAULT_FAT), box([-0.99, SKIN_M, -0.99], [0.99, 0.99, 0.99]))]
    t = np.radians(tilt_deg)
    turn = np.array([[np.cos(t), -np.sin(t), 0.0], [np.sin(t), np.cos(t), 0.0], [0.0, 0.0, 1.0]])
    centre = np.array([0.0, 0.040 + 0.020 / np.cos(t), 0.0])  # the front face 40 mm deep on the normal
    block = box([-0.02, -0.02, -0.02], [0.02, 0.02, 0.02])
    muscle = trimesh.Trimesh(np.asarray(block.vertices) @ turn.T + centre, block.faces, process=False)
    organs.append(Organ("muscle", Material(tissue="muscle"), muscle))
    ph = Phantom.build("tilted", organs)
    tx = Antenna(position_m=np.array([0.0, 0.050, 0.0]), name="tx",
                 polarization=[0, 0, 1], pattern="dipole")
    rx = Antenna(position_m=np.array([0.0, 0.0005, 0.0]), name="r", polarization=[0, 0, 1], pattern="dipole")
    spec = ChannelSpec(tx, (rx,), phantom=ph.name, frequency_hz=F_HZ, max_interactions=2, rays=50_000)
    (prof,) = trace_channel(spec, ph).profiles
    if tilt_deg < CURVED_DEG:
        assert prof.validity == ()
    elif tilt_deg < PARALLEL_DEG:
        assert prof.validity == ("curved_layers",)
    else:
        assert "near_field" in prof.validity and "curved_layers" not in prof.validity
