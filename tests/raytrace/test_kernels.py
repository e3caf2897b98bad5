"""The compiled per-ray kernels (raytrace/kernels.py) against closed forms that share no code
with them: the vector laws of reflection and refraction and the Fresnel coefficients of
raytrace/em.py (themselves checked against ``tmm`` in test_em.py), Beer-Lambert absorption
from the Gabriel tissue model, the straight-line intersection with a plane, and the exact
normal of a sphere. The tracer-level oracles (test_tracer_*.py) exercise the same kernels
through whole paths."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.body.library import half_space, homogeneous_sphere
from raytrace.body.phantom import Material
from raytrace.engine import kernels
from raytrace.engine.records import ShotRays, build
from raytrace.engine.scene import scene_for
from raytrace.physics import em
from raytrace.solver import sbr
from raytrace.solver.launch import fibonacci_sphere
from raytrace.solver.media import MediaTable

FREQUENCY_HZ = 402e6


@pytest.fixture(scope="module")
def one_bounce():
    """One bounce of ~3500 rays from the half-space's transmitter (muscle, 30 mm behind the
    planar muscle/air face y = 0) towards that face, through :func:`raytrace.solver.sbr._bounce`."""
    phantom = half_space()
    media = MediaTable.build(phantom, np.array([FREQUENCY_HZ]))
    scene = scene_for(phantom, ~media.face_transparent)
    tx = np.asarray(phantom.sites["tx"].position_m, float)
    d = fibonacci_sphere(20_000)
    d = d[d[:, 1] < -0.3]  # towards the face, hitting it within 0.1 m of the foot point
    n = len(d)
    ctx = sbr._context(scene, media, np.array([[0.0, -0.05, 0.0]]), np.array([-1]), kmax=6, dynamic_range_db=200.0)
    state = build(
        ShotRays,
        o=np.broadcast_to((tx - scene.center).astype(np.float32), (n, 3)).copy(), d=d.astype(np.float32),
        med=np.full(n, 0, np.int64), w=np.ones(n, np.float32), rad=np.zeros(n, np.float32),
        ang=np.full(n, 1e-3, np.float32), length=np.zeros(n, np.float32), nint=np.zeros(n, np.int64),
        hist=np.full(n, -1, np.int64), src=np.arange(n), mode=np.zeros(n, np.int8),
    )
    log, found = sbr._Log(), sbr._Found()
    _cast, children = sbr._bounce(ctx, state, log, found)
    return scene, tx, d, children, log


def _split(children):
    """Reflected children (back in muscle, medium 0) and transmitted ones (air, -1)."""
    refl = children.med == 0
    return sbr._take(children, np.flatnonzero(refl)), sbr._take(children, np.flatnonzero(~refl))


def test_bounce_directions_follow_the_laws_of_reflection_and_refraction(one_bounce):
    scene, _tx, d, children, _log = one_bounce
    refl, trans = _split(children)
    normal = np.array([0.0, -1.0, 0.0])  # the face's outward normal (muscle -> air)
    n_muscle = em.refractive_index(Material(tissue="muscle").complex_relative_permittivity(FREQUENCY_HZ))
    # every ray reflects (R > 0 everywhere); float32 arithmetic: 1e-6 covers a few roundings
    assert len(refl.d) == len(d)
    expected_r = em.reflect_direction(d[refl.src], normal)
    np.testing.assert_allclose(refl.d, expected_r, atol=1e-6)
    expected_t, tir = em.refract_direction(d, normal, n_muscle, 1.0)
    # transmitted children exactly for the rays inside the critical angle (~7 deg from muscle)
    assert set(trans.src.tolist()) == set(np.flatnonzero(~tir).tolist())
    assert 0 < len(trans.d) < len(d) // 4
    # float32: cos_t = sqrt(1 - eta^2 sin^2 i) loses ~eta^2 eps32 / cos_t near grazing (eta = 8.6)
    cos_t = -expected_t[trans.src, 1]
    tol = 1e-6 + n_muscle.real ** 2 * 1.2e-7 / cos_t
    assert (np.abs(trans.d - expected_t[trans.src]).max(axis=1) <= tol).all()
    # Snell's law itself, n1 sin(theta_i) = n2 sin(theta_t), on the transmitted rays
    sin_i = np.linalg.norm(np.cross(d[trans.src], normal), axis=1)
    sin_t = np.linalg.norm(np.cross(trans.d.astype(float), normal), axis=1)
    np.testing.assert_allclose(n_muscle.real * sin_i, sin_t, atol=2e-6)


def test_bounce_hit_points_lie_on_the_plane_along_each_ray(one_bounce):
    scene, tx, d, children, _log = one_bounce
    refl, _trans = _split(children)
    t = tx[1] / -d[refl.src, 1]  # straight line to the plane y = 0
    expected = tx + t[:, None] * d[refl.src]
    got = refl.o.astype(float) + scene.center  # reflected origins: the hit, pushed back into muscle
    # float32 positions at the scene's 1 m scale (ulp 6e-8 m) plus the spawn offset (16 ulps)
    np.testing.assert_allclose(got, expected, atol=scene.offset_m + 1e-6)
    assert (got[:, 1] > 0.0).all()  # pushed to the muscle side
    _r, trans = _split(children)
    assert (trans.o[:, 1].astype(float) + scene.center[1] < 0.0).all()  # pushed to the air side


def test_bounce_power_split_is_fresnel_times_beer_lambert(one_bounce):
    _scene, tx, d, children, log = one_bounce
    refl, trans = _split(children)
    eps = Material(tissue="muscle").complex_relative_permittivity(FREQUENCY_HZ)
    n_muscle = em.refractive_index(eps)
    alpha = em.attenuation_np_per_m(eps, FREQUENCY_HZ)
    t = tx[1] / -d[:, 1]
    absorbed = np.exp(-2.0 * alpha * t)  # power: Beer-Lambert over the path in muscle
    cos_i = -d[:, 1]
    f = em.fresnel(n_muscle.real, 1.0, np.clip(cos_i, 0.0, 1.0))  # lossless Fresnel on Re n (pruning weight)
    r_power = 0.5 * (em.power_reflectance(f.r_te) + em.power_reflectance(f.r_tm))
    # float32 weights: 1e-5 relative
    np.testing.assert_allclose(refl.w, (absorbed * r_power)[refl.src], rtol=1e-5)
    np.testing.assert_allclose(trans.w, (absorbed * (1.0 - r_power))[trans.src], rtol=1e-5, atol=1e-9)
    # every child is logged once with its code: face of organ 0 left (leaving = 1), reflect bit
    codes = np.concatenate(log.code)
    assert len(codes) == len(refl.w) + len(trans.w)
    assert (codes[:len(refl.w)] == (0 * 2 + 1) * 2 + 1).all() and (codes[len(refl.w):] == (0 * 2 + 1) * 2).all()
    # reduced length L / Re n and the tube radius grown by the launch angle over the leg
    np.testing.assert_allclose(refl.length, (t / n_muscle.real)[refl.src], rtol=1e-5)
    np.testing.assert_allclose(refl.rad, 1e-3 * t[refl.src], rtol=1e-5)


@pytest.mark.parametrize("events", [0, 6])
def test_bounce_reception_is_the_ray_tube_width(events):
    """A receiver at perpendicular distance h from a ray, a distance s along it, is a candidate
    iff h <= rad + s * ang (the tube's half-width there); the same for a ray that already has
    max_interactions events (cast only to be received: no children)."""
    phantom = half_space()
    media = MediaTable.build(phantom, np.array([FREQUENCY_HZ]))
    scene = scene_for(phantom, ~media.face_transparent)
    tx = np.asarray(phantom.sites["tx"].position_m, float)
    d = np.array([0.0, -1.0, 0.0])
    s, ang, rad = 0.02, 0.01, 1e-3
    width = rad + s * ang
    offsets = np.array([0.5, 0.9, 1.1, 2.0]) * width
    rx = tx + s * d + offsets[:, None] * np.array([1.0, 0.0, 0.0])
    ctx = sbr._context(scene, media, rx, np.zeros(len(rx), np.int64), kmax=6, dynamic_range_db=80.0)
    state = build(
        ShotRays,
        o=(tx - scene.center).astype(np.float32)[None, :], d=d.astype(np.float32)[None, :],
        med=np.zeros(1, np.int64), w=np.ones(1, np.float32), rad=np.full(1, rad, np.float32),
        ang=np.full(1, ang, np.float32), length=np.zeros(1, np.float32), nint=np.full(1, events, np.int64),
        hist=np.full(1, -1, np.int64), src=np.zeros(1, np.int64), mode=np.zeros(1, np.int8),
    )
    found = sbr._Found()
    cast, children = sbr._bounce(ctx, state, sbr._Log(), found)
    assert cast == 1
    assert (children is None) == (events == 6)
    got = np.concatenate(found.rx)
    assert got.tolist() == [0, 1]
    np.testing.assert_allclose(np.concatenate(found.close), [0.5, 0.9], rtol=1e-4)


def test_bounce_casts_a_ray_without_children_only_if_a_receiver_is_on_its_line():
    """A ray with max_interactions events is cast only when a receiver of its class lies within
    its tube's width of its unbounded line; even then a receiver past the surface it hits (on
    the line, 1 cm beyond the face) is not received. Rays with events left are always cast."""
    phantom = half_space()
    media = MediaTable.build(phantom, np.array([FREQUENCY_HZ]))
    scene = scene_for(phantom, ~media.face_transparent)
    tx = np.asarray(phantom.sites["tx"].position_m, float)
    d = np.array([0.0, -1.0, 0.0])
    beyond = np.array([tx[0], -0.01, tx[2]])  # on the ray's line, past the plane y = 0
    off_line = tx + 0.02 * d + np.array([0.05, 0.0, 0.0])
    for rx, events, cast_expected in ((off_line, 6, 0), (off_line, 5, 1), (beyond, 6, 1)):
        ctx = sbr._context(scene, media, rx[None, :], np.zeros(1, np.int64), kmax=6, dynamic_range_db=80.0)
        state = build(
            ShotRays,
            o=(tx - scene.center).astype(np.float32)[None, :], d=d.astype(np.float32)[None, :],
            med=np.zeros(1, np.int64), w=np.ones(1, np.float32), rad=np.full(1, 1e-3, np.float32),
            ang=np.full(1, 0.01, np.float32), length=np.zeros(1, np.float32), nint=np.full(1, events, np.int64),
            hist=np.full(1, -1, np.int64), src=np.zeros(1, np.int64), mode=np.zeros(1, np.int8),
        )
        found = sbr._Found()
        cast, _children = sbr._bounce(ctx, state, sbr._Log(), found)
        assert cast == cast_expected
        assert not found.rx


def _sphere_faces(count: int, seed: int):
    """The faceted sphere's scene, its kernel tables, ``count`` of its faces at random and the
    generator that chose them."""
    scene = scene_for(homogeneous_sphere())
    rng = np.random.default_rng(seed)
    return scene, scene.kernel_tables, rng.choice(len(scene.faces), count, replace=False), rng


def test_smooth_normal_is_the_sphere_normal():
    """On a faceted sphere the interpolated normal (Max's vertex weights, exact on a sphere)
    equals the radial direction at the vertices to rounding, and inside a facet deviates from
    it by less than the angle between the facet's corners (linear interpolation)."""
    scene, tables, faces, rng = _sphere_faces(300, seed=7)
    for f in faces:
        tri = scene.vertices[scene.faces[f]]
        for corner in tri:
            n = np.array(kernels._smooth_normal(tables.frame, scene.face_normals, f, *corner))
            np.testing.assert_allclose(n, corner / np.linalg.norm(corner), atol=1e-9)
        w = rng.dirichlet(np.ones(3))
        point = w @ tri
        n = np.array(kernels._smooth_normal(tables.frame, scene.face_normals, f, *point))
        radial = point / np.linalg.norm(point)
        spread = max(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))
                     for a in tri for b in tri)
        assert abs(np.linalg.norm(n) - 1.0) < 1e-12
        assert np.arccos(np.clip(n @ radial, -1.0, 1.0)) <= spread


