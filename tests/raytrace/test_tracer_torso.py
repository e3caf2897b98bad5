"""Tracer on the default torso (many nested, curved, faceted organs): integration checks.

Oracles: the phantom's own point-in-organ lookup (``Phantom.medium_index``, an
independent Embree probe) for every segment's medium; the delay/length sums
recomputed from the segments; geometry-only invariants. Modest ray counts keep
the test fast; it checks consistency, not the channel's values.
"""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.physics.em import C0
from raytrace.solver.config import TracerConfig
from raytrace.spec import Antenna
from tests.helpers import trace

torso = pytest.importorskip("raytrace.body.torso")


@pytest.fixture(scope="module")
def phantom():
    return torso.default_torso()


def test_torso_paths_are_consistent_with_the_phantom(phantom):
    capsules = [s for s in phantom.sites.values() if s.kind == "capsule"][:3]
    sensors = [Antenna(s.position_m, name=s.name) for s in phantom.sites.values() if s.kind == "sensor"]
    total = 0
    for cap in capsules:
        # 6 interactions: leaving the torso alone takes 4 refractions (organ, muscle wall,
        # fat, skin), so reflections need at least 5.
        res = trace(phantom, Antenna(cap.position_m), sensors, 402e6, rays=20000, max_interactions=6)
        assert res.transmitter_medium == cap.medium
        for prof in res.profiles:
            delays = [p.delay_s for p in prof.paths]
            assert delays == sorted(delays)
            for path in prof.paths:
                assert np.isfinite(path.gain) and abs(path.gain) > 0
                assert len(path.interactions) <= 6 or all(i.kind == "refraction" for i in path.interactions)
                starts = np.array([s.start_m for s in path.segments])
                ends = np.array([s.end_m for s in path.segments])
                assert np.allclose(starts[0], cap.position_m) and np.allclose(ends[-1], prof.position_m)
                assert np.allclose(starts[1:], ends[:-1])
                mids = 0.5 * (starts + ends)
                assert phantom.medium_names(phantom.medium_index(mids)) == [s.medium for s in path.segments]
                assert abs(sum(s.length_m for s in path.segments) - path.length_m) < 1e-12
                # the delay is sum L_i Re(n_i) / c: at least the geometric length / c
                assert path.delay_s > path.length_m / C0
                total += 1
    assert total > 10


# ----------------------------------------------------------------- direct paths, contact sensors
@pytest.fixture(scope="module")
def contact_torso():
    if not hasattr(torso, "SENSOR_DEPTH_M"):
        pytest.skip("torso without contact sensors")
    return torso.default_torso()


@pytest.fixture(scope="module")
def direct_traces(contact_torso):
    ph = contact_torso
    sensors = [Antenna(s.position_m, name=n) for n, s in ph.sites.items() if s.kind == "sensor"]
    return {
        n: trace(ph, Antenna(s.position_m, name=n), sensors, 402e6, rays=100_000, max_interactions=6)
        for n, s in ph.sites.items() if s.kind == "capsule"
    }


def _is_direct(path):
    return all(i.kind == "refraction" for i in path.interactions)


def test_every_capsule_sensor_pair_has_a_direct_path(contact_torso, direct_traces):
    """Acceptance (tracer issue): for every capsule site x sensor site pair of the default
    torso, a direct (refraction-only) path exists -- 6 x 12 = 72 pairs at the default 1e5 rays.
    The sensor sites were placed where geometric optics has one (torso module doc; the
    uniform-belt positions it does not cover are pinned below)."""
    sites = contact_torso.sites
    assert all(s.medium == "skin" for s in sites.values() if s.kind == "sensor")
    assert len(direct_traces) == 6 and all(len(r.profiles) == 12 for r in direct_traces.values())
    missing = [(cap, prof.receiver) for cap, res in direct_traces.items() for prof in res.profiles
               if not any(_is_direct(p) for p in prof.paths)]
    assert missing == []


