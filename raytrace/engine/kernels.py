"""Compiled per-ray kernels (numba, without the GIL) for the tracer's inner loops.

Why compiled code and not numpy here: Newton refinement (:mod:`raytrace.solver.refine`)
re-traces a few thousand rays per iteration, a few dozen times, with a dozen
numpy operations per ray step. At that batch size each numpy call costs more
in interpreter overhead than in arithmetic, and the work holds the GIL, so two
threads did not help (docs/tracer.md, "Tried and dropped"). The shooting's
bounce and the refraction-only walk were large-batch numpy, but made a dozen
temporaries of every ray per bounce. These kernels do the same arithmetic one
ray at a time in compiled code. :func:`follow` and :func:`bounce` call Embree
themselves (:mod:`raytrace.engine.embree`): :func:`newton` takes each seed through
all its Newton iterations (re-tracing, Jacobian, step, line search) in one
call, :func:`follow` each ray through its whole signature, and the shooting
casts and splits a generation of rays in one call; Python drives only the
shooting's generations. :func:`walk_step` still gets Embree's answers from the caller.

The formulas are those of the numpy code they replaced, written per ray:
the float64 re-intersection of :meth:`raytrace.engine.scene.TracerScene.first_hit`,
the smooth normal of :meth:`raytrace.engine.scene.TracerScene.smooth_normals`, the
law of reflection and the vector Snell law of :func:`raytrace.physics.em.refract_direction`
(``t = eta (d - cos_i n) + cos_t n``, Born & Wolf 1.5) without its input
checks. They are tested against the independent closed forms of
:mod:`raytrace.physics.em` in tests/raytrace/test_kernels.py and, through the tracer, against
every oracle of docs/tracer.md.

The kernels take named records (:mod:`raytrace.engine.records`: the scene's face tables, the
media table, the per-ray state, the step records, ...) built and checked once in Python;
the small per-step helpers take only the arrays they read. Compiled by
:mod:`raytrace.engine.jit` (cached on disk, keyed on the engine's sources, so only the first
process after an install or an edit compiles: ~20 s; :func:`raytrace.solver.tracer.warm_up`
does it ahead of the first request). Embree is called by symbol name, so the cached code
stays valid in a new process.

It stays one module (about 1000 lines) because it is one thing: the tracer's compiled per-ray
loops and the per-step helpers they share (hit, normal, reflect/refract, record a step), compiled,
cached and tested together; the helpers mean nothing outside these loops.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from raytrace.engine import embree
from raytrace.engine.jit import helper, kernel
from raytrace.engine.records import LogEntries, Receptions, ShotRays, TraceState, WalkRays

KIND_REFRACTION = 0
KIND_REFLECTION = 1
KIND_PASS = 2
_ZERO_GRADIENT = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


class _Trial(NamedTuple):
    """Where one Newton line search of a ray starts from (point, medium), along which base
    launch and full step, towards which receiver, and the miss it must beat (scalars, made in
    the kernel)."""

    sx: float
    sy: float
    sz: float
    medium: int
    bx: float
    by: float
    bz: float
    s0: float
    s1: float
    rx: float
    ry: float
    rz: float
    old_miss: float


@helper
def _smooth_normal(frame, face_normals, f, x, y, z):
    """Smooth unit normal at point (x, y, z) of face f: barycentrics from the face's frame row,
    clipped to [0, 1], corner normals interpolated; the facet normal if the result degenerates
    or flips (:meth:`raytrace.engine.scene.TracerScene.smooth_normals`)."""
    fr = frame[f]
    v2x, v2y, v2z = x - fr[0], y - fr[1], z - fr[2]
    d20 = v2x * fr[3] + v2y * fr[4] + v2z * fr[5]
    d21 = v2x * fr[6] + v2y * fr[7] + v2z * fr[8]
    d00, d01, d11, den = fr[9], fr[10], fr[11], fr[12]
    bv = (d11 * d20 - d01 * d21) / den
    bw = (d00 * d21 - d01 * d20) / den
    bu = 1.0 - bv - bw
    bu = min(max(bu, 0.0), 1.0)
    bv = min(max(bv, 0.0), 1.0)
    bw = min(max(bw, 0.0), 1.0)
    nx = bu * fr[13] + bv * fr[16] + bw * fr[19]
    ny = bu * fr[14] + bv * fr[17] + bw * fr[20]
    nz = bu * fr[15] + bv * fr[18] + bw * fr[21]
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    fx, fy, fz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
    if not norm > 1e-12:
        return fx, fy, fz
    nx, ny, nz = nx / norm, ny / norm, nz / norm
    if nx * fx + ny * fy + nz * fz <= 0.0:
        return fx, fy, fz
    return nx, ny, nz


@helper
def _smooth_normal_gradient(frame, face_normals, f, x, y, z):
    """What the differential of :func:`_smooth_normal` at point (x, y, z) of face f needs:
    the barycentrics are affine in the point, ``dv = gv.dP``, ``dw = gw.dP``, so the
    interpolated normal moves by ``dM = (n1 - n0)(gv.dP) + (n2 - n0)(gw.dP)`` and the unit one
    by ``dN = (dM - N (N.dM)) / |M|``. Returns ``(gv, gw, n1 - n0, n2 - n0, 1 / |M|)`` as 13
    scalars; all zero where the facet normal stands in (degenerate or flipped: dN = 0)."""
    fr = frame[f]
    v2x, v2y, v2z = x - fr[0], y - fr[1], z - fr[2]
    d20 = v2x * fr[3] + v2y * fr[4] + v2z * fr[5]
    d21 = v2x * fr[6] + v2y * fr[7] + v2z * fr[8]
    d00, d01, d11, den = fr[9], fr[10], fr[11], fr[12]
    bv = min(max((d11 * d20 - d01 * d21) / den, 0.0), 1.0)
    bw = min(max((d00 * d21 - d01 * d20) / den, 0.0), 1.0)
    bu = min(max(1.0 - (d11 * d20 - d01 * d21) / den - (d00 * d21 - d01 * d20) / den, 0.0), 1.0)
    mx = bu * fr[13] + bv * fr[16] + bw * fr[19]
    my = bu * fr[14] + bv * fr[17] + bw * fr[20]
    mz = bu * fr[15] + bv * fr[18] + bw * fr[21]
    norm = math.sqrt(mx * mx + my * my + mz * mz)
    if not norm > 1e-12 or mx * face_normals[f, 0] + my * face_normals[f, 1] + mz * face_normals[f, 2] <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return ((d11 * fr[3] - d01 * fr[6]) / den, (d11 * fr[4] - d01 * fr[7]) / den, (d11 * fr[5] - d01 * fr[8]) / den,
            (d00 * fr[6] - d01 * fr[3]) / den, (d00 * fr[7] - d01 * fr[4]) / den, (d00 * fr[8] - d01 * fr[5]) / den,
            fr[16] - fr[13], fr[17] - fr[14], fr[18] - fr[15], fr[19] - fr[13], fr[20] - fr[14], fr[21] - fr[15],
            1.0 / norm)


@helper
def _smooth_normal_uv(corner, face_normals, f, bu, bv):
    """Smooth unit normal of face f from Embree's barycentrics ``(u, v)``:
    ``n0 + u (n1 - n0) + v (n2 - n0)`` over the face's corner-table row, normalised; the facet
    normal if it degenerates or flips (float32-accurate: enough for seeds)."""
    g = corner[f]
    nx = g[0] + bu * g[3] + bv * g[6]
    ny = g[1] + bu * g[4] + bv * g[7]
    nz = g[2] + bu * g[5] + bv * g[8]
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    fx, fy, fz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
    nx, ny, nz = nx / norm, ny / norm, nz / norm
    if not nx * fx + ny * fy + nz * fz > 0.0:
        return fx, fy, fz
    return nx, ny, nz


@helper
def _smooth_normal_uv64(frame, face_normals, f, bu, bv):
    """:func:`_smooth_normal_uv` in float64 from the face's frame row (corner normals in columns
    13-21; the differences to the first are taken here, the same numbers as a precomputed table)."""
    fr = frame[f]
    nx = fr[13] + bu * (fr[16] - fr[13]) + bv * (fr[19] - fr[13])
    ny = fr[14] + bu * (fr[17] - fr[14]) + bv * (fr[20] - fr[14])
    nz = fr[15] + bu * (fr[18] - fr[15]) + bv * (fr[21] - fr[15])
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    fx, fy, fz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
    nx, ny, nz = nx / norm, ny / norm, nz / norm
    if not nx * fx + ny * fy + nz * fz > 0.0:
        return fx, fy, fz
    return nx, ny, nz


@helper
def _sides(face_organ, parent, f, d_dot_n):
    """Which side of face f a ray with ``d . n_facet = d_dot_n`` crosses: ``(leaving, organ,
    m_from, m_to)``; leaving its organ into the parent when the direction is along the outward
    facet normal, else entering it from the parent (the containment tree of docs/tracer.md)."""
    organ = face_organ[f]
    leaving = d_dot_n > 0.0
    par = parent[organ]
    return leaving, organ, (organ if leaving else par), (par if leaving else organ)


@helper
def _plane_distance(face_normals, plane_d, f, ox, oy, oz, dx, dy, dz, t32):
    """Float64 distance along the unit direction from the true origin to face f's plane
    (``(n.v0 - n.o) / (n.d)``, clamped at 0), Embree's float32 ``t32`` if the ray is parallel."""
    fx, fy, fz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
    denom = fx * dx + fy * dy + fz * dz
    if abs(denom) > 1e-12:
        t64 = (plane_d[f] - (fx * ox + fy * oy + fz * oz)) / denom
        if math.isfinite(t64):
            return max(t64, 0.0)
    return np.float64(t32)