# ------------------------------------------------------------------ ray differentials (follow)
def _closed_form_last_leg(tx, d, n_muscle, reflect):
    """The half-space's one-event path in closed form: straight to the plane y = 0, then the
    law of reflection or Snell's law (raytrace.physics.em, checked against tmm in test_em.py)."""
    t = tx[1] / -d[:, 1]
    point = tx + t[:, None] * d
    normal = np.array([0.0, -1.0, 0.0])
    if reflect:
        return point, em.reflect_direction(d, normal)
    out, _tir = em.refract_direction(d, normal, n_muscle, 1.0)
    return point, out


def _half_space_tracing():
    """The half-space's propagation scene, media, transmitter (position, medium) and the
    muscle's refractive index at the test frequency."""
    phantom = half_space()
    media = MediaTable.build(phantom, np.array([FREQUENCY_HZ]))
    scene = scene_for(phantom, ~media.face_transparent)
    tx = np.asarray(phantom.sites["tx"].position_m, float)
    tx_medium = int(phantom.medium_index(tx[None])[0])
    n_muscle = em.refractive_index(Material(tissue="muscle").complex_relative_permittivity(FREQUENCY_HZ))
    return scene, media, tx, tx_medium, n_muscle


@pytest.mark.parametrize("reflect", [False, True])
def test_ray_differentials_equal_the_closed_form_derivatives_at_a_plane(reflect):
    """Derivatives of the last point and direction by the two launch angles: the kernel's
    differentials against central differences (h = 1e-6 rad, truncation ~h^2) of the closed
    form, for refraction into air and reflection back into muscle at the half-space's face.
    Tolerance 1e-7 relative to the derivative's size (the closed form's rounding / h)."""
    from raytrace.solver import refine

    scene, media, tx, tx_medium, n_muscle = _half_space_tracing()
    d = fibonacci_sphere(40_000)
    limit = 0.99 if reflect else 0.995  # inside the ~7 deg critical cone for refraction
    d = d[-d[:, 1] > limit]
    assert len(d) > 10
    code = refine.encode(0, True, reflect)
    res = refine.follow(scene, media, tx, tx_medium, d, np.full((len(d), 1), code), np.ones(len(d), np.int64),
                        tangents=refine.tangent_basis(d))
    assert res.ok.all()
    u, v = refine.tangent_basis(d)
    h = 1e-6
    for c, t in enumerate((u, v)):
        plus = _closed_form_last_leg(tx, refine._normalize(d + h * t), n_muscle, reflect)
        minus = _closed_form_last_leg(tx, refine._normalize(d - h * t), n_muscle, reflect)
        for got, hi, lo in ((res.d_point[:, c], plus[0], minus[0]), (res.d_dir[:, c], plus[1], minus[1])):
            expected = (hi - lo) / (2 * h)
            scale = np.linalg.norm(expected, axis=1, keepdims=True)
            assert (np.abs(got - expected) <= 1e-7 * np.maximum(scale, 1.0)).all()