#: A uniform contact-sensor belt (every 45 deg at z = 0) and four sensors at z = 0.155 m: the
#: torso's sensor sites of the first version, kept here as the record of where geometric optics
#: has no direct path. Name -> (polar angle from anterior towards the subject's left [deg], z [m]).
UNIFORM_BELT = {
    "belt_anterior": (0, 0.0), "belt_anterior_left": (45, 0.0), "belt_left": (90, 0.0),
    "belt_posterior_left": (135, 0.0), "belt_posterior": (180, 0.0), "belt_posterior_right": (225, 0.0),
    "belt_right": (270, 0.0), "belt_anterior_right": (315, 0.0),
    "upper_anterior_left": (30, 0.155), "upper_anterior": (0, 0.155), "upper_anterior_right": (330, 0.155),
    "upper_left": (90, 0.155),
}
#: Capsule x UNIFORM_BELT pairs with no refraction-only geometric-optics path found by any of five
#: searches: this tracer at 1e5 and 1e6 rays, its refraction-only search at 2e6 rays from both
#: ends (reciprocity), and two independent brute-force refraction-only shooters
#: (tools/torso_direct_bruteforce.py: a 3.9e6-ray theta-phi lattice with image-triangle
#: containment, and 2e6 Fibonacci rays each zoomed by a derivative-free grid search).
#: Mechanisms (checked by tracing the straight line): the fat layer's 26 deg critical angle
#: (muscle -> fat) when the capsule sees the sensor's fat patch obliquely (stomach -> lateral
#: sensors, transverse colon -> belt sides, descending colon -> anterior sensors), and the wedge
#: behind the limb of a colon (a weak lens, n 8.2 in 7.9): rays grazing it are bent ~30 deg,
#: leaving a shadow between the tangent ray and the grazing refracted ray (small_intestine_2 ->
#: belt_left / belt_right, 1-2 mm inside the wedge). These are genuine GO shadows of this
#: phantom (real fields reach them by diffraction).
GO_SHADOWS = {
    ("stomach", "belt_left"), ("stomach", "belt_right"), ("stomach", "upper_left"),
    ("small_intestine_2", "belt_left"), ("small_intestine_2", "belt_right"),
    ("ascending_colon", "belt_anterior_left"), ("ascending_colon", "upper_left"),
    ("transverse_colon", "belt_left"), ("transverse_colon", "belt_right"), ("transverse_colon", "upper_left"),
    ("descending_colon", "belt_anterior"), ("descending_colon", "belt_anterior_right"),
    ("descending_colon", "upper_left"),
}
#: Pairs whose only direct paths leave a low-index layer (fat, bone) within a fraction of a
#: degree of its critical angle: a launch sliver narrower than the 1e5-ray spacing, found by
#: this tracer at 1e6 rays (ascending colon, 7 refractions through spine and liver: -135 and
#: -128 dB, 50 dB under the pair's strongest path) or by its refraction-only search at 2e6
#: rays (small_intestine_1 -> upper_left).
SLIVER_ONLY = {
    ("ascending_colon", "upper_anterior_left"), ("ascending_colon", "upper_anterior"),
    ("small_intestine_1", "upper_left"),
}


def test_uniform_belt_direct_paths_outside_the_go_shadows(contact_torso):
    """Why the sensor sites are where they are: on the uniform belt, the pairs without a direct
    path at 1e5 rays are exactly the proven GO shadows, plus at most the sub-spacing slivers.
    Finding a path in a proven shadow would contradict the independent searches (a tracer
    bug); missing one elsewhere would be a search failure. 56 of the 72 pairs have one."""
    ph = contact_torso
    sensors = [Antenna(torso.contact_point(ph, deg, z), name=n) for n, (deg, z) in UNIFORM_BELT.items()]
    missing = set()
    for cap, site in ((n, s) for n, s in ph.sites.items() if s.kind == "capsule"):
        # the direct-path search does not depend on max_interactions; 1 keeps the shooting cheap
        res = trace(ph, Antenna(site.position_m, name=cap), sensors, 402e6, rays=100_000,
                            max_interactions=1)
        missing |= {(cap, p.receiver) for p in res.profiles if not any(_is_direct(q) for q in p.paths)}
    assert GO_SHADOWS <= missing <= GO_SHADOWS | SLIVER_ONLY, (missing - GO_SHADOWS, GO_SHADOWS - missing)
    assert 6 * 12 - len(missing) >= 56