@helper
def _refract(dx, dy, dz, nx, ny, nz, eta):
    """Vector Snell law (Born & Wolf 1.5): ``t = eta (d - ci nf) + ct nf`` with ``nf`` the normal
    oriented along ``d``, ``eta = Re n1 / Re n2``. Returns ``(tir, tx, ty, tz, ci, ct)``;
    under total internal reflection (``eta^2 (1 - ci^2) > 1``) ``t`` is meaningless."""
    dns = dx * nx + dy * ny + dz * nz
    s = -1.0 if dns < 0.0 else 1.0
    ci = abs(dns)
    sin2 = eta * eta * (1.0 - ci * ci)
    ct = math.sqrt(max(1.0 - sin2, 0.0))
    tx = eta * (dx - ci * s * nx) + ct * s * nx
    ty = eta * (dy - ci * s * ny) + ct * s * ny
    tz = eta * (dz - ci * s * nz) + ct * s * nz
    tn = math.sqrt(tx * tx + ty * ty + tz * tz)
    return sin2 > 1.0, tx / tn, ty / tn, tz / tn, ci, ct


@kernel
def _grow(a, size):
    out = np.empty(size, a.dtype)
    out[:len(a)] = a
    return out


@helper
def _tube_miss(rx_m, r, o, d, i, reach, rad, ang, reception_factor):
    """Whether ray i's segment (length ``reach``) passes receiver r within the ray tube's
    half-width ``reception_factor * (rad + s * ang)`` at the closest point, ``s`` along the ray;
    returns ``(received, miss, radius)``."""
    vx, vy, vz = rx_m[r, 0] - o[i, 0], rx_m[r, 1] - o[i, 1], rx_m[r, 2] - o[i, 2]
    tt = vx * d[i, 0] + vy * d[i, 1] + vz * d[i, 2]
    if not (tt > 0.0 and tt < reach):
        return False, 0.0, 0.0
    px, py, pz = vx - tt * d[i, 0], vy - tt * d[i, 1], vz - tt * d[i, 2]
    perp = math.sqrt(px * px + py * py + pz * pz)
    radius = reception_factor * (rad[i] + tt * ang[i])
    return perp <= radius, perp, radius


@helper
def _segment_miss(vx, vy, vz, dx, dy, dz, reach):
    """Distance from a receiver at offset (vx, vy, vz) from a leg's start to the leg (unit
    direction d, length ``reach``): the closest point clamped to the leg (the walks' miss)."""
    tp = min(max(vx * dx + vy * dy + vz * dz, 0.0), reach)
    ex, ey, ez = vx - tp * dx, vy - tp * dy, vz - tp * dz
    return math.sqrt(ex * ex + ey * ey + ez * ez)


@helper
def _may_receive(rx_m, rx_zone, ray_zone, o, d, i, rad, ang, reception_factor):
    """Whether :func:`_tube_miss` could receive ray i at some receiver of its zone for any
    segment length (the test with an unbounded segment)."""
    for r in range(len(rx_m)):
        if rx_zone[r] == ray_zone and _tube_miss(rx_m, r, o, d, i, np.inf, rad, ang, reception_factor)[0]:
            return True
    return False


@helper
def _may_return(w, alpha_m, return_m, threshold, px, py, pz, dx, dy, dz, bounds):
    """Whether a ray of power factor ``w`` spawned at (px, py, pz) along d in a medium from which
    no receiver can be reached without an interaction may still make a reception: not if the
    absorption over the least length it must travel before it can cross towards a receiver
    (``return_m``) brings it below ``threshold`` (every later power factor is lower), nor if it
    leaves the scene's box ``bounds`` (it is outside the box on an axis and moves away from it
    there: it can hit nothing). Both exact."""
    if return_m > 0.0 and w * math.exp(-2.0 * alpha_m * return_m) < threshold:
        return False
    if (px > bounds[1, 0] and dx > 0.0) or (px < bounds[0, 0] and dx < 0.0):
        return False
    if (py > bounds[1, 1] and dy > 0.0) or (py < bounds[0, 1] and dy < 0.0):
        return False
    if (pz > bounds[1, 2] and dz > 0.0) or (pz < bounds[0, 2] and dz < 0.0):
        return False
    return True


