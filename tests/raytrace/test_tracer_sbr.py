"""Shooting phase (raytrace/sbr.py): rays that cannot reach a receiver's zone within
``max_interactions``, leave the scene's box or are absorbed below the dynamic range before they
can get back are not spawned, and that must not change the candidates; the facet curvature
that widens the reception tubes.

Oracles: the torso's nesting and a closed room's shell written out by hand for the interaction
counts and return lengths, and the same launch shot with the pruning disabled for the
candidates (exact equality: pruning is a pure optimisation).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from raytrace.body.phantom import Material, Organ, Phantom
from raytrace.engine.scene import scene_for
from raytrace.solver import sbr
from raytrace.solver.config import TracerConfig
from raytrace.solver.media import MediaTable

torso = pytest.importorskip("raytrace.body.torso")


@pytest.fixture(scope="module")
def phantom():
    return torso.default_torso()


def _medium(ph, name):
    return -1 if name == "air" else [o.name for o in ph.organs].index(name)


def test_interactions_needed_follow_the_torso_layers(phantom):
    media = MediaTable.build(phantom, np.array([402e6]))
    skin = _medium(phantom, "skin")
    need = sbr._interactions_needed(media, np.array([skin]))
    # by hand: from air one refraction into skin; from fat one; from the muscle wall two
    # (muscle -> fat -> skin); from the cavity the same (cavity and wall are both muscle: the
    # surface between them is transparent); from an organ in the cavity three
    expected = {"air": 1, "skin": 0, "subcutaneous_fat": 1, "muscle_wall": 2, "visceral_cavity": 2,
                "liver": 3, "small_intestine": 3, "spine": 3, "left_lung": 3}
    for name, n in expected.items():
        assert need[_medium(phantom, name) + 1] == n, name
    # receivers in two classes: the nearer one counts
    liver = _medium(phantom, "liver")
    need2 = sbr._interactions_needed(media, np.array([skin, liver]))
    assert need2[_medium(phantom, "liver") + 1] == 0
    assert need2[_medium(phantom, "small_intestine") + 1] == 2  # organ -> cavity -> liver
    assert need2[_medium(phantom, "air") + 1] == 1


def _candidate_set(c):
    return sorted(
        (int(r), tuple(int(x) for x in codes), tuple(np.round(d, 12)), float(cl))
        for r, codes, d, cl in zip(c.receiver, c.codes, c.launch_dir, c.closeness)
    )


@pytest.mark.parametrize("max_interactions", [4, 6])
def test_pruning_leaves_the_candidates_unchanged(phantom, monkeypatch, max_interactions):
    media = MediaTable.build(phantom, np.array([402e6]))
    scene = scene_for(phantom, ~media.face_transparent)
    tx = phantom.sites[[n for n, s in phantom.sites.items() if s.kind == "capsule"][0]].position_m
    sensors = [s for s in phantom.sites.values() if s.kind == "sensor"]
    rx = np.array([s.position_m for s in sensors])
    tx_med = int(phantom.medium_index(tx[None, :])[0])
    rx_med = np.array([int(phantom.medium_index(r[None, :])[0]) for r in rx])
    args = (scene, media, tx, tx_med, rx, rx_med, 20_000, max_interactions, 80.0)
    pruned = sbr.shoot(*args)
    monkeypatch.setattr(sbr, "_interactions_needed", lambda media, rx_medium: np.zeros(len(media.materials),
                                                                                          np.int64))
    full = sbr.shoot(*args)
    assert pruned.segments < full.segments  # it does prune something
    assert len(full.receiver) > 0
    assert _candidate_set(pruned) == _candidate_set(full)


def _closed_room():
    """A 6 x 5 x 3 m room's air (one organ) in a 1 m concrete shell (eps_r 5.24, 0.0462 S/m)."""
    lo, hi = np.array([-3.0, -2.5, -1.5]), np.array([3.0, 2.5, 1.5])
    return Phantom.build("closed-room", [
        Organ("walls", Material(relative_permittivity=5.24, conductivity_s_per_m=0.0462),
              trimesh.creation.box(bounds=[lo - 1.0, hi + 1.0])),
        Organ("room", Material(relative_permittivity=1.0, conductivity_s_per_m=0.0),
              trimesh.creation.box(bounds=[lo, hi]))])