def test_smooth_normal_gradient_is_the_derivative_of_the_smooth_normal():
    """Inside a facet of the faceted sphere, the differential the kernels use for the smooth
    normal equals the central difference of the smooth normal itself (h = 1e-7 m, inside the
    facet; tolerance 1e-6 of the gradient's scale 1/R = 10 /m)."""
    scene, tables, faces, rng = _sphere_faces(200, seed=5)
    for f in faces:
        tri = scene.vertices[scene.faces[f]]
        b = rng.dirichlet([4.0, 4.0, 4.0])  # well inside the triangle
        point = b @ tri
        e1 = tri[1] - tri[0]
        e2 = np.cross(scene.face_normals[f], e1)
        grad = kernels._smooth_normal_gradient(tables.frame, scene.face_normals, f, *point)
        gv, gw, a1, a2, inv_m = np.array(grad[0:3]), np.array(grad[3:6]), np.array(grad[6:9]), \
            np.array(grad[9:12]), grad[12]
        n0 = np.array(kernels._smooth_normal(tables.frame, scene.face_normals, f, *point))
        for e in (e1 / np.linalg.norm(e1), e2 / np.linalg.norm(e2)):
            dm = a1 * (gv @ e) + a2 * (gw @ e)
            dn = (dm - n0 * (n0 @ dm)) * inv_m
            h = 1e-7
            hi = np.array(kernels._smooth_normal(tables.frame, scene.face_normals, f, *(point + h * e)))
            lo = np.array(kernels._smooth_normal(tables.frame, scene.face_normals, f, *(point - h * e)))
            np.testing.assert_allclose(dn, (hi - lo) / (2 * h), atol=1e-5)