@helper
def _trace_ray(i, hit, scene, media, state, steps, max_steps, differentials, dp, dd):
    """Ray ``i`` of :func:`follow` traced on from its current ``state`` (a
    :class:`~raytrace.engine.records.TraceState`, updated in place) to its end, at most
    ``max_steps`` casts through ``hit`` into ``scene`` (:class:`~raytrace.engine.records.SceneTables`,
    ``media`` :class:`~raytrace.engine.records.MediaTables`); in record mode each step is written
    into ``steps`` (:class:`~raytrace.engine.records.StepRecords`); with ``differentials``,
    ``dp`` / ``dd`` are carried along. Returns the rays cast."""
    o, d, med, push, k, nint, ok, done = state.o, state.d, state.med, state.push, state.k, state.nint, state.ok, \
        state.done
    codes, targets, record = state.codes, state.targets, state.record
    handle, mask, base, center, offset_m = scene.handle, scene.mask, scene.base, scene.center, scene.offset_m
    face_normals, plane_d, frame, face_organ = scene.face_normals, scene.plane_d, scene.frame, scene.face_organ
    parent, cls, transparent, n_re = media.parent, media.material_class, media.transparent, media.n_real
    n_codes = codes.shape[1]
    s = 0
    while ok[i] and not done[i] and s < max_steps:
        final = k[i] >= nint[i]
        if record and final:
            tx, ty, tz = targets[i, 0] - o[i, 0], targets[i, 1] - o[i, 1], targets[i, 2] - o[i, 2]
            nrm = math.sqrt(tx * tx + ty * ty + tz * tz)
            d[i, 0], d[i, 1], d[i, 2] = tx / nrm, ty / nrm, tz / nrm
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
        f, t32, _u, _v = embree.intersect(
            handle, mask, base, hit, np.float32(ox - center[0] + push[i, 0]),
            np.float32(oy - center[1] + push[i, 1]), np.float32(oz - center[2] + push[i, 2]),
            np.float32(dx), np.float32(dy), np.float32(dz))
        s += 1
        if f < 0:
            if record and final:
                done[i] = True  # nothing between the last event and the target
            else:
                ok[i] = False
            break
        fx, fy, fz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
        # float64 re-intersection with the hit triangle's plane from the true origin
        t = _plane_distance(face_normals, plane_d, f, ox, oy, oz, dx, dy, dz, t32)
        if record and final:
            tx, ty, tz = targets[i, 0] - ox, targets[i, 1] - oy, targets[i, 2] - oz
            if t >= math.sqrt(tx * tx + ty * ty + tz * tz):
                done[i] = True  # the target comes before the hit
                break
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        leaving, organ, m_from, m_to = _sides(face_organ, parent, f, fx * dx + fy * dy + fz * dz)
        sgn = 1.0 if leaving else -1.0
        is_transparent = transparent[f]
        expected = -1
        if not final and n_codes > 0:
            expected = codes[i, min(k[i], n_codes - 1)]
        reflect = (expected & 1) == 1
        event = not is_transparent and not final
        bad = cls[m_from + 1] != cls[med[i] + 1]  # the ray is not in the medium it thinks
        bad = bad or (not is_transparent and final)  # a real surface blocks the last leg
        code = (organ * 2 + (1 if leaving else 0)) * 2 + (1 if reflect else 0)
        bad = bad or (event and code != expected)
        if bad:
            ok[i] = False
            break
        nx, ny, nz = _smooth_normal(frame, face_normals, f, px, py, pz)
        ndx, ndy, ndz = dx, dy, dz
        pfac = sgn
        if is_transparent or not reflect:
            new_med = m_to
        else:
            new_med = m_from
        if event and reflect:
            dn = dx * nx + dy * ny + dz * nz
            ndx, ndy, ndz = dx - 2.0 * dn * nx, dy - 2.0 * dn * ny, dz - 2.0 * dn * nz
            pfac = -sgn
            if (ndx * fx + ndy * fy + ndz * fz) * sgn >= 0.0:
                ok[i] = False  # the smooth normal sent the reflection through the facet
                break
        elif event:
            tir, ndx, ndy, ndz, _ci, _ct = _refract(dx, dy, dz, nx, ny, nz, n_re[m_from + 1] / n_re[m_to + 1])
            if tir or (ndx * fx + ndy * fy + ndz * fz) * sgn <= 0.0:
                ok[i] = False  # total internal reflection, or refracted back through the facet
                break
        if differentials:
            grad = _ZERO_GRADIENT
            if event:
                grad = _smooth_normal_gradient(frame, face_normals, f, px, py, pz)
            _carry_differentials(dp, dd, t, dx, dy, dz, fx, fy, fz, nx, ny, nz, ndx, ndy, ndz, event, reflect,
                                 n_re[m_from + 1] / n_re[m_to + 1], grad)
        o[i, 0], o[i, 1], o[i, 2] = px, py, pz
        d[i, 0], d[i, 1], d[i, 2] = ndx, ndy, ndz
        med[i] = new_med
        push[i, 0], push[i, 1], push[i, 2] = pfac * fx * offset_m, pfac * fy * offset_m, pfac * fz * offset_m
        if event:
            k[i] += 1
        if not record:
            done[i] = k[i] >= nint[i]
        elif s <= steps.valid.shape[0]:  # record mode (a counting pass has no rows)
            r = s - 1
            steps.valid[r, i] = True
            steps.point[r, i, 0], steps.point[r, i, 1], steps.point[r, i, 2] = px, py, pz
            steps.face[r, i] = f
            steps.kind[r, i] = KIND_PASS if is_transparent else (KIND_REFLECTION if reflect else KIND_REFRACTION)
            steps.med_from[r, i] = m_from
            steps.med_to[r, i] = m_to
            steps.normal[r, i, 0], steps.normal[r, i, 1], steps.normal[r, i, 2] = nx, ny, nz
            steps.dir_in[r, i, 0], steps.dir_in[r, i, 1], steps.dir_in[r, i, 2] = dx, dy, dz
    return s


@helper
def _trial_launch(out, i, lam, bx, by, bz, s0, s1):
    """A line-search trial launch into ``out[i]``: ``normalize(b + lam (s0 u + s1 v))`` with
    ``u, v`` the :func:`_tangents` of ``b``."""
    bux, buy, buz, bvx, bvy, bvz = _tangents(bx, by, bz)
    a_, b_ = lam * s0, lam * s1
    lx, ly, lz = bx + a_ * bux + b_ * bvx, by + a_ * buy + b_ * bvy, bz + a_ * buz + b_ * bvz
    nrm = math.sqrt(lx * lx + ly * ly + lz * lz)
    out[i, 0], out[i, 1], out[i, 2] = lx / nrm, ly / nrm, lz / nrm


@helper
def _restart(i, sx, sy, sz, s_med, state, dp, dd):
    """Ray ``i`` of ``state`` back at its start point along ``state.d[i]``, with the launch
    differentials along the :func:`_tangents` of ``d[i]`` and none of the point."""
    o, push, d = state.o, state.push, state.d
    o[i, 0], o[i, 1], o[i, 2], state.med[i] = sx, sy, sz, s_med
    push[i, 0] = push[i, 1] = push[i, 2] = 0.0
    state.k[i] = 0
    state.ok[i] = True
    state.done[i] = state.nint[i] == 0
    ux, uy, uz, vx, vy, vz = _tangents(d[i, 0], d[i, 1], d[i, 2])
    dd[0, 0], dd[0, 1], dd[0, 2], dd[1, 0], dd[1, 1], dd[1, 2] = ux, uy, uz, vx, vy, vz
    for c in range(2):
        for q in range(3):
            dp[c, q] = 0.0


@helper
def _line_search(i, hit, scene, media, state, steps, max_steps, dp, dd, fractions, first, trial):
    """Newton's backtracking for ray ``i`` of ``state`` from the start of ``trial`` (a
    :class:`_Trial`): the trial launches (:func:`_trial_launch`) of ``fractions[first:]`` in
    turn, each traced with its differentials (:func:`_trace_ray`), until one's last leg passes
    the receiver closer than ``trial.old_miss`` (:func:`_miss`). Returns (that fraction's index
    or -1, rays cast, most steps of a trial); the ray's state and ``dp`` / ``dd`` are the last
    trial's trace."""
    o, d, ok, done = state.o, state.d, state.ok, state.done
    cast = 0
    most = 0
    for j in range(first, len(fractions)):
        _trial_launch(d, i, fractions[j], trial.bx, trial.by, trial.bz, trial.s0, trial.s1)
        _restart(i, trial.sx, trial.sy, trial.sz, trial.medium, state, dp, dd)
        s = _trace_ray(i, hit, scene, media, state, steps, max_steps, True, dp, dd)
        cast += s
        most = max(most, s)
        if ok[i] and done[i] and _miss(o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                       trial.rx, trial.ry, trial.rz) < trial.old_miss:
            return j, cast, most
    return -1, cast, most


@kernel
def follow(scene, media, state, steps, max_steps, differentials, search):
    """:func:`raytrace.solver.refine.follow`: every ray of ``state`` (a
    :class:`~raytrace.engine.records.TraceState`, updated in place) traced to its end in
    ``scene`` (:class:`~raytrace.engine.records.SceneTables`) through ``media``
    (:class:`~raytrace.engine.records.MediaTables`), at most ``max_steps`` casts per ray: per
    step, Embree's float32 first hit from the centred origin plus the spawn push (in record mode
    a ray past its last event is first aimed at its target), then the float64 hit point on the
    hit triangle's plane, side and media from the facet normal, the signature's expected event
    checked, then reflection (``d - 2 (d.n) n``) or refraction (vector Snell law with the real
    parts of the indices) about the smooth normal. A ray that leaves its signature is marked
    ``ok = False``. In record mode every step goes into ``steps``
    (:class:`~raytrace.engine.records.StepRecords`). Returns ``(segments, steps)``: rays cast,
    and the largest number of steps a ray took (the record rows used).

    Ray differentials (Igehy, "Tracing ray differentials", SIGGRAPH 1999), when
    ``differentials`` (:class:`~raytrace.engine.records.Differentials`) has a row per ray: the
    derivatives of the point and the direction with respect to two launch angles, whose
    direction derivatives are ``differentials.launch[i]``, carried through every step and left
    in ``differentials.point`` / ``.direction`` (of the last event point and direction).
    Transfer to the facet plane ``n.p = c``: ``dt = -n.(dP + t dD) / n.D``,
    ``dP' = dP + t dD + dt D``; reflection ``dD' = dD - 2 ((dD.N + D.dN) N + (D.N) dN)``;
    refraction (``T = eta D + (s cos_t - eta D.N) N``) ``dT = eta dD + (s dcos_t - eta
    d(D.N)) N + (s cos_t - eta D.N) dN`` with ``dcos_t = eta^2 (D.N) d(D.N) / cos_t``; ``dN``
    from :func:`_smooth_normal_gradient`.

    Line-search mode (``search``, a :class:`~raytrace.engine.records.LineSearch`, has
    fractions; one step of :func:`newton`'s backtracking, the same :func:`_line_search`): ray i
    is launched from its start along ``normalize(base_dir + f (step_0 u + step_1 v))`` (``u, v``
    the tangents of ``base_dir``) for each fraction f in turn from index ``won[i]`` on (in: where
    to start), with differentials along the trial's own tangents, until its last leg passes the
    receiver ``rx[i]`` closer than ``old_miss[i]``: ``won[i]`` is then that fraction's index (-1
    if none), ``trial_dir[i]`` its launch, and the ray's state its trace."""
    o, med, ok = state.o, state.med, state.ok
    fractions = search.fractions
    with_differentials = len(differentials.launch) > 0 or len(fractions) > 0
    line_search = len(fractions) > 0
    dp = np.zeros((2, 3))
    dd = np.zeros((2, 3))
    hit = embree.ray_hit()
    segments = 0
    most = 0
    for i in range(len(ok)):
        if line_search:
            first = search.won[i]
            base, step, rx = search.base_dir, search.step, search.rx
            trial = _Trial(o[i, 0], o[i, 1], o[i, 2], med[i], base[i, 0], base[i, 1], base[i, 2], step[i, 0],
                           step[i, 1], rx[i, 0], rx[i, 1], rx[i, 2], search.old_miss[i])
            search.won[i], cast, s = _line_search(i, hit, scene, media, state, steps, max_steps, dp, dd, fractions,
                                                  first, trial)
            last = search.won[i] if search.won[i] >= 0 else len(fractions) - 1  # the accepted, else the last, trial
            if first < len(fractions):
                _trial_launch(search.trial_dir, i, fractions[last], trial.bx, trial.by, trial.bz, trial.s0,
                              trial.s1)
        else:
            if with_differentials:
                for c in range(2):
                    for q in range(3):
                        dd[c, q] = differentials.launch[i, c, q]
                        dp[c, q] = 0.0
            cast = s = _trace_ray(i, hit, scene, media, state, steps, max_steps, with_differentials, dp, dd)
        segments += cast
        most = max(most, s)
        if with_differentials:
            for c in range(2):
                for q in range(3):
                    differentials.point[i, c, q] = dp[c, q]
                    differentials.direction[i, c, q] = dd[c, q]
    return segments, most