def test_zones_and_return_lengths_of_a_closed_room():
    """The room's air and the air outside the walls are one material but two zones: rays outside
    need two crossings (walls, room), not none. A ray on the walls' outer face (inside the
    concrete) must still cross the 1 m shell before it can get back in: its return length is
    the thickness (by hand); a ray entering the concrete from the room (a convex box) must reach
    the outer face and come back: twice the thickness."""
    ph = _closed_room()
    media = MediaTable.build(ph, np.array([3.5e9]))
    scene = scene_for(ph, ~media.face_transparent)
    zone = sbr.zones(media)
    assert zone[0] != zone[2]  # outside air (medium -1), room air (organ 1)
    need = sbr._interactions_needed(media, np.array([1]))
    assert list(need) == [2, 1, 0]
    alpha = np.array([0.0, 3.8, 0.0])
    ret = sbr.return_lengths(scene, media, zone, need, alpha)
    outer = scene.face_organ == 0
    np.testing.assert_allclose(ret[outer, 0], 1.0, rtol=1e-3)  # inside the concrete, at its outer face
    # in the concrete at the (convex) room's surface, moving away from it: out to the outer face and back
    np.testing.assert_allclose(ret[~outer, 1], 2.0, rtol=1e-3)
    assert (ret[outer, 1] == 0).all() and (ret[~outer, 0] == 0).all()  # outside air (no absorption), room air


@pytest.mark.parametrize("max_interactions", [4, 5])
def test_return_and_escape_pruning_leave_the_candidates_unchanged(monkeypatch, max_interactions):
    """Rays that leave the scene's box outside every receiver's zone, or that the walls' absorption
    over their least return length brings below the dynamic range, are not cast: the candidates
    are those of the same launch without that pruning (exact equality), with fewer segments."""
    ph = _closed_room()
    media = MediaTable.build(ph, np.array([3.5e9]))
    scene = scene_for(ph, ~media.face_transparent)
    tx = np.array([0.7, -0.4, 0.2])
    rx = np.array([[-1.3, 1.1, -0.35], [2.1, 1.7, 0.6], [-2.2, -1.6, 0.9], [0.4, 0.9, -1.0]])
    args = (scene, media, tx, 1, rx, np.ones(len(rx), np.int64), 20_000, max_interactions, 80.0)
    pruned = sbr.shoot(*args, walk=True)
    real_context = sbr._context

    def unpruned(*a, **k):
        ctx = real_context(*a, **k)
        m = ctx.media._replace(return_m=np.zeros_like(ctx.media.return_m),
                               bounds_m=np.array([[-1e9] * 3, [1e9] * 3]))
        return sbr._Context(ctx.scene, m, ctx.receivers, ctx.settings, ctx.walk)

    monkeypatch.setattr(sbr, "_context", unpruned)
    full = sbr.shoot(*args, walk=True)
    assert pruned.segments < full.segments  # it does prune something
    assert len(full.receiver) > 0
    assert _candidate_set(pruned) == _candidate_set(full)