@pytest.mark.parametrize("first", [0, 2])
def test_line_search_accepts_the_first_fraction_from_its_start_that_reduces_the_miss(first):
    """Newton's backtracking in the kernel (line-search mode of follow): from each ray's start
    index on, the fractions are tried in order and the first whose last leg passes the receiver
    closer than the old miss wins. Oracle: the half-space's closed-form last leg for every trial
    launch (a trial beyond the critical angle breaks the signature and never wins). Receivers
    lie on the last legs of nearby launches, so some trials reduce the miss and some overshoot."""
    from raytrace.solver import refine

    scene, media, tx, tx_medium, n_muscle = _half_space_tracing()
    rng = np.random.default_rng(3)
    d = fibonacci_sphere(40_000)
    base = d[-d[:, 1] > 0.997][:60]
    target = refine._normalize(base + rng.normal(scale=0.03, size=base.shape))
    p_t, d_t = _closed_form_last_leg(tx, target, n_muscle, reflect=False)
    rx = p_t + 0.1 * d_t
    step = rng.normal(scale=0.08, size=(len(base), 2))

    def miss(launch):
        point, out = _closed_form_last_leg(tx, launch, n_muscle, reflect=False)
        _out, tir = em.refract_direction(launch, np.array([0.0, -1.0, 0.0]), n_muscle, 1.0)
        w = rx - point
        tau = np.einsum("ij,ij->i", w, out)
        off = np.linalg.norm(w - tau[:, None] * out, axis=1)
        return np.where(tir | ~np.isfinite(off) | (tau <= 0), np.inf, off)

    old = miss(base)
    u, v = refine.tangent_basis(base)
    fractions = 0.5 ** np.arange(6)
    trial_miss = np.stack([miss(refine._normalize(base + f * (step[:, :1] * u + step[:, 1:] * v)))
                           for f in fractions], axis=1)
    expected = np.full(len(base), -1)
    for i in range(len(base)):
        wins = np.flatnonzero(trial_miss[i, first:] < old[i])
        if len(wins):
            expected[i] = first + wins[0]
    assert len(set(expected.tolist())) >= 3  # the cases are not all alike
    code = refine.encode(0, True, False)
    res = refine.follow(scene, media, tx, tx_medium, base, np.full((len(base), 1), code),
                        np.ones(len(base), np.int64),
                        line_search=(fractions, step, rx, old, np.full(len(base), first)))
    np.testing.assert_array_equal(res.won, expected)
    ok = expected >= 0
    tilt = step[ok, :1] * u[ok] + step[ok, 1:] * v[ok]
    won_launch = refine._normalize(base[ok] + fractions[expected[ok], None] * tilt)
    np.testing.assert_allclose(res.launch_dir[ok], won_launch, atol=1e-12)