@kernel
def newton(scene, media, seeds, steps, max_steps, settings):
    """:func:`raytrace.solver.refine.refine`'s Newton iteration, one seed of ``seeds`` (a
    :class:`~raytrace.engine.records.NewtonSeeds`) at a time to its end, with ``settings``
    (:class:`~raytrace.engine.records.NewtonSettings`): trace the launch with its ray
    differentials (:func:`follow`); the residual is where the last leg crosses the plane through
    the receiver normal to it, in that plane's :func:`_tangents` basis, and the Jacobian the same
    offset's derivatives by the two launch angles (``x = L + tau D - rx``, ``tau = (rx - L).D``:
    ``dx = dL - (dL.D) D + tau dD``); converged when the miss is below ``tolerance_m``
    (``tube`` = ``|det J|``, the ray-tube area per steradian); otherwise the step ``-J^-1 r``,
    at most ``max_step_rad``, backtracked over ``fractions`` from ``growth`` halvings above the
    last accepted one (:func:`_line_search`). A seed fails when its trace leaves the signature,
    its Jacobian is singular, no trial reduces the miss, or the miss is not below
    ``stall_factor`` times its value ``stall_window`` iterations earlier. ``steps``: empty
    :class:`~raytrace.engine.records.StepRecords`. Returns the rays cast."""
    dirs, rx, converged, tube, tx = seeds.dirs, seeds.rx, seeds.converged, seeds.tube, seeds.tx
    fractions = settings.fractions
    p = len(dirs)
    state = TraceState(np.empty((p, 3)), np.empty((p, 3)), np.empty(p, np.int64), np.empty((p, 3)),
                       np.empty(p, np.int64), seeds.nint, np.empty(p, np.bool_), np.empty(p, np.bool_), seeds.codes,
                       np.empty((0, 3)), False)
    o, d, ok, done = state.o, state.d, state.ok, state.done
    dp = np.zeros((2, 3))
    dd = np.zeros((2, 3))
    history = np.empty(settings.max_iterations)
    jac = np.empty((2, 2))
    hit = embree.ray_hit()
    segments = 0
    for i in range(p):
        converged[i] = False
        tube[i] = np.nan
        d[i, 0], d[i, 1], d[i, 2] = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        _restart(i, tx[0], tx[1], tx[2], seeds.tx_medium, state, dp, dd)
        segments += _trace_ray(i, hit, scene, media, state, steps, max_steps, True, dp, dd)
        accepted = 0
        for it in range(settings.max_iterations):
            if not (ok[i] and done[i]):
                break  # the trace left its signature
            lx, ly, lz, dx, dy, dz = o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2]
            wx, wy, wz = rx[i, 0] - lx, rx[i, 1] - ly, rx[i, 2] - lz
            e1x, e1y, e1z, e2x, e2y, e2z = _tangents(dx, dy, dz)
            denom = dx * dx + dy * dy + dz * dz
            tau = (wx * dx + wy * dy + wz * dz) / denom
            xx, xy, xz = lx + tau * dx - rx[i, 0], ly + tau * dy - rx[i, 1], lz + tau * dz - rx[i, 2]
            r0 = xx * e1x + xy * e1y + xz * e1z
            r1 = xx * e2x + xy * e2y + xz * e2z
            if not (denom > 1e-6 and tau > 0.0 and math.isfinite(r0) and math.isfinite(r1)):
                break
            tau_j = wx * dx + wy * dy + wz * dz
            for c in range(2):
                dtau = -(dp[c, 0] * dx + dp[c, 1] * dy + dp[c, 2] * dz)
                qx = dp[c, 0] + dtau * dx + tau_j * dd[c, 0]
                qy = dp[c, 1] + dtau * dy + tau_j * dd[c, 1]
                qz = dp[c, 2] + dtau * dz + tau_j * dd[c, 2]
                jac[0, c] = qx * e1x + qy * e1y + qz * e1z
                jac[1, c] = qx * e2x + qy * e2y + qz * e2z
            det = jac[0, 0] * jac[1, 1] - jac[0, 1] * jac[1, 0]
            if not (math.isfinite(det) and abs(det) > 0.0):
                break
            miss = math.sqrt(r0 * r0 + r1 * r1)
            if miss < settings.tolerance_m:
                converged[i] = True
                tube[i] = abs(det)
                break
            history[it] = miss
            if it >= settings.stall_window and not miss < settings.stall_factor * history[it - settings.stall_window]:
                break
            i00, i01, i10, i11 = jac[1, 1] / det, -jac[0, 1] / det, -jac[1, 0] / det, jac[0, 0] / det
            s0 = -(i00 * r0 + i01 * r1)
            s1 = -(i10 * r0 + i11 * r1)
            norm = math.sqrt(s0 * s0 + s1 * s1)
            scale = min(1.0, settings.max_step_rad / max(norm, 1e-300))
            s0, s1 = s0 * scale, s1 * scale
            bx, by, bz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
            trial = _Trial(tx[0], tx[1], tx[2], seeds.tx_medium, bx, by, bz, s0, s1, rx[i, 0], rx[i, 1], rx[i, 2],
                           miss)
            won, cast, _steps = _line_search(i, hit, scene, media, state, steps, max_steps, dp, dd, fractions,
                                             max(accepted - settings.growth, 0), trial)
            segments += cast
            if won < 0:
                break
            _trial_launch(dirs, i, fractions[won], bx, by, bz, s0, s1)
            accepted = won
    return segments


@helper
def _tangents(dx, dy, dz):
    """:func:`raytrace.solver.refine.tangent_basis` of one unit direction: ``u = d x r / |d x r|``
    with ``r`` the x axis (the y axis when ``|d_x| >= 0.9``), ``v = d x u``."""
    rx, ry = (1.0, 0.0) if abs(dx) < 0.9 else (0.0, 1.0)
    ux, uy, uz = dy * 0.0 - dz * ry, dz * rx - dx * 0.0, dx * ry - dy * rx
    n = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / n, uy / n, uz / n
    return ux, uy, uz, dy * uz - dz * uy, dz * ux - dx * uz, dx * uy - dy * ux


@helper
def _miss(px, py, pz, dx, dy, dz, rx, ry, rz):
    """Distance from the receiver to a last leg (point, unit direction) if it lies ahead of it
    (the Newton residual's offset, in the plane normal to the leg), else inf."""
    wx, wy, wz = rx - px, ry - py, rz - pz
    tau = wx * dx + wy * dy + wz * dz
    if not tau > 0.0:
        return np.inf
    ex, ey, ez = wx - tau * dx, wy - tau * dy, wz - tau * dz
    return math.sqrt(ex * ex + ey * ey + ez * ez)