def test_direct_paths_on_the_torso_are_exact(contact_torso, direct_traces):
    """Every direct path: Snell's law at each vertex with the smooth surface normal (the
    tangential component of n d is continuous, |n1 d1 x ns - n2 d2 x ns| within what the
    Newton stopping miss of 1e-9 m allows on the adjacent legs), the delay equals sum L_i Re n_i / c from its
    segments (1e-15 s), segments' media match the phantom's lookup at their midpoints,
    delays sorted, gains finite and non-zero."""
    from raytrace.engine.scene import scene_for
    from raytrace.solver.media import MediaTable

    ph = contact_torso
    media = MediaTable.build(ph, np.array([402e6]))
    scene = scene_for(ph)
    n_of = {ph.medium_name(m): media.n_real[m + 1] for m in range(-1, len(ph.organs))}
    checked = 0
    for res in direct_traces.values():
        for prof in res.profiles:
            delays = [p.delay_s for p in prof.paths]
            assert delays == sorted(delays)
            for path in prof.paths:
                assert np.isfinite(path.gain) and abs(path.gain) > 0
                if not _is_direct(path):
                    continue
                segs = path.segments
                mids = np.array([0.5 * (s.start_m + s.end_m) for s in segs])
                assert ph.medium_names(ph.medium_index(mids)) == [s.medium for s in segs]
                delay = sum(s.length_m * n_of[s.medium] for s in segs) / C0
                assert abs(delay - path.delay_s) < 1e-15
                # Snell at each vertex between segments of different media
                for a, b in zip(segs[:-1], segs[1:]):
                    if a.medium == b.medium:
                        continue
                    point = a.end_m
                    face = ph.mesh.nearest.on_surface(point[None])[2]
                    ns = scene.smooth_normals(face, point[None])[0]
                    d1 = (a.end_m - a.start_m) / a.length_m
                    d2 = (b.end_m - b.start_m) / b.length_m
                    jump = n_of[a.medium] * np.cross(d1, ns) - n_of[b.medium] * np.cross(d2, ns)
                    # Newton stops once the last leg misses the receiver by < 1e-9 m; on the short
                    # final skin leg (~1 mm) that is an angle of 1e-9 / L, times n
                    tol = 1e-9 + 2.0 * n_of[b.medium] * 1e-9 / b.length_m + 1e-9 / a.length_m
                    assert np.linalg.norm(jump) < tol
                checked += 1
    assert checked >= 72


def test_torso_trace_is_deterministic(contact_torso, direct_traces):
    """The same request twice gives identical output (no hidden randomness or state)."""
    ph = contact_torso
    cap = "small_intestine_2"
    sensors = [Antenna(s.position_m, name=n) for n, s in ph.sites.items() if s.kind == "sensor"]
    again = trace(ph, Antenna(ph.sites[cap].position_m, name=cap), sensors, 402e6, rays=100_000,
                          max_interactions=6)
    first = direct_traces[cap]
    for p1, p2 in zip(first.profiles, again.profiles):
        key = [(p.delay_s, p.gain, p.length_m) for p in p1.paths]
        assert key == [(p.delay_s, p.gain, p.length_m) for p in p2.paths]


def test_reverse_search_gives_the_forward_direct_path(contact_torso, direct_traces):
    """Reciprocity fallback: the direct path searched from the sensor's side, reversed
    (signature reversed, each surface from the other side) and refined forward, is the path
    the forward search found (same launch direction to 1e-6 rad: both are Newton solutions
    to 1e-9 m over ~0.1 m), for a pair whose forward search is well conditioned."""
    from raytrace.engine.scene import scene_for
    from raytrace.solver.direct import reverse_seeds, reverse_signature
    from raytrace.solver.media import MediaTable
    from raytrace.solver.refine import refine

    codes = np.array([[10, 6, 33, -1]])
    assert reverse_signature(reverse_signature(codes, np.array([3])), np.array([3])).tolist() == codes.tolist()
    assert reverse_signature(codes, np.array([3])).tolist() == [[35, 4, 8, -1]]
    ph = contact_torso
    media = MediaTable.build(ph, np.array([402e6]))
    scene = scene_for(ph, ~media.face_transparent)
    cap, sensor = "small_intestine_2", "belt_anterior"
    tx = ph.sites[cap].position_m
    rx = ph.sites[sensor].position_m[None]
    tx_med, rx_med = ph.organ_index(ph.sites[cap].medium), ph.organ_index(ph.sites[sensor].medium)
    back = reverse_seeds(scene, media, tx, tx_med, rx, np.array([rx_med]), np.array([0]), 20_000)
    assert len(back.receiver) >= 1
    fwd = refine(scene, media, tx, tx_med, np.repeat(rx, len(back.receiver), 0), back.launch_dir, back.codes,
                 back.nint)
    assert fwd.converged.any()
    prof = next(p for p in direct_traces[cap].profiles if p.receiver == sensor)
    launch = [(p.segments[0].end_m - tx) / p.segments[0].length_m for p in prof.paths if _is_direct(p)]
    angles = [np.arccos(np.clip(d @ u, -1, 1)) for d in fwd.dirs[fwd.converged] for u in launch]
    assert min(angles) < 1e-6