@pytest.mark.parametrize("reflect", [False, True])
def test_newton_converges_to_the_closed_form_launch_and_ray_tube(reflect):
    """The Newton kernel (refine): receivers placed on the closed-form last legs of known
    launches, seeds 0.02 rad off them. Every seed must converge to its launch (tolerance 1e-7
    rad: the 1e-9 m miss over the ~0.1 m lever) with the ray tube |det J| of the closed form's
    landing map, by central differences (h = 1e-6 rad; 1e-5 relative: truncation ~h^2 and
    rounding ~1e-16 / h^2 of the offsets). A receiver back in the muscle has no path refracted
    into the air and must not converge."""
    from raytrace.solver import refine

    scene, media, tx, tx_medium, n_muscle = _half_space_tracing()
    rng = np.random.default_rng(5)
    d = fibonacci_sphere(40_000)
    launch = d[-d[:, 1] > (0.99 if reflect else 0.997)][::3][:40]
    point, out = _closed_form_last_leg(tx, launch, n_muscle, reflect)
    rx = point + rng.uniform(0.05, 0.2, (len(launch), 1)) * out
    seeds = refine._normalize(launch + rng.normal(scale=0.02 / np.sqrt(3), size=launch.shape))
    code = refine.encode(0, True, reflect)
    codes, nint = np.full((len(launch), 1), code), np.ones(len(launch), np.int64)
    got = refine.refine(scene, media, tx, tx_medium, rx, seeds, codes, nint)
    assert got.converged.all()
    np.testing.assert_allclose(got.dirs, launch, atol=1e-7)

    def landing(dirs, i):  # offset of the closed-form last leg at receiver i, in the plane normal to it
        p, o = _closed_form_last_leg(tx, dirs, n_muscle, reflect)
        w = rx[i] - p
        x = p + np.einsum("ij,ij->i", w, o)[:, None] * o - rx[i]
        e1, e2 = refine.tangent_basis(out[i:i + 1])
        return np.stack([x @ e1[0], x @ e2[0]], axis=1)

    u, v = refine.tangent_basis(launch)
    h = 1e-6
    for i in range(len(launch)):
        cols = [(landing(refine._normalize(launch[i:i + 1] + h * t[i:i + 1]), i)
                 - landing(refine._normalize(launch[i:i + 1] - h * t[i:i + 1]), i))[0] / (2 * h) for t in (u, v)]
        expected = abs(np.linalg.det(np.stack(cols, axis=1)))
        assert abs(got.tube_m2_per_sr[i] - expected) <= 1e-5 * expected
    if not reflect:
        inside = rx.copy()
        inside[:, 1] = 0.01  # the muscle is y > 0 (the transmitter at y = 0.03), the air y < 0
        assert not refine.refine(scene, media, tx, tx_medium, inside, seeds, codes, nint).converged.any()