@helper
def _carry_differentials(dp, dd, t, dx, dy, dz, fx, fy, fz, nx, ny, nz, tx, ty, tz, event, reflect, eta, grad):
    """Carry both ray differentials (rows of ``dp``, ``dd``) across one step of :func:`follow`:
    transfer to the hit facet's plane, then the event's law about the smooth normal (formulas
    in :func:`follow`'s docstring); (tx, ty, tz) is the new direction, ``grad`` the
    :func:`_smooth_normal_gradient` at the hit."""
    gvx, gvy, gvz, gwx, gwy, gwz, ax, ay, az, bx, by, bz, inv_m = grad
    dn_f = fx * dx + fy * dy + fz * dz
    dns = dx * nx + dy * ny + dz * nz
    ct = 0.0
    if event and not reflect:
        ct = math.sqrt(max(1.0 - eta * eta * (1.0 - dns * dns), 1e-300))
    sg = -1.0 if dns < 0.0 else 1.0
    for c in range(2):
        qx, qy, qz = dp[c, 0] + t * dd[c, 0], dp[c, 1] + t * dd[c, 1], dp[c, 2] + t * dd[c, 2]
        dt = -(fx * qx + fy * qy + fz * qz) / dn_f
        ex, ey, ez = qx + dt * dx, qy + dt * dy, qz + dt * dz
        dp[c, 0], dp[c, 1], dp[c, 2] = ex, ey, ez
        if not event:
            continue  # a transparent surface: the direction is unchanged
        sv = gvx * ex + gvy * ey + gvz * ez
        sw = gwx * ex + gwy * ey + gwz * ez
        mx, my, mz = ax * sv + bx * sw, ay * sv + by * sw, az * sv + bz * sw
        proj = nx * mx + ny * my + nz * mz
        gx, gy, gz = (mx - nx * proj) * inv_m, (my - ny * proj) * inv_m, (mz - nz * proj) * inv_m
        ddx, ddy, ddz = dd[c, 0], dd[c, 1], dd[c, 2]
        d_dns = ddx * nx + ddy * ny + ddz * nz + dx * gx + dy * gy + dz * gz
        if reflect:
            dd[c, 0] = ddx - 2.0 * (d_dns * nx + dns * gx)
            dd[c, 1] = ddy - 2.0 * (d_dns * ny + dns * gy)
            dd[c, 2] = ddz - 2.0 * (d_dns * nz + dns * gz)
        else:
            d_ct = eta * eta * dns * d_dns / ct
            a = sg * ct - eta * dns
            da = sg * d_ct - eta * d_dns
            ux, uy, uz = eta * ddx + da * nx + a * gx, eta * ddy + da * ny + a * gy, eta * ddz + da * nz + a * gz
            proj = ux * tx + uy * ty + uz * tz  # zero in exact arithmetic: T stays a unit vector
            dd[c, 0], dd[c, 1], dd[c, 2] = ux - proj * tx, uy - proj * ty, uz - proj * tz