@pytest.mark.parametrize("cap", ["small_intestine_1", "descending_colon", "ascending_colon"])
def test_default_launch_finds_each_receivers_strongest_path(contact_torso, direct_traces, cap):
    """Completeness of the shooting at the default 1e5 rays against a 4x denser launch (4e5):
    every sensor's strongest path is found, and >= 90 % of the paths within 10 dB of it.
    Oracle: the denser trace (more rays can only add candidates; every path of both is exact,
    so the same path has the same delay to 1e-15 s). Before the reception tubes were widened
    at curved surfaces (raytrace.solver.sbr, CURVATURE_MARGIN) four of these 36 pairs lacked their
    strongest path (one by 17.6 dB) and 82 % of the strong paths were found. With the wider
    tubes ascending_colon -> upper_left still lacked its strongest, the skin/air echo of a
    direct path that only the direct search finds (now seeded from it: the tracer's surface
    echo seeds). Now 100 % of the strongest and 93 / 93 / 96 % of the strong paths (measured)."""
    ph = contact_torso
    sensors = [Antenna(s.position_m, name=n) for n, s in ph.sites.items() if s.kind == "sensor"]
    dense = trace(ph, Antenna(ph.sites[cap].position_m, name=cap), sensors, 402e6, rays=400_000,
                          max_interactions=6)
    found = strong = 0
    for lo, hi in zip(direct_traces[cap].profiles, dense.profiles):
        top = max(abs(p.gain) for p in hi.paths)
        best = max(hi.paths, key=lambda p: abs(p.gain))
        assert any(abs(q.delay_s - best.delay_s) < 1e-15 for q in lo.paths), (cap, lo.receiver)
        for p in hi.paths:
            if abs(p.gain) >= top * 10 ** (-10 / 20):
                strong += 1
                found += any(abs(q.delay_s - p.delay_s) < 1e-15 for q in lo.paths)
    assert found >= 0.9 * strong, (found, strong)


def test_every_pair_has_a_direct_path_in_the_ism_band_too(contact_torso):
    """The sensor sites were chosen at 402 MHz; at 2.45 GHz (the other WCE band) the tissue
    indices and so the critical angles change (muscle eps_r 57 -> 53, fat 11.6 -> 10.8), and
    every one of the 72 pairs still has a direct path (measured: all 72). The direct-path search
    does not depend on max_interactions; 1 keeps the shooting cheap."""
    ph = contact_torso
    sensors = [Antenna(s.position_m, name=n) for n, s in ph.sites.items() if s.kind == "sensor"]
    missing = []
    for cap, site in ((n, s) for n, s in ph.sites.items() if s.kind == "capsule"):
        res = trace(ph, Antenna(site.position_m, name=cap), sensors, 2.45e9, rays=100_000,
                            max_interactions=1)
        missing += [(cap, p.receiver) for p in res.profiles if not any(_is_direct(q) for q in p.paths)]
    assert missing == []


def test_seed_walk_in_float32_follows_the_same_surfaces_as_the_exact_walk(phantom):
    """The global seed walk runs on Embree's float32 distances from the pushed-off query origin
    (``exact=False``); it must cross the same surfaces as the float64 walk. Measured: 0 of
    3 x 20000 launches differ; when the distance was applied from the un-pushed origin, the
    next ray started on the surface it had just crossed and re-hit it at ~1e-9 m, cutting 1.7-5 %
    of the walks short. Tolerance 0.1 % of launches (a ray grazing an edge may legitimately
    split differently in float32)."""
    from raytrace.engine.scene import scene_for
    from raytrace.solver import direct
    from raytrace.solver.launch import fibonacci_sphere
    from raytrace.solver.media import MediaTable

    media = MediaTable.build(phantom, np.array([402e6]))
    scene = scene_for(phantom, ~media.face_transparent)
    sensors = [s.position_m for s in phantom.sites.values() if s.kind == "sensor"]
    rx = np.array(sensors, float)
    rx_medium = phantom.medium_index(rx)
    launch = fibonacci_sphere(20_000)
    capsules = [n for n, s in phantom.sites.items() if s.kind == "capsule"][:3]
    for name in capsules:
        tx = np.asarray(phantom.sites[name].position_m, float)
        tx_medium = int(phantom.medium_index(tx[None])[0])
        exact = direct.refraction_walk(scene, media, tx, tx_medium, launch, rx, rx_medium, exact=True)
        fast = direct.refraction_walk(scene, media, tx, tx_medium, launch, rx, rx_medium, exact=False)
        differ = int((exact.events != fast.events).any(axis=1).sum())
        assert differ <= 0.001 * len(launch), (name, differ)


