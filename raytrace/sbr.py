"""Shooting and bouncing rays: candidate interaction signatures for every receiver.

One launch (a Fibonacci sphere of directions at the transmitter) serves all
receivers; it is processed in batches of :data:`LAUNCH_BATCH` directions,
each batch's whole bounce tree at once, so memory stays bounded without
culling branches. Per bounce, every live ray of the batch is cast together
(Embree batches of :data:`CHUNK_RAYS`); at each hit it splits into a
reflected ray and, unless Snell has no real solution (total internal
reflection), a transmitted ray, up to ``max_interactions`` events. The scene
given holds only the surfaces between different materials (see
:func:`raytrace.scene.scene_for`), so media are compared by material class.
A ray's power factor (lossless Fresnel power reflectance / transmittance
from Re n, mean of TE and TM, times the true absorption ``exp(-2 alpha L)``)
prunes it once below the dynamic range; a safety cap on live rays keeps the
highest power / reduced-length^2 (deterministic partition). Shooting runs in
float32 (it only produces seeds; refinement is float64).

Reception: a segment passing within the reception radius of a receiver in
a medium of the same material makes a candidate. The radius is the ray tube's half-width,
grown along the unfolded path as ``angle * length`` with ``angle`` the launch
spacing sqrt(4 pi / N), multiplied at each refraction by the tube's angular
magnification ``max(n1 cos_i / (n2 cos_t), n1 / n2, 1)``, and widened at every
curved surface by what a thin mirror / lens of the surface's curvature ``k``
does to the tube's edge ray at half-width ``h``: ``2 k h`` on reflection,
``k h |1 - n1 / n2|`` on refraction (times :data:`CURVATURE_MARGIN`; ``k``
from :attr:`raytrace.scene.TracerScene.face_curvature32`). Without that term
curved organs (colon, kidneys, spine, the skin's own curvature) spread the rays
of a reflected tube far beyond its modelled width, and receivers between them
got no candidate: on the default torso at 1e5 rays, 6 of 36 capsule x sensor
pairs lacked their strongest path. Candidates are only seeds:
:func:`raytrace.refine.refine` makes every kept path exact.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from raytrace.budget import Budget
from raytrace.launch import angular_spacing_rad, fibonacci_sphere
from raytrace.media import MediaTable
from raytrace.refine import encode, snell_refract
from raytrace.scene import TracerScene

#: Launch directions traced together (their whole bounce tree at once).
LAUNCH_BATCH = 50_000
#: Safety cap on the live rays of one launch batch (highest priority kept).
MAX_LIVE_RAYS = 2_000_000
#: Launch batches shot concurrently (threads; Embree releases the GIL). Peak memory grows
#: with it: each batch holds its own bounce tree.
SHOOT_THREADS = min(2, os.cpu_count() or 1)
#: Reception radius in units of the local ray-tube half-width.
RECEPTION_FACTOR = 1.0
#: Safety factor on the curvature widening of the tubes (module doc). Measured on the default
#: torso (3 capsules x 12 sensors, 1e5 rays; reference: the union of 1e6-ray traces): paths
#: within 20 dB of a receiver's strongest that were missed, of 267: 84 without the term, 42
#: with margin 1, 25 with margin 2; receivers missing their strongest path: 6, 1, 0 of 36.
#: Request time grows with the candidates (about +50 % at margin 2).
CURVATURE_MARGIN = 2.0


@dataclass
class Candidates:
    receiver: np.ndarray  # (C,) receiver index
    codes: np.ndarray  # (C, K) signature, -1 padded
    faces: np.ndarray  # (C, K) faces of the events, -1 padded
    nint: np.ndarray  # (C,)
    launch_dir: np.ndarray  # (C, 3)
    closeness: np.ndarray  # (C,) miss distance / reception radius
    rays_launched: int
    segments: int


#: Rays processed per Embree batch inside one bounce (bounds the temporaries' memory).
CHUNK_RAYS = 1 << 18


@dataclass
class _Context:
    scene: TracerScene
    n_re: np.ndarray
    alpha: np.ndarray
    parent: np.ndarray
    transparent: np.ndarray
    threshold: float
    kmax: int
    rx_m: np.ndarray
    rx_medium: np.ndarray
    cls: np.ndarray  # material class per medium (index m + 1)
    need: np.ndarray  # fewest further interactions to reach a receiver's class, per medium (m + 1)


@dataclass
class _State:
    """Live rays: origin (already pushed off the surface), direction, medium, power factor,
    tube radius and angle, reduced length sum L_i / Re n_i, events so far, event-log pointer,
    launch index."""

    o: np.ndarray
    d: np.ndarray
    med: np.ndarray
    w: np.ndarray
    rad: np.ndarray
    ang: np.ndarray
    length: np.ndarray
    nint: np.ndarray
    hist: np.ndarray
    src: np.ndarray

    def take(self, index) -> "_State":
        return _State(*(getattr(self, f)[index] for f in _STATE_FIELDS))

    @staticmethod
    def concat(parts: list["_State"]) -> "_State | None":
        if not parts:
            return None
        if len(parts) == 1:
            return parts[0]
        return _State(*(np.concatenate([getattr(p, f) for p in parts]) for f in _STATE_FIELDS))


_STATE_FIELDS = ("o", "d", "med", "w", "rad", "ang", "length", "nint", "hist", "src")


@dataclass
class _Log:
    """Event log: one entry per (interacting ray, kind); rays point at their last entry."""

    parent: list = field(default_factory=list)
    code: list = field(default_factory=list)
    face: list = field(default_factory=list)
    size: int = 0


@dataclass
class _Found:
    rx: list = field(default_factory=list)
    hist: list = field(default_factory=list)
    n: list = field(default_factory=list)
    src: list = field(default_factory=list)
    close: list = field(default_factory=list)
    codes: list = field(default_factory=list)  # resolved per launch batch
    faces: list = field(default_factory=list)


def _bounce(ctx: _Context, s: _State, log: _Log, found: _Found) -> "_State | None":
    """Cast one chunk of live rays, record receptions, and spawn the next generation."""
    scene = ctx.scene
    off = scene.offset_m
    n_re = ctx.n_re
    threshold = ctx.threshold
    o, d, med = s.o, s.d, s.med
    face, t, uv = scene.first_hit32(o, d)
    # reception (rays in the receiver's medium class only; one mask per class)
    ray_cls = ctx.cls[med + 1]
    rx_cls = ctx.cls[ctx.rx_medium + 1]
    for c in np.unique(rx_cls):
        i_c = np.flatnonzero(ray_cls == c)
        if len(i_c) == 0:
            continue
        o_c, d_c, t_c = o[i_c], d[i_c], t[i_c]
        for r in np.flatnonzero(rx_cls == c):
            vec = ctx.rx_m[r] - o_c
            tt = np.einsum("ij,ij->i", vec, d_c)
            sel = np.flatnonzero((tt > 0.0) & (tt < t_c))
            if len(sel) == 0:
                continue
            i, vec, tt = i_c[sel], vec[sel], tt[sel]
            perp = np.linalg.norm(vec - tt[:, None] * d_c[sel], axis=1)
            radius = RECEPTION_FACTOR * (s.rad[i] + tt * s.ang[i])
            got = perp <= radius
            if got.any():
                i = i[got]
                found.rx.append(np.full(len(i), r))
                found.hist.append(s.hist[i])
                found.n.append(s.nint[i])
                found.src.append(s.src[i])
                found.close.append(perp[got] / np.maximum(radius[got], 1e-30))
    keep = np.flatnonzero(face >= 0)
    if len(keep) == 0:
        return None
    if len(keep) == len(face):
        keep = slice(None)  # every ray hit: views instead of gathers
    f = face[keep]
    tk = t[keep]
    dk, mk = d[keep], med[keep]
    pt = o[keep] + tk[:, None] * dk
    wk = s.w[keep] * np.exp(-2.0 * ctx.alpha[mk + 1] * tk)
    radk = s.rad[keep] + tk * s.ang[keep]
    lengthk = s.length[keep] + tk / n_re[mk + 1]  # reduced length sum L_i / Re n_i
    fn = scene.face_normals32[f]
    dn = np.einsum("ij,ij->i", dk, fn)
    leaving = dn > 0.0
    organ = scene.face_organ[f]
    parent = ctx.parent[organ]
    m_from = np.where(leaving, organ, parent)
    m_to = np.where(leaving, parent, organ)
    sg = np.where(leaving, np.float32(1.0), np.float32(-1.0))
    valid = (ctx.cls[m_from + 1] == ctx.cls[mk + 1]) & (wk >= threshold)
    transparent = ctx.transparent[f]

    nk, angk = s.nint[keep], s.ang[keep]
    ev = valid & ~transparent & (nk < ctx.kmax)
    p_mask = valid & transparent
    # interaction physics over every hit at once (masks, no per-kind gathers)
    ns = scene.smooth_normals_uv(f, uv[keep])
    flip = np.einsum("ij,ij->i", ns, fn) <= 0.0
    ns[flip] = fn[flip]
    n1, n2 = n_re[m_from + 1], n_re[m_to + 1]
    dns = np.einsum("ij,ij->i", dk, ns)
    dt, tir, ci, ct = snell_refract(dk, ns, dns, n1 / n2)
    # pruning weight only: lossless Fresnel power reflectance from Re n (mean of TE, TM)
    n1c, n2c, n1t, n2i = n1 * ci, n2 * ct, n1 * ct, n2 * ci
    r_te = (n1c - n2c) / np.maximum(n1c + n2c, 1e-30)
    r_tm = (n2i - n1t) / np.maximum(n2i + n1t, 1e-30)
    refl_p = np.where(tir, 1.0, np.clip(0.5 * (r_te * r_te + r_tm * r_tm), 0.0, 1.0))
    dr = dk - (2.0 * dns)[:, None] * ns
    wr = wk * refl_p
    wt = wk - wr
    r_mask = ev & (np.einsum("ij,ij->i", dr, fn) * sg < 0.0) & (wr >= threshold)
    t_mask = ev & ~tir & (wt >= threshold) & (np.einsum("ij,ij->i", dt, fn) * sg > 0.0)
    # a child that cannot reach a receiver's material class within max_interactions is dropped
    # (it could never be received: see _interactions_needed)
    r_mask &= nk + (1 + ctx.need[m_from + 1]) <= ctx.kmax
    t_mask &= nk + (1 + ctx.need[m_to + 1]) <= ctx.kmax
    p_mask &= nk + ctx.need[m_to + 1] <= ctx.kmax
    mag = np.minimum(np.maximum(np.maximum(n1 * ci / np.maximum(n2 * ct, 1e-3), n1 / n2), 1.0), 50.0)
    # curved surfaces turn the tube's edge rays: by 2 k h on reflection, k h |1 - n1/n2| on refraction
    bend = np.float32(CURVATURE_MARGIN) * scene.face_curvature32[f] * radk
    # event log: one int32 entry per spawned reflected / transmitted ray
    base = log.size
    r_idx, t_idx = np.flatnonzero(r_mask), np.flatnonzero(t_mask)
    hk = s.hist[keep]
    if len(r_idx) or len(t_idx):
        log.parent.append(np.concatenate([hk[r_idx], hk[t_idx]]).astype(np.int32))
        log.code.append(np.concatenate([encode(organ[r_idx], leaving[r_idx], 1),
                                        encode(organ[t_idx], leaving[t_idx], 0)]).astype(np.int32))
        log.face.append(np.concatenate([f[r_idx], f[t_idx]]).astype(np.int32))
        log.size += len(r_idx) + len(t_idx)
    n_r, n_t, n_p = int(r_mask.sum()), int(t_mask.sum()), int(p_mask.sum())
    total = n_r + n_t + n_p
    if total == 0:
        return None
    a, b = n_r, n_r + n_t
    push = (sg * np.float32(off))[:, None] * fn
    o = np.empty((total, 3), np.float32)
    np.compress(r_mask, pt - push, axis=0, out=o[:a])
    o_tp = pt + push
    np.compress(t_mask, o_tp, axis=0, out=o[a:b])
    np.compress(p_mask, o_tp, axis=0, out=o[b:])
    d = np.empty((total, 3), np.float32)
    np.compress(r_mask, dr, axis=0, out=d[:a])
    np.compress(t_mask, dt, axis=0, out=d[a:b])
    np.compress(p_mask, dk, axis=0, out=d[b:])
    med = np.concatenate([m_from[r_mask], m_to[t_mask], m_to[p_mask]])
    w = np.concatenate([wr[r_mask], wt[t_mask], wk[p_mask]])
    rad = np.concatenate([radk[r_mask], radk[t_mask], radk[p_mask]])
    ang = np.concatenate([(angk + 2.0 * bend)[r_mask], (angk * mag + bend * np.abs(1.0 - n1 / n2))[t_mask],
                          angk[p_mask]])
    nint = np.concatenate([nk[r_mask] + 1, nk[t_mask] + 1, nk[p_mask]])
    hist = np.concatenate([base + np.arange(len(r_idx) + len(t_idx)), hk[p_mask]])
    src = s.src[keep]
    src = np.concatenate([src[r_mask], src[t_mask], src[p_mask]])
    length = np.concatenate([lengthk[r_mask], lengthk[t_mask], lengthk[p_mask]])
    return _State(o=o, d=d, med=med, w=w, rad=rad, ang=ang, length=length, nint=nint, hist=hist, src=src)


def shoot(
    scene: TracerScene,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    rx_m: np.ndarray,
    rx_medium: np.ndarray,
    rays: int,
    max_interactions: int,
    dynamic_range_db: float,
    budget: Budget | None = None,
) -> Candidates:
    """Launch ``rays`` directions, bounce them, return reception candidates (vectorised per bounce).

    Per ray the state is position, direction, medium, power factor, tube
    radius/angle, event count, launch index and a pointer into an event log
    (parent event, code, face) from which candidate signatures are rebuilt;
    the spawned origin is offset off the surface just left (float32 safety).
    """
    kmax = int(max_interactions)
    width = max(kmax, 1)
    launch = fibonacci_sphere(rays)
    ctx = _Context(
        scene=scene,
        n_re=media.n_real.astype(np.float32),
        alpha=((2.0 * np.pi * media.frequencies_hz[0] / 299_792_458.0) * -media.n[0].imag).astype(np.float32),
        parent=media.parent,
        transparent=media.face_transparent,
        threshold=10.0 ** (-dynamic_range_db / 10.0),
        kmax=kmax,
        rx_m=(np.asarray(rx_m, float) - scene.center).astype(np.float32),
        rx_medium=np.asarray(rx_medium),
        cls=media.material_class,
        need=_interactions_needed(media, rx_medium),
    )
    max_steps = 4 * kmax + 2 * len(media.materials) + 8
    spacing = angular_spacing_rad(rays)
    tx_c = (np.asarray(tx_m, float) - scene.center).astype(np.float32)

    def launch_batch(first: int) -> tuple[_Found, int]:
        # the whole bounce tree of one batch of launch directions: bounds memory without
        # culling branches; batches are independent (own event log and candidates)
        count = min(LAUNCH_BATCH, rays - first)
        log, found, segments = _Log(), _Found(), 0
        state = _State(
            o=np.broadcast_to(tx_c, (count, 3)).copy(),
            d=launch[first:first + count].astype(np.float32),
            med=np.full(count, tx_medium, np.int64),
            w=np.ones(count, np.float32),
            rad=np.zeros(count, np.float32),
            ang=np.full(count, spacing, np.float32),
            length=np.zeros(count, np.float32),
            nint=np.zeros(count, np.int64),
            hist=np.full(count, -1, np.int64),
            src=np.arange(first, first + count),
        )
        for _ in range(max_steps):
            n_live = len(state.o)
            if n_live == 0:
                break
            children = [
                _bounce(ctx, state.take(slice(a, a + CHUNK_RAYS)), log, found)
                for a in range(0, n_live, CHUNK_RAYS)
            ]
            segments += n_live
            if budget is not None:
                budget.charge(n_live)
            state = _State.concat([c for c in children if c is not None])
            if state is None:
                break
            if len(state.o) > MAX_LIVE_RAYS:
                # safety cap: keep the rays most likely to matter, power factor over the squared
                # reduced length sum L_i / n_i (the paraxial ray-tube spreading of layered media)
                priority = state.w / np.maximum(state.length, 1e-4) ** 2
                keep = np.sort(np.argpartition(-priority, MAX_LIVE_RAYS - 1)[:MAX_LIVE_RAYS])
                state = state.take(keep)
        _resolve(found, log, width)  # signatures of this batch's candidates; the log is freed
        return found, segments

    firsts = list(range(0, rays, LAUNCH_BATCH))
    workers = min(SHOOT_THREADS, len(firsts))
    if workers > 1:
        # Embree and the large numpy operations release the GIL: batches run concurrently;
        # the results are merged in batch order, so the candidates are those of a serial run
        with ThreadPoolExecutor(max_workers=workers) as pool:
            batches = list(pool.map(launch_batch, firsts))
    else:
        batches = [launch_batch(first) for first in firsts]
    found = _Found()
    for part, _n in batches:
        for name in ("rx", "n", "src", "close", "codes", "faces"):
            getattr(found, name).extend(getattr(part, name))
    segments = sum(n for _f, n in batches)
    if not found.codes:
        return Candidates(
            receiver=np.zeros(0, np.int64), codes=np.zeros((0, width), np.int64),
            faces=np.zeros((0, width), np.int64), nint=np.zeros(0, np.int64), launch_dir=np.zeros((0, 3)),
            closeness=np.zeros(0), rays_launched=rays, segments=segments,
        )
    return Candidates(
        receiver=np.concatenate(found.rx),
        codes=np.concatenate(found.codes),
        faces=np.concatenate(found.faces),
        nint=np.concatenate(found.n),
        launch_dir=launch[np.concatenate(found.src)],
        closeness=np.concatenate(found.close),
        rays_launched=rays,
        segments=segments,
    )


def _interactions_needed(media: MediaTable, rx_medium: np.ndarray) -> np.ndarray:
    """Per medium (index m + 1): the fewest interactions a ray in it needs before it can be
    received, i.e. the number of transmissions to reach a medium of a receiver's material
    class (0 for those classes; a large number when none can be reached).

    A ray only ever crosses a surface of organ X between X and its parent (the bounce
    requires the side it comes from to be of the ray's class), each crossing of a visible
    surface costs one interaction and joins two different classes, and reception needs the
    ray's class to be the receiver's. So a breadth-first search over the graph of material
    classes (an edge per organ/parent pair of different classes) bounds the interactions
    still needed; a ray with ``nint + need > max_interactions`` can never make a candidate
    and is not spawned (exact pruning: the candidates are unchanged)."""
    cls = np.asarray(media.material_class, np.int64)
    n_cls = int(cls.max()) + 1
    adjacent: list[set[int]] = [set() for _ in range(n_cls)]
    for organ, parent in enumerate(np.asarray(media.parent, np.int64)):
        a, b = int(cls[organ + 1]), int(cls[parent + 1])
        if a != b:
            adjacent[a].add(b)
            adjacent[b].add(a)
    big = 1 << 20
    dist = np.full(n_cls, big, np.int64)
    frontier = sorted({int(c) for c in cls[np.asarray(rx_medium, np.int64) + 1]})
    dist[frontier] = 0
    step = 0
    while frontier:  # a graph of a dozen material classes
        step += 1
        nxt = sorted({b for a in frontier for b in adjacent[a] if dist[b] == big})
        dist[nxt] = step
        frontier = nxt
    return dist[cls]


def _resolve(found: _Found, log: _Log, width: int) -> None:
    """Rebuild the signatures (codes, faces) of the candidates found since the last call by
    walking the event log back from each one's last event, then empty the log."""
    new = slice(len(found.codes), len(found.hist))
    hist = found.hist[new]
    if hist:
        parent_log = np.concatenate(log.parent) if log.parent else np.zeros(0, np.int32)
        code_log = np.concatenate(log.code) if log.code else np.zeros(0, np.int32)
        face_log = np.concatenate(log.face) if log.face else np.zeros(0, np.int32)
        h = np.concatenate(hist)
        n = np.concatenate(found.n[new])
        codes = np.full((len(h), width), -1, np.int64)
        faces = np.full((len(h), width), -1, np.int64)
        slot = n - 1
        cur = h.astype(np.int64)
        while True:
            rows = np.flatnonzero(cur >= 0)
            if len(rows) == 0:
                break
            codes[rows, slot[rows]] = code_log[cur[rows]]
            faces[rows, slot[rows]] = face_log[cur[rows]]
            slot[rows] -= 1
            cur[rows] = parent_log[cur[rows]]
        # one resolved block per found block, so later batches index consistently
        sizes = [len(x) for x in hist]
        cuts = np.cumsum(sizes)[:-1]
        found.codes.extend(np.split(codes, cuts))
        found.faces.extend(np.split(faces, cuts))
    log.parent.clear()
    log.code.clear()
    log.face.clear()
    log.size = 0