@kernel
def bounce(rays, scene, media, receivers, settings, walk, log_base):
    """One bounce of :func:`raytrace.solver.sbr.shoot` for a chunk of live ``rays``
    (:class:`~raytrace.engine.records.ShotRays`) cast into ``scene``
    (:class:`~raytrace.engine.records.ShotScene`) through ``media``
    (:class:`~raytrace.engine.records.ShotMedia`) towards ``receivers``
    (:class:`~raytrace.engine.records.ShotReceivers`) with the constants ``settings``
    (:class:`~raytrace.engine.records.ShotSettings`: ``threshold``, ``kmax``, ``offset_m``,
    ``reception_factor``, ``curvature_margin``, ``no_passes``, ``walk_events`` below); the
    event-log entries made are numbered from ``log_base`` on.

    Reception: a ray in the receiver's zone (``media.zone``: the region of one material it is
    in, :func:`raytrace.solver.sbr.zones`) whose segment passes the receiver
    within ``reception_factor * (rad + t_along * ang)`` (the ray tube's half-width) makes a
    candidate. Then each ray that hit a surface is absorbed along its segment
    (``exp(-2 alpha L)``) and splits, about the smooth normal, into a reflected ray
    (``d - 2 (d.n) n``) with the lossless Fresnel power reflectance of Re n (mean of TE and TM,
    Born & Wolf 1.5.3) and a transmitted one (vector Snell law) with the rest, unless Snell has
    no real solution (total internal reflection); a transparent surface passes the ray
    unchanged. Children below ``threshold`` or unable to reach a receiver's class within
    ``kmax`` events (``need``) are dropped, and so are those outside every receiver's zone that
    leave the scene's box or whose absorption over the least length they must still travel
    there (``return_m``) brings them below ``threshold`` (:func:`_may_return`). Tube angles grow
    as in :mod:`raytrace.solver.sbr`.

    A ray that already has ``kmax`` events can have no children (``no_passes``: the scene
    has no transparent surface to pass on through), so it is cast only if the receiver test
    could pass for some segment length, i.e. some receiver of its class lies within the tube
    half-width of its unbounded line; otherwise it is not cast at all (exact: the
    receptions are unchanged).

    The refraction-only walk (:func:`raytrace.solver.direct.refraction_walk`'s seed search) rides on
    the same rays when ``walk`` (:class:`~raytrace.engine.records.WalkRecords`: ``walk_miss``,
    ``walk_n``, ``walk_hist``) has a row per launch direction of the batch (row
    ``src - src_base``): ``mode`` 1 marks a ray with no reflection so far, 2 a ray that only the
    walk still follows. Every leg of a mode 1 or 2 ray in a receiver's zone
    updates that launch's closest approach to the receiver (``walk_miss``, the segment
    clamped to its hit, at most 1 km) with the events so far (``walk_n``) and the ray's last
    log entry (``walk_hist``), as the walk does; a mode 1 ray's transmitted child is mode 1,
    and where the shooting drops it (below ``threshold``, or ``kmax`` / ``need``) it carries on
    as mode 2: refracted only, unpruned, up to ``walk_events`` events, never received or
    split. Mode 0: not walked (or no walk).

    Returns the number of rays cast, the children (:class:`~raytrace.engine.records.ShotRays`:
    reflected, then transmitted, then passed, each in ray order, as the numpy reference did), the
    event-log entries of the reflected and transmitted children
    (:class:`~raytrace.engine.records.LogEntries`: parent entry, code, face), and the receptions
    (:class:`~raytrace.engine.records.Receptions`: receiver, log entry, events, launch index,
    miss over radius), receiver-major.
    """
    o, d, med, w, rad, ang, length = rays.o, rays.d, rays.med, rays.w, rays.rad, rays.ang, rays.length
    nint, hist, src, mode = rays.nint, rays.hist, rays.src, rays.mode
    handle, mask, base, face_normals32, face_organ = scene.handle, scene.mask, scene.base, scene.face_normals, \
        scene.face_organ
    corner32, curvature32, offset_m = scene.corner, scene.curvature, scene.offset_m
    parent, cls, transparent, n_re, alpha, need = media.parent, media.material_class, media.transparent, \
        media.n_real, media.alpha, media.need
    zone, rx_zone, return_m, bounds = media.zone, receivers.zone, media.return_m, media.bounds_m
    rx_m = receivers.position_m
    threshold, kmax, reception_factor = settings.threshold, settings.kmax, settings.reception_factor
    curvature_margin, no_passes, walk_events = settings.curvature_margin, settings.no_passes, settings.walk_events
    walk_miss, walk_n, walk_hist, src_base = walk.miss, walk.events, walk.hist, walk.src_base
    n = len(o)
    n_rx = len(rx_m)
    prim = np.empty(n, np.int64)
    tfar = np.empty(n, np.float32)
    bu = np.empty(n, np.float32)
    bv = np.empty(n, np.float32)
    hit = embree.ray_hit()
    cast = 0
    for i in range(n):
        if nint[i] >= kmax and no_passes and mode[i] == 0 and not _may_receive(rx_m, rx_zone, zone[med[i] + 1], o,
                                                                               d, i, rad, ang, reception_factor):
            prim[i], tfar[i] = -1, np.inf  # no children possible, and no receiver on its line: not cast
            continue
        prim[i], tfar[i], bu[i], bv[i] = embree.intersect(handle, mask, base, hit, o[i, 0], o[i, 1], o[i, 2],
                                                          d[i, 0], d[i, 1], d[i, 2])
        cast += 1
    # receptions: tested ray by ray (each ray's data once, the receivers stay in cache; with
    # many receivers the receiver-by-receiver loop streamed every ray array once per receiver),
    # into arrays grown by doubling, then put receiver-major (ray order within a receiver) by a
    # stable counting sort: the same receptions, in the same order, as testing receiver by receiver
    cap = 256
    h_rx = np.empty(cap, np.int64)
    h_ray = np.empty(cap, np.int64)
    h_close = np.empty(cap, np.float64)
    per_rx = np.zeros(n_rx + 1, np.int64)
    c = 0
    grid_lo, cell, dims = receivers.grid_lo_m, receivers.grid_cell_m, receivers.grid_dims
    cell_start, cell_items = receivers.cell_start, receivers.cell_items
    lo_c = np.zeros(3, np.int64)
    hi_c = np.zeros(3, np.int64)
    for i in range(n):
        if mode[i] == 2 or need[med[i] + 1] != 0:  # walk only, or no receiver in its zone
            continue
        ray_zone = zone[med[i] + 1]
        reach = tfar[i] if prim[i] >= 0 else np.inf
        # the cells of the segment's box widened by its largest tube half-width (+ a float32 margin)
        grid = n_rx > 4 and prim[i] >= 0
        if grid:
            widen = reception_factor * (np.float64(rad[i]) + np.float64(reach) * ang[i]) * 1.001 + 1e-4
            for a in range(3):
                end = np.float64(o[i, a]) + np.float64(reach) * d[i, a]
                lo_a = min(np.float64(o[i, a]), end) - widen
                hi_a = max(np.float64(o[i, a]), end) + widen
                lo_c[a] = min(max(int(math.floor((lo_a - grid_lo[a]) / cell)), 0), dims[a] - 1)
                hi_c[a] = min(max(int(math.floor((hi_a - grid_lo[a]) / cell)), 0), dims[a] - 1)
                if not math.isfinite(widen) or hi_a < grid_lo[a] or lo_a > grid_lo[a] + dims[a] * cell:
                    hi_c[a] = lo_c[a] - 1  # no cell (the box misses the grid), or a non-finite tube
            if not math.isfinite(widen):
                grid = False
        if grid:
            for ci in range(lo_c[0], hi_c[0] + 1):
                for cj in range(lo_c[1], hi_c[1] + 1):
                    for ck in range(lo_c[2], hi_c[2] + 1):
                        cc = (ci * dims[1] + cj) * dims[2] + ck
                        for q in range(cell_start[cc], cell_start[cc + 1]):
                            r = cell_items[q]
                            if rx_zone[r] != ray_zone:
                                continue
                            received, perp, radius = _tube_miss(rx_m, r, o, d, i, reach, rad, ang,
                                                                reception_factor)
                            if not received:
                                continue
                            if c == cap:
                                cap *= 2
                                h_rx, h_ray, h_close = _grow(h_rx, cap), _grow(h_ray, cap), _grow(h_close, cap)
                            h_rx[c], h_ray[c] = r, i
                            h_close[c] = perp / max(radius, 1e-30)
                            per_rx[r + 1] += 1
                            c += 1
            continue
        for r in range(n_rx):
            if rx_zone[r] != ray_zone:
                continue
            received, perp, radius = _tube_miss(rx_m, r, o, d, i, reach, rad, ang, reception_factor)
            if not received:
                continue
            if c == cap:
                cap *= 2
                h_rx, h_ray, h_close = _grow(h_rx, cap), _grow(h_ray, cap), _grow(h_close, cap)
            h_rx[c], h_ray[c] = r, i
            h_close[c] = perp / max(radius, 1e-30)
            per_rx[r + 1] += 1
            c += 1
    for r in range(n_rx):
        per_rx[r + 1] += per_rx[r]
    c_rx = np.empty(c, np.int64)
    c_hist = np.empty(c, np.int64)
    c_n = np.empty(c, np.int64)
    c_src = np.empty(c, np.int64)
    c_close = np.empty(c, np.float64)
    for k in range(c):
        r, i = h_rx[k], h_ray[k]
        at = per_rx[r]
        per_rx[r] += 1
        c_rx[at], c_hist[at], c_n[at], c_src[at], c_close[at] = r, hist[i], nint[i], src[i], h_close[k]
    walking = walk_miss.shape[0] > 0
    if walking:
        for i in range(n):
            if mode[i] == 0:
                continue
            ray_zone = zone[med[i] + 1]
            reach = min(np.float64(tfar[i]) if prim[i] >= 0 else np.inf, 1e3)
            row = src[i] - src_base
            for r in range(n_rx):
                if rx_zone[r] != ray_zone:
                    continue
                dist = _segment_miss(rx_m[r, 0] - o[i, 0], rx_m[r, 1] - o[i, 1], rx_m[r, 2] - o[i, 2],
                                     d[i, 0], d[i, 1], d[i, 2], reach)
                if dist < walk_miss[row, r]:
                    walk_miss[row, r] = dist
                    walk_n[row, r] = nint[i]
                    walk_hist[row, r] = hist[i]

    # interactions: per-ray outcome first (0/1 reflected, 0/1 transmitted, or passed)
    kind = np.zeros(n, np.int8)  # bit 1: reflected child, bit 2: transmitted child, bit 4: passed
    mode_t = np.zeros(n, np.int8)  # the transmitted child's mode
    pt = np.empty((n, 3), np.float32)
    dr = np.empty((n, 3), np.float32)
    dt = np.empty((n, 3), np.float32)
    push = np.empty((n, 3), np.float32)
    w_r = np.empty(n, np.float32)
    w_t = np.empty(n, np.float32)
    rad_k = np.empty(n, np.float32)
    ang_r = np.empty(n, np.float32)
    ang_t = np.empty(n, np.float32)
    len_k = np.empty(n, np.float32)
    m_from_k = np.empty(n, np.int64)
    m_to_k = np.empty(n, np.int64)
    code_k = np.empty(n, np.int32)
    face_k = np.empty(n, np.int32)
    n_r = n_t = n_p = 0
    for i in range(n):
        if prim[i] < 0:
            continue
        f = prim[i]
        t = tfar[i]
        m = med[i]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        wk = w[i] * math.exp(-2.0 * alpha[m + 1] * t)
        fx, fy, fz = face_normals32[f, 0], face_normals32[f, 1], face_normals32[f, 2]
        dn = dx * fx + dy * fy + dz * fz
        leaving, organ, m_from, m_to = _sides(face_organ, parent, f, dn)
        if cls[m_from + 1] != cls[m + 1]:
            continue
        nk = nint[i]
        shot = mode[i] < 2 and wk >= threshold  # the shooting goes on from here
        walked = walking and mode[i] >= 1 and nk < walk_events  # the walk goes on from here
        if not shot and not walked:
            continue
        sg = 1.0 if leaving else -1.0
        radk = rad[i] + t * ang[i]
        pt[i, 0], pt[i, 1], pt[i, 2] = o[i, 0] + t * dx, o[i, 1] + t * dy, o[i, 2] + t * dz
        push[i, 0], push[i, 1], push[i, 2] = sg * offset_m * fx, sg * offset_m * fy, sg * offset_m * fz
        rad_k[i] = radk
        len_k[i] = length[i] + t / n_re[m + 1]
        m_from_k[i] = m_from
        m_to_k[i] = m_to
        face_k[i] = f
        if transparent[f]:  # never with the walk (raytrace.solver.sbr: its scene has no transparent surface)
            if shot and nk + need[m_to + 1] <= kmax:
                kind[i] = 4
                w_t[i] = wk
                n_p += 1
            continue
        shot = shot and nk < kmax
        if not shot and not walked:
            continue
        # smooth normal from Embree's barycentrics, the facet's if it flips
        nx, ny, nz = _smooth_normal_uv(corner32, face_normals32, f, bu[i], bv[i])
        n1, n2 = n_re[m_from + 1], n_re[m_to + 1]
        eta = n1 / n2
        dns = dx * nx + dy * ny + dz * nz
        tir, tx, ty, tz, ci, ct = _refract(dx, dy, dz, nx, ny, nz, eta)
        if tir:
            refl_p = 1.0
        else:
            n1c, n2c, n1t, n2i = n1 * ci, n2 * ct, n1 * ct, n2 * ci
            r_te = (n1c - n2c) / max(n1c + n2c, 1e-30)
            r_tm = (n2i - n1t) / max(n2i + n1t, 1e-30)
            refl_p = min(max(0.5 * (r_te * r_te + r_tm * r_tm), 0.0), 1.0)
        rx_, ry_, rz_ = dx - 2.0 * dns * nx, dy - 2.0 * dns * ny, dz - 2.0 * dns * nz
        wr = wk * refl_p
        wt = wk - wr
        bend = curvature_margin * curvature32[f] * radk
        code_k[i] = (organ * 2 + (1 if leaving else 0)) * 2
        side = 0 if leaving else 1  # the reflected child's side of the face (0: inside its organ)
        if (shot and (rx_ * fx + ry_ * fy + rz_ * fz) * sg < 0.0 and wr >= threshold
                and nk + 1 + need[m_from + 1] <= kmax
                and (need[m_from + 1] == 0 or _may_return(
                    wr, alpha[m_from + 1], return_m[f, side], threshold, pt[i, 0] - push[i, 0],
                    pt[i, 1] - push[i, 1], pt[i, 2] - push[i, 2], rx_, ry_, rz_, bounds))):
            kind[i] |= 1
            dr[i, 0], dr[i, 1], dr[i, 2] = rx_, ry_, rz_
            w_r[i] = wr
            ang_r[i] = ang[i] + 2.0 * bend
            n_r += 1
        through = not tir and (tx * fx + ty * fy + tz * fz) * sg > 0.0
        if (shot and through and wt >= threshold and nk + 1 + need[m_to + 1] <= kmax
                and (need[m_to + 1] == 0 or _may_return(
                    wt, alpha[m_to + 1], return_m[f, 1 - side], threshold, pt[i, 0] + push[i, 0],
                    pt[i, 1] + push[i, 1], pt[i, 2] + push[i, 2], tx, ty, tz, bounds))):
            mode_t[i] = mode[i]
        elif walked and through and (need[m_to + 1] == 0 or _may_return(
                1.0, 0.0, 0.0, 0.0, pt[i, 0] + push[i, 0], pt[i, 1] + push[i, 1], pt[i, 2] + push[i, 2], tx, ty, tz,
                bounds)):  # the walk alone goes on, unless it leaves the box outside every receiver's zone
            mode_t[i] = 2
        else:
            through = False
        if through:
            kind[i] |= 2
            dt[i, 0], dt[i, 1], dt[i, 2] = tx, ty, tz
            w_t[i] = wt
            mag = min(max(max(n1 * ci / max(n2 * ct, 1e-3), eta), 1.0), 50.0)
            ang_t[i] = ang[i] * mag + bend * abs(1.0 - eta)
            n_t += 1

    total = n_r + n_t + n_p
    c_o = np.empty((total, 3), np.float32)
    c_d = np.empty((total, 3), np.float32)
    c_med = np.empty(total, np.int64)
    c_w = np.empty(total, np.float32)
    c_rad = np.empty(total, np.float32)
    c_ang = np.empty(total, np.float32)
    c_len = np.empty(total, np.float32)
    c_nint = np.empty(total, np.int64)
    c_hist_next = np.empty(total, np.int64)
    c_src_next = np.empty(total, np.int64)
    c_mode = np.empty(total, np.int8)
    log_parent = np.empty(n_r + n_t, np.int32)
    log_code = np.empty(n_r + n_t, np.int32)
    log_face = np.empty(n_r + n_t, np.int32)
    a = 0
    for block in range(3):
        bit = 1 << block
        for i in range(n):
            if not kind[i] & bit:
                continue
            if block == 0:  # reflected: back to the side it came from
                for q in range(3):
                    c_o[a, q] = pt[i, q] - push[i, q]
                    c_d[a, q] = dr[i, q]
                c_med[a], c_w[a], c_ang[a] = m_from_k[i], w_r[i], ang_r[i]
                c_mode[a] = 0
            else:  # transmitted / passed: on through the surface
                for q in range(3):
                    c_o[a, q] = pt[i, q] + push[i, q]
                    c_d[a, q] = dt[i, q] if block == 1 else d[i, q]
                c_med[a], c_w[a] = m_to_k[i], w_t[i]
                c_ang[a] = ang_t[i] if block == 1 else ang[i]
                c_mode[a] = mode_t[i] if block == 1 else mode[i]
            c_rad[a], c_len[a], c_src_next[a] = rad_k[i], len_k[i], src[i]
            if block < 2:
                log_parent[a] = hist[i]
                log_code[a] = code_k[i] + (1 if block == 0 else 0)
                log_face[a] = face_k[i]
                c_nint[a] = nint[i] + 1
                c_hist_next[a] = log_base + a
            else:
                c_nint[a] = nint[i]
                c_hist_next[a] = hist[i]
            a += 1
    return (cast, ShotRays(c_o, c_d, c_med, c_w, c_rad, c_ang, c_len, c_nint, c_hist_next, c_src_next, c_mode),
            LogEntries(log_parent, log_code, log_face), Receptions(c_rx, c_hist, c_n, c_src, c_close))