def test_concurrent_launch_batches_give_the_serial_candidates(phantom):
    """Launch batches shot in threads are merged in batch order: exactly the serial result."""
    media = MediaTable.build(phantom, np.array([402e6]))
    scene = scene_for(phantom, ~media.face_transparent)
    tx = phantom.sites[[n for n, s in phantom.sites.items() if s.kind == "capsule"][0]].position_m
    rx = np.array([s.position_m for s in phantom.sites.values() if s.kind == "sensor"])
    tx_med = int(phantom.medium_index(tx[None, :])[0])
    rx_med = np.array([int(phantom.medium_index(r[None, :])[0]) for r in rx])
    args = (scene, media, tx, tx_med, rx, rx_med, 20_000, 6, 80.0)
    serial = sbr.shoot(*args, config=TracerConfig(launch_batch=7_000, threads=1))  # 3 batches of a 20k launch
    threaded = sbr.shoot(*args, config=TracerConfig(launch_batch=7_000, threads=2))
    assert len(serial.receiver) > 0
    assert serial.segments == threaded.segments
    for name in ("receiver", "codes", "faces", "nint", "launch_dir", "closeness"):
        np.testing.assert_array_equal(getattr(serial, name), getattr(threaded, name), err_msg=name)


def test_launch_rows_are_those_of_the_whole_fibonacci_sphere():
    """A launch batch computes its own rows of the sphere (raytrace.solver.launch): bit for bit the
    rows of the whole launch, and the closed form z_i = 1 - (2 i + 1) / N, azimuth i times the
    golden angle pi (3 - sqrt 5) (Gonzalez 2010), to rounding."""
    from raytrace.solver.launch import fibonacci_sphere

    n = 20_000
    whole = fibonacci_sphere(n)
    rows = np.array([0, 1, 7_000, 7_001, 13_999, n - 1])
    np.testing.assert_array_equal(fibonacci_sphere(n, rows), whole[rows])
    np.testing.assert_array_equal(fibonacci_sphere(n, np.arange(7_000, 14_000)), whole[7_000:14_000])
    z = 1.0 - (2.0 * rows + 1.0) / n
    phi = rows * np.pi * (3.0 - np.sqrt(5.0))
    expected = np.stack([np.sqrt(1.0 - z * z) * np.cos(phi), np.sqrt(1.0 - z * z) * np.sin(phi), z], axis=1)
    np.testing.assert_allclose(whole[rows], expected, rtol=0, atol=1e-12)  # float64 rounding of cos / sin


def test_face_curvature_is_one_over_the_radius_on_a_sphere_and_zero_on_flat_faces():
    """The shooting widens its tubes by the facet curvature (raytrace.solver.sbr module doc). Oracle:
    closed forms. On an icosphere of radius R, corner normals are radial, so the angle between
    two of them over the chord joining them is 2 asin(c / 2R) / c -> 1/R (chord c ~ 0.08 R at
    subdivision 4: 1/R within 0.1 %). On a box, flat faces keep their facet normal at every
    corner (crease rule), so the curvature is exactly 0."""
    radius = 0.05
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    box = trimesh.creation.box(extents=[0.5, 0.5, 0.5])
    mat = Material(relative_permittivity=10.0, conductivity_s_per_m=0.0)
    ph = Phantom.build("k", [Organ("box", mat, box), Organ("ball", Material(relative_permittivity=20.0,
                                                                             conductivity_s_per_m=0.0), sphere)])
    scene = scene_for(ph)
    k = scene.face_curvature32
    on_ball = scene.face_organ == ph.organ_index("ball")
    np.testing.assert_allclose(k[on_ball], 1.0 / radius, rtol=1e-3)
    assert np.all(k[~on_ball] == 0.0)


def test_row_groups_are_numpys_unique_rows():
    """The seeds' (receiver, signature) groups are labelled as ``np.unique(axis=0)`` labels them
    (lexicographic order of the rows), through the mixed-radix path and the lexsort fallback."""
    from raytrace.solver.tracer import _row_groups

    rng = np.random.default_rng(17)
    for hi in (3, 40, 10**6):  # the last does not fit the mixed radix with 6 columns
        key = rng.integers(-1, hi, size=(4000, 6))
        key[:2000:2] = key[1:2000:2]  # repeated rows
        _, ref = np.unique(key, axis=0, return_inverse=True)
        np.testing.assert_array_equal(_row_groups(key), ref.ravel())