def test_spread_picks_is_the_greedy_thinning():
    """The seed thinning kernel against the greedy loop written out in Python: per group, best
    first, keep a launch unless it is within the separation of one already kept, up to the cap
    per group. Random directions clustered so that all three outcomes occur (kept, too close,
    group full)."""
    rng = np.random.default_rng(11)
    n = 400
    group = np.sort(rng.integers(0, 30, n))
    centres = rng.normal(size=(30, 3))
    dirs = centres[group] + rng.normal(scale=0.05, size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    score = rng.random(n)
    order = np.lexsort((score, group))
    starts = np.flatnonzero(np.r_[True, group[order][1:] != group[order][:-1], True])
    min_cos, cap = np.cos(0.05), 3
    expected = np.zeros(n, bool)
    for a, b in zip(starts[:-1], starts[1:]):
        kept = []
        for idx in order[a:b]:
            if len(kept) < cap and all(dirs[idx] @ dirs[k] < min_cos for k in kept):
                kept.append(idx)
        expected[kept] = True
    got = kernels.spread_picks(order, starts, dirs, min_cos, cap)
    np.testing.assert_array_equal(got, expected)
    kept, size = np.bincount(group[expected], minlength=30), np.bincount(group, minlength=30)
    assert kept.max() == cap  # a full group
    assert (kept < np.minimum(size, cap)).any()  # a group thinned by the separation


def test_per_ray_helpers_borrow_their_arrays_without_reference_counting():
    """Every private helper the kernels call (all but ``_grow``, which allocates) is compiled
    with numba's reference counting off: with it on, each call of ``_trace_ray`` or
    ``_line_search`` did an atomic incref and decref of ~35 array arguments, 40 % of Newton's
    time (raytrace/kernels.py, ``_helper``). Only the compile options are checked here; the
    helpers' arithmetic is checked against closed forms above."""
    from numba.core.registry import CPUDispatcher

    helpers = {name: d for name, d in vars(kernels).items() if isinstance(d, CPUDispatcher) and name.startswith("_")}
    assert {"_trace_ray", "_line_search", "_smooth_normal", "_carry_differentials", "_tube_miss"} <= set(helpers)
    counting = sorted(name for name, d in helpers.items() if d.targetoptions.get("_nrt") is not False)
    assert counting == ["_grow"]


def test_seed_clusters_are_the_components_of_the_linked_pairs():
    """raytrace.solver.tracer._clusters (cells + union-find in a kernel) against the connected
    components of every pair within the link, listed by a k-d tree (scipy), labels included:
    random unit vectors in groups, links from a tenth of a degree to tens of degrees, and points
    at exactly the link apart along an axis."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    from raytrace.solver.tracer import _clusters

    def pairs_components(group, dirs, link):
        pts = dirs.copy()
        pts[:, 0] += 3.0 * group
        pairs = cKDTree(pts).query_pairs(link, output_type="ndarray")
        graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(dirs),) * 2)
        return connected_components(graph, directed=False)[1]

    rng = np.random.default_rng(7)
    for _ in range(100):
        n = int(rng.integers(1, 400))
        centre = rng.normal(size=3)
        dirs = centre + rng.normal(scale=rng.uniform(0.001, 0.5), size=(n, 3))  # clumps, as candidates are
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        group = rng.integers(0, 4, n)
        link = float(rng.uniform(0.002, 0.6))
        np.testing.assert_array_equal(_clusters(group, dirs, link), pairs_components(group, dirs, link))
    line = np.array([[0.0, 0.0, 1.0], [0.01, 0.0, 1.0], [0.02, 0.0, 1.0], [0.05, 0.0, 1.0]])
    np.testing.assert_array_equal(_clusters(np.zeros(4, np.int64), line, 0.01), [0, 0, 0, 1])