@kernel
def walk_step(rays, hits, targets, out, scene, media, exact, max_events):
    """One event of :func:`raytrace.solver.direct.refraction_walk` for every live ray of
    ``rays`` (:class:`~raytrace.engine.records.WalkRays`, row r is walked ray ``ids[r]``), from
    Embree's ``hits`` (:class:`~raytrace.engine.records.Hits`) of their query, towards
    ``targets`` (:class:`~raytrace.engine.records.WalkTargets`), recording into ``out``
    (:class:`~raytrace.engine.records.WalkOutput`, per walked ray: ``miss``, ``nmiss``,
    ``codes``), in ``scene`` (:class:`~raytrace.engine.records.SceneTables`) through ``media``
    (:class:`~raytrace.engine.records.MediaTables`).

    Each leg in a receiver's material class updates the ray's closest approach to that
    receiver (``ray_rx[i] >= 0``: only to its own receiver, column 0; else to every receiver,
    one column each). Then the ray refracts (vector Snell law with Re n about the smooth
    normal, Born & Wolf 1.5) and its event is appended to its signature; it stops at total
    internal reflection, at a surface it is not in front of, or after ``max_events``.
    ``exact``: float64 re-intersection and float64 smooth normal (else Embree's float32
    distance, from the query origin ``q`` (centred, pushed off the surface), and barycentric
    normal, ~1e-8 m, enough for seeds). Returns the surviving rays, compacted, with their next
    float32 Embree query (centred origin + spawn push): a :class:`~raytrace.engine.records.WalkRays`."""
    ids, o, d, med, nint, q = rays.ids, rays.o, rays.d, rays.med, rays.nint, rays.q
    prim, tfar, bu, bv = hits.prim, hits.tfar, hits.u, hits.v
    rx_m, rx_cls, ray_rx = targets.position_m, targets.material_class, targets.ray_rx
    miss, nmiss, codes = out.miss, out.nmiss, out.codes
    face_normals, plane_d, frame = scene.face_normals, scene.plane_d, scene.frame
    face_organ, offset_m, center = scene.face_organ, scene.offset_m, scene.center
    parent, cls, n_re = media.parent, media.material_class, media.n_real
    n = len(ids)
    n_rx = len(rx_m)
    own = len(ray_rx) > 0
    keep = np.zeros(n, np.bool_)
    new_o = np.empty((n, 3))
    new_d = np.empty((n, 3))
    new_med = np.empty(n, np.int64)
    new_push = np.empty((n, 3))
    survivors = 0
    for r in range(n):
        i = ids[r]
        dx, dy, dz = d[r, 0], d[r, 1], d[r, 2]
        ox, oy, oz = o[r, 0], o[r, 1], o[r, 2]
        if not exact:  # Embree's distance is from the query's origin, pushed off the surface
            ox, oy, oz = q[r, 0] + center[0], q[r, 1] + center[1], q[r, 2] + center[2]
        f = np.int64(prim[r])
        t = np.inf
        fx = fy = fz = 0.0
        if f >= 0:
            fx, fy, fz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
            if exact:
                t = _plane_distance(face_normals, plane_d, f, ox, oy, oz, dx, dy, dz, tfar[r])
            else:
                t = np.float64(tfar[r])
        reach = min(t, 1e3)
        ray_cls = cls[med[r] + 1]
        for c in range(1 if own else n_rx):
            target = ray_rx[i] if own else c
            if rx_cls[target] != ray_cls:
                continue
            dist = _segment_miss(rx_m[target, 0] - ox, rx_m[target, 1] - oy, rx_m[target, 2] - oz, dx, dy, dz, reach)
            if dist < miss[i, c]:
                miss[i, c] = dist
                nmiss[i, c] = nint[r]
        if f < 0 or nint[r] >= max_events:
            continue
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        leaving, organ, m_from, m_to = _sides(face_organ, parent, f, fx * dx + fy * dy + fz * dz)
        if cls[m_from + 1] != ray_cls:
            continue
        if exact:
            nx, ny, nz = _smooth_normal(frame, face_normals, f, px, py, pz)
        else:
            nx, ny, nz = _smooth_normal_uv64(frame, face_normals, f, bu[r], bv[r])
        tir, tx, ty, tz, _ci, _ct = _refract(dx, dy, dz, nx, ny, nz, n_re[m_from + 1] / n_re[m_to + 1])
        sg = 1.0 if leaving else -1.0
        if tir or (tx * fx + ty * fy + tz * fz) * sg <= 0.0:
            continue  # total internal reflection ends a refraction-only walk
        codes[i, nint[r]] = (organ * 2 + (1 if leaving else 0)) * 2
        keep[r] = True
        new_o[r, 0], new_o[r, 1], new_o[r, 2] = px, py, pz
        new_d[r, 0], new_d[r, 1], new_d[r, 2] = tx, ty, tz
        new_med[r] = m_to
        new_push[r, 0], new_push[r, 1], new_push[r, 2] = sg * fx * offset_m, sg * fy * offset_m, sg * fz * offset_m
        survivors += 1
    out_ids = np.empty(survivors, np.int64)
    out_o = np.empty((survivors, 3))
    out_d = np.empty((survivors, 3))
    out_med = np.empty(survivors, np.int64)
    out_n = np.empty(survivors, np.int64)
    out_q = np.empty((survivors, 3), np.float32)
    out_dq = np.empty((survivors, 3), np.float32)
    a = 0
    for r in range(n):
        if not keep[r]:
            continue
        out_ids[a], out_med[a], out_n[a] = ids[r], new_med[r], nint[r] + 1
        for c in range(3):
            out_o[a, c] = new_o[r, c]
            out_d[a, c] = new_d[r, c]
            out_q[a, c] = new_o[r, c] - center[c] + new_push[r, c]
            out_dq[a, c] = new_d[r, c]
        a += 1
    return WalkRays(out_ids, out_o, out_d, out_med, out_n, out_q, out_dq)