def test_walk_on_the_shooting_rays_gives_the_seed_walks_seeds(phantom):
    """The refraction-only seed walk riding on the shooting's rays (float32 state, the
    shooting's launch) picks the same seeds as the stand-alone walk (float64 state): the same
    launch directions, signatures and event counts for every receiver, closest approaches
    within 1e-3 relative (float32 positions over a few events; measured 4e-4). Its rays never
    make reception candidates: the shooting's candidates are identical with and without it."""
    from raytrace.engine.scene import scene_for
    from raytrace.solver import direct, sbr
    from raytrace.solver.media import MediaTable

    media = MediaTable.build(phantom, np.array([402e6]))
    scene = scene_for(phantom, ~media.face_transparent)
    rx = np.array([s.position_m for s in phantom.sites.values() if s.kind == "sensor"], float)
    rx_medium = phantom.medium_index(rx)
    name = [n for n, s in phantom.sites.items() if s.kind == "capsule"][0]
    tx = np.asarray(phantom.sites[name].position_m, float)
    tx_medium = int(phantom.medium_index(tx[None])[0])
    rays = 60_000  # two launch batches
    receivers = np.arange(len(rx))
    plain = sbr.shoot(scene, media, tx, tx_medium, rx, rx_medium, rays, 6, 80.0)
    walked = sbr.shoot(scene, media, tx, tx_medium, rx, rx_medium, rays, 6, 80.0, walk=True)
    for field in ("receiver", "codes", "faces", "nint", "launch_dir", "closeness"):
        np.testing.assert_array_equal(getattr(plain, field), getattr(walked, field))
    assert walked.segments > plain.segments  # the walk's own continuations
    alone = direct.direct_seeds(scene, media, tx, tx_medium, rx, rx_medium, rays, receivers)
    riding = walked.direct_seeds(receivers)
    assert len(alone.receiver) == len(rx) * TracerConfig().seeds_per_receiver
    np.testing.assert_array_equal(riding.receiver, alone.receiver)
    np.testing.assert_allclose(riding.launch_dir, alone.launch_dir, atol=1e-12)
    np.testing.assert_array_equal(riding.codes, alone.codes)
    np.testing.assert_array_equal(riding.nint, alone.nint)
    np.testing.assert_allclose(riding.miss_m, alone.miss_m, rtol=1e-3)


def test_the_live_ray_cap_never_drops_the_walks_rays(phantom):
    """Under the shooting's safety cap on live rays (forced low: 22000 for a 20000-ray launch,
    which cuts the shot segments by more than 20 %), the walk riding on the shooting keeps
    every one of its rays (one per launch) and gives the same seeds as without the cap
    (ranking them by power over squared length like the others changes the seeds)."""
    from raytrace.engine.scene import scene_for
    from raytrace.solver import sbr
    from raytrace.solver.media import MediaTable

    media = MediaTable.build(phantom, np.array([402e6]))
    scene = scene_for(phantom, ~media.face_transparent)
    rx = np.array([s.position_m for s in phantom.sites.values() if s.kind == "sensor"], float)
    rx_medium = phantom.medium_index(rx)
    tx = np.asarray(next(s for s in phantom.sites.values() if s.kind == "capsule").position_m, float)
    tx_medium = int(phantom.medium_index(tx[None])[0])
    free = sbr.shoot(scene, media, tx, tx_medium, rx, rx_medium, 20_000, 6, 80.0, walk=True)
    capped = sbr.shoot(scene, media, tx, tx_medium, rx, rx_medium, 20_000, 6, 80.0, walk=True,
                       config=TracerConfig(max_live_rays=22000))
    assert capped.segments < 0.8 * free.segments  # the cap did cut
    a, b = free.direct_seeds(np.arange(len(rx))), capped.direct_seeds(np.arange(len(rx)))
    np.testing.assert_array_equal(a.codes, b.codes)
    np.testing.assert_array_equal(a.launch_dir, b.launch_dir)
