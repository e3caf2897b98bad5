"""Shooting and bouncing rays: candidate interaction signatures for every receiver.

One launch (a Fibonacci sphere of directions at the transmitter) serves all
receivers. Per bounce, every live ray is cast at once (one Embree batch);
at each non-transparent hit it splits into a reflected ray and, unless Snell
has no real solution (total internal reflection), a transmitted ray, up to
``max_interactions`` events. A ray's power factor (lossless Fresnel power
reflectance / transmittance from Re n, mean of TE and TM, times the true
absorption ``exp(-2 alpha L)``) prunes it once below the dynamic range; a cap
on live rays keeps the strongest (deterministic partition).

Reception: a segment passing within the reception radius of a receiver in
the same medium makes a candidate. The radius is the ray tube's half-width,
grown along the unfolded path as ``angle * length`` with ``angle`` the launch
spacing sqrt(4 pi / N), multiplied at each refraction by the tube's angular
magnification ``max(n1 cos_i / (n2 cos_t), n1 / n2, 1)``. Candidates are
only seeds: :func:`raytrace.refine.refine` makes every kept path exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from raytrace.budget import Budget
from raytrace.launch import angular_spacing_rad, fibonacci_sphere
from raytrace.media import MediaTable
from raytrace.refine import encode
from raytrace.scene import TracerScene

#: Live rays are capped at this many (strongest kept).
MAX_LIVE_RAYS = 2_000_000
#: Reception radius in units of the local ray-tube half-width.
RECEPTION_FACTOR = 1.0


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


def _refract(d: np.ndarray, ns: np.ndarray, dns: np.ndarray, eta: np.ndarray):
    """Vector Snell law (same formula as :func:`raytrace.em.refract_direction`, no input checks)."""
    sgn = np.where(dns < 0.0, -1.0, 1.0)
    ci = np.abs(dns)
    sin2 = eta * eta * (1.0 - ci * ci)
    tir = sin2 > 1.0
    ct = np.sqrt(np.clip(1.0 - sin2, 0.0, None))
    t = eta[:, None] * (d - (ci * sgn)[:, None] * ns) + (ct * sgn)[:, None] * ns
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, tir, ci, ct


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
    spacing = angular_spacing_rad(rays)
    n_re = media.n_real
    n_c = media.n[0]
    alpha = (2.0 * np.pi * media.frequencies_hz[0] / 299_792_458.0) * -n_c.imag  # (M+1,) Np/m
    threshold = 10.0 ** (-dynamic_range_db / 10.0)
    off = scene.offset_m
    rx_m = np.asarray(rx_m, float)

    o = np.broadcast_to(np.asarray(tx_m, float), (rays, 3)).copy()
    d = launch.copy()
    med = np.full(rays, tx_medium, np.int64)
    w = np.ones(rays)
    rad = np.zeros(rays)
    ang = np.full(rays, spacing)
    nint = np.zeros(rays, np.int64)
    hist = np.full(rays, -1, np.int64)
    src = np.arange(rays)
    log_parent: list[np.ndarray] = []
    log_code: list[np.ndarray] = []
    log_face: list[np.ndarray] = []
    logged = 0

    out_rx, out_hist, out_n, out_src, out_close = [], [], [], [], []
    segments = 0
    max_steps = 4 * kmax + 2 * len(media.materials) + 8
    for _ in range(max_steps):
        if len(o) == 0:
            break
        face, t, uv = scene.first_hit(o, d, barycentric=True, exact=False)
        segments += len(o)
        if budget is not None:
            budget.charge(len(o))
        # reception (rays in the receiver's medium only)
        for r in range(len(rx_m)):
            i = np.flatnonzero(med == rx_medium[r])
            if len(i) == 0:
                continue
            vec = rx_m[r] - o[i]
            di = d[i]
            tt = np.einsum("ij,ij->i", vec, di)
            sel = (tt > 0.0) & (tt < t[i])
            i, vec, di, tt = i[sel], vec[sel], di[sel], tt[sel]
            perp = np.linalg.norm(vec - tt[:, None] * di, axis=1)
            radius = RECEPTION_FACTOR * (rad[i] + tt * ang[i])
            got = perp <= radius
            if got.any():
                i = i[got]
                out_rx.append(np.full(len(i), r))
                out_hist.append(hist[i])
                out_n.append(nint[i])
                out_src.append(src[i])
                out_close.append(perp[got] / np.maximum(radius[got], 1e-300))
        keep = np.flatnonzero(face >= 0)
        if len(keep) == 0:
            break
        f = face[keep]
        tk = t[keep]
        dk, mk = d[keep], med[keep]
        pt = o[keep] + tk[:, None] * dk
        wk = w[keep] * np.exp(-2.0 * alpha[mk + 1] * tk)
        radk = rad[keep] + tk * ang[keep]
        fn = scene.face_normals[f]
        dn = np.einsum("ij,ij->i", dk, fn)
        leaving = dn > 0.0
        organ = scene.face_organ[f]
        parent = media.parent[organ]
        m_from = np.where(leaving, organ, parent)
        m_to = np.where(leaving, parent, organ)
        sg = np.where(leaving, 1.0, -1.0)
        valid = (m_from == mk) & (wk >= threshold)
        transparent = media.face_transparent[f]

        nk, angk = nint[keep], ang[keep]
        ev = valid & ~transparent & (nk < kmax)
        p_mask = valid & transparent
        # interaction physics over every hit at once (masks, no per-kind gathers)
        ns = scene.smooth_normals_uv(f, uv[keep])
        flip = np.einsum("ij,ij->i", ns, fn) <= 0.0
        ns[flip] = fn[flip]
        n1, n2 = n_re[m_from + 1], n_re[m_to + 1]
        dns = np.einsum("ij,ij->i", dk, ns)
        dt, tir, ci, ct = _refract(dk, ns, dns, n1 / n2)
        # pruning weight only: lossless Fresnel power reflectance from Re n (mean of TE, TM)
        n1c, n2c, n1t, n2i = n1 * ci, n2 * ct, n1 * ct, n2 * ci
        r_te = (n1c - n2c) / np.maximum(n1c + n2c, 1e-300)
        r_tm = (n2i - n1t) / np.maximum(n2i + n1t, 1e-300)
        refl_p = np.where(tir, 1.0, np.clip(0.5 * (r_te * r_te + r_tm * r_tm), 0.0, 1.0))
        dr = dk - (2.0 * dns)[:, None] * ns
        wr = wk * refl_p
        wt = wk - wr
        r_mask = ev & (np.einsum("ij,ij->i", dr, fn) * sg < 0.0) & (wr >= threshold)
        t_mask = ev & ~tir & (wt >= threshold) & (np.einsum("ij,ij->i", dt, fn) * sg > 0.0)
        mag = np.minimum(np.maximum(np.maximum(n1 * ci / np.maximum(n2 * ct, 1e-3), n1 / n2), 1.0), 50.0)
        # event log (interacting rays only): reflected entry at base + e, transmitted at base + E + e
        ev_idx = np.flatnonzero(ev)
        n_ev = len(ev_idx)
        evpos = np.cumsum(ev) - 1
        base = logged
        if n_ev:
            hk = hist[keep][ev_idx]
            log_parent.append(np.concatenate([hk, hk]))
            log_code.append(np.concatenate([encode(organ[ev_idx], leaving[ev_idx], 1),
                                            encode(organ[ev_idx], leaving[ev_idx], 0)]))
            log_face.append(np.concatenate([f[ev_idx], f[ev_idx]]))
            logged += 2 * n_ev
        n_r, n_t, n_p = int(r_mask.sum()), int(t_mask.sum()), int(p_mask.sum())
        total = n_r + n_t + n_p
        if total == 0:
            break
        a, b = n_r, n_r + n_t
        push = (sg * off)[:, None] * fn
        o = np.empty((total, 3))
        np.compress(r_mask, pt - push, axis=0, out=o[:a])
        o_tp = pt + push
        np.compress(t_mask, o_tp, axis=0, out=o[a:b])
        np.compress(p_mask, o_tp, axis=0, out=o[b:])
        d = np.empty((total, 3))
        np.compress(r_mask, dr, axis=0, out=d[:a])
        np.compress(t_mask, dt, axis=0, out=d[a:b])
        np.compress(p_mask, dk, axis=0, out=d[b:])
        med = np.concatenate([m_from[r_mask], m_to[t_mask], m_to[p_mask]])
        w = np.concatenate([wr[r_mask], wt[t_mask], wk[p_mask]])
        rad = np.concatenate([radk[r_mask], radk[t_mask], radk[p_mask]])
        ang = np.concatenate([angk[r_mask], (angk * mag)[t_mask], angk[p_mask]])
        nint = np.concatenate([nk[r_mask] + 1, nk[t_mask] + 1, nk[p_mask]])
        hist = np.concatenate([base + evpos[r_mask], base + n_ev + evpos[t_mask], hist[keep][p_mask]])
        src = src[keep]
        src = np.concatenate([src[r_mask], src[t_mask], src[p_mask]])
        if len(o) > MAX_LIVE_RAYS:
            order = np.sort(np.argpartition(-w, MAX_LIVE_RAYS - 1)[:MAX_LIVE_RAYS])
            o, d, med, w, rad, ang, nint, hist, src = (
                a[order] for a in (o, d, med, w, rad, ang, nint, hist, src)
            )
    if not out_rx:
        return Candidates(
            receiver=np.zeros(0, np.int64), codes=np.zeros((0, width), np.int64),
            faces=np.zeros((0, width), np.int64), nint=np.zeros(0, np.int64), launch_dir=np.zeros((0, 3)),
            closeness=np.zeros(0), rays_launched=rays, segments=segments,
        )
    parent_log = np.concatenate(log_parent) if log_parent else np.zeros(0, np.int64)
    code_log = np.concatenate(log_code) if log_code else np.zeros(0, np.int64)
    face_log = np.concatenate(log_face) if log_face else np.zeros(0, np.int64)
    h = np.concatenate(out_hist)
    n = np.concatenate(out_n)
    codes = np.full((len(h), width), -1, np.int64)
    faces = np.full((len(h), width), -1, np.int64)
    # walk the event log back from each candidate's last event
    slot = n - 1
    cur = h.copy()
    while True:
        live = cur >= 0
        if not live.any():
            break
        rows = np.flatnonzero(live)
        codes[rows, slot[rows]] = code_log[cur[rows]]
        faces[rows, slot[rows]] = face_log[cur[rows]]
        slot[rows] -= 1
        cur[rows] = parent_log[cur[rows]]
    return Candidates(
        receiver=np.concatenate(out_rx),
        codes=codes,
        faces=faces,
        nint=n,
        launch_dir=launch[np.concatenate(out_src)],
        closeness=np.concatenate(out_close),
        rays_launched=rays,
        segments=segments,
    )