@kernel
def spread_picks(order, starts, dirs, min_cos, per_group):
    """Greedy thinning of candidate launches: group g is ``order[starts[g]:starts[g + 1]]``,
    best first; a candidate is kept if the cosine between its launch direction and every
    direction kept in its group so far is below ``min_cos``, up to ``per_group`` per group.
    Returns the keep mask over candidates (:func:`raytrace.solver.tracer._select_seeds`)."""
    keep = np.zeros(len(dirs), np.bool_)
    kept = np.empty(max(per_group, 1), np.int64)
    for g in range(len(starts) - 1):
        nk = 0
        for j in range(starts[g], starts[g + 1]):
            if nk == per_group:
                break
            idx = order[j]
            spread = True
            for q in range(nk):
                other = kept[q]
                cos = dirs[idx, 0] * dirs[other, 0] + dirs[idx, 1] * dirs[other, 1] + dirs[idx, 2] * dirs[other, 2]
                if cos >= min_cos:
                    spread = False
                    break
            if spread:
                kept[nk] = idx
                nk += 1
                keep[idx] = True
    return keep


@kernel
def first_of_duplicates(group, dirs, max_angle):
    """Mask of the rows kept, in order: a row is dropped when a row kept before it in the
    same ``group`` has a launch direction within ``max_angle`` (Euclidean distance of the
    unit vectors) of its own. :func:`raytrace.solver.tracer._unique_paths`'s greedy pass; each
    group's kept rows are a linked list."""
    n = len(group)
    out = np.zeros(n, np.bool_)
    head = np.full(int(group.max()) + 1 if n else 0, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    for row in range(n):
        g = group[row]
        k = head[g]
        same = False
        while k >= 0:
            ex, ey, ez = dirs[k, 0] - dirs[row, 0], dirs[k, 1] - dirs[row, 1], dirs[k, 2] - dirs[row, 2]
            if math.sqrt(ex * ex + ey * ey + ez * ez) <= max_angle:
                same = True
                break
            k = nxt[k]
        if not same:
            out[row] = True
            nxt[row] = head[g]
            head[g] = row
    return out



@helper
def _root(parent, a):
    """The root of ``a`` in the union-find forest ``parent``, halving the path on the way."""
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@kernel
def link_components(pts, cells, link):
    """Connected components of the graph linking two rows of ``pts`` (n, 3) whose Euclidean
    distance is at most ``link`` (single linkage), without listing the pairs: ``cells`` (n, 3)
    are the rows' integer cubic cells of edge just under ``link / sqrt(3)``
    (:func:`raytrace.solver.tracer._clusters`), so two rows of one cell are always within
    ``link`` (a cell is one component at once) and two rows within ``link`` lie at most two
    cells apart on each axis; two such cells are joined by the first pair of their rows found
    within ``link`` (squared distances, as a k-d tree's pair query compares them). Returns the
    label of each row: components numbered in order of their smallest row (as
    :func:`scipy.sparse.csgraph.connected_components` numbers them)."""
    n = pts.shape[0]
    labels = np.empty(n, np.int64)
    if n == 0:
        return labels
    lo_y, lo_z = cells[:, 1].min(), cells[:, 2].min()
    ny = cells[:, 1].max() - lo_y + 5
    nz = cells[:, 2].max() - lo_z + 5
    lo_x = cells[:, 0].min()
    key = np.empty(n, np.int64)
    for i in range(n):
        key[i] = ((cells[i, 0] - lo_x + 2) * ny + (cells[i, 1] - lo_y + 2)) * nz + (cells[i, 2] - lo_z + 2)
    order = np.argsort(key, kind="mergesort")
    parent = np.arange(n)
    keys = np.empty(n, np.int64)
    starts = np.empty(n + 1, np.int64)
    m = 0
    for j in range(n):
        k = key[order[j]]
        if m > 0 and k == keys[m - 1]:
            a, b = _root(parent, order[j]), _root(parent, order[starts[m - 1]])
            if a != b:
                parent[max(a, b)] = min(a, b)
        else:
            keys[m] = k
            starts[m] = j
            m += 1
    starts[m] = n
    link2 = link * link
    # the key offsets of the cells up to two apart on each axis with a higher key (each pair of
    # cells once), each with a cursor through the sorted keys (a merge: no search per cell)
    offsets = np.empty(62, np.int64)
    o = 0
    for dx in range(0, 3):
        for dy in range(-2, 3):
            for dz in range(-2, 3):
                if dx == 0 and (dy < 0 or (dy == 0 and dz <= 0)):
                    continue
                offsets[o] = (dx * ny + dy) * nz + dz
                o += 1
    cursor = np.zeros(62, np.int64)
    for c in range(m):
        for o in range(62):
            want = keys[c] + offsets[o]
            e = cursor[o]
            while e < m and keys[e] < want:
                e += 1
            cursor[o] = e
            if e >= m or keys[e] != want:
                continue
            if _root(parent, order[starts[c]]) == _root(parent, order[starts[e]]):
                continue
            joined = False
            for p in range(starts[c], starts[c + 1]):
                i = order[p]
                for q in range(starts[e], starts[e + 1]):
                    j = order[q]
                    ex, ey, ez = pts[i, 0] - pts[j, 0], pts[i, 1] - pts[j, 1], pts[i, 2] - pts[j, 2]
                    if ex * ex + ey * ey + ez * ez <= link2:
                        a, b = _root(parent, i), _root(parent, j)
                        parent[max(a, b)] = min(a, b)
                        joined = True
                        break
                if joined:
                    break
    # number the components by their smallest row: every root is its component's smallest row
    # (unions keep the smaller root), so a row that is its own root opens a new label
    count = 0
    for i in range(n):
        r = _root(parent, i)
        if r == i:
            labels[i] = count
            count += 1
        else:
            labels[i] = labels[r]
    return labels
