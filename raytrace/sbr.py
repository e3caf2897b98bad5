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

        parts = []  # (origin, dir, med, w, rad, ang, nint, hist, src)
        ps = np.flatnonzero(valid & transparent)
        if len(ps):
            parts.append((pt[ps] + (sg[ps] * off)[:, None] * fn[ps], dk[ps], m_to[ps], wk[ps], radk[ps],
                          ang[keep][ps], nint[keep][ps], hist[keep][ps], src[keep][ps]))
        ev = np.flatnonzero(valid & ~transparent & (nint[keep] < kmax))
        if len(ev):
            dj, fj, pj, fnj, sgj = dk[ev], f[ev], pt[ev], fn[ev], sg[ev]
            ns = scene.smooth_normals_uv(fj, uv[keep][ev])
            flip = np.einsum("ij,ij->i", ns, fnj) <= 0.0
            ns[flip] = fnj[flip]
            mf, mt = m_from[ev], m_to[ev]
            dns = np.einsum("ij,ij->i", dj, ns)
            dt, tir, ci, ct = _refract(dj, ns, dns, n_re[mf + 1] / n_re[mt + 1])
            # pruning weight only: lossless Fresnel power reflectance from Re n (mean of TE, TM)
            n1c, n2c = n_re[mf + 1] * ci, n_re[mt + 1] * ct
            n1t, n2i = n_re[mf + 1] * ct, n_re[mt + 1] * ci
            r_te = (n1c - n2c) / np.maximum(n1c + n2c, 1e-300)
            r_tm = (n2i - n1t) / np.maximum(n2i + n1t, 1e-300)
            refl_p = np.where(tir, 1.0, np.clip(0.5 * (r_te * r_te + r_tm * r_tm), 0.0, 1.0))
            wj, radj, angj = wk[ev], radk[ev], ang[keep][ev]
            nj, srcj = nint[keep][ev], src[keep][ev]
            base = logged
            log_parent.append(np.concatenate([hist[keep][ev], hist[keep][ev]]))
            log_code.append(np.concatenate([encode(organ[ev], leaving[ev], 1), encode(organ[ev], leaving[ev], 0)]))
            log_face.append(np.concatenate([fj, fj]))
            logged += 2 * len(ev)
            ids = np.arange(len(ev))
            # reflected
            dr = dj - (2.0 * dns)[:, None] * ns
            wr = wj * refl_p
            okr = (np.einsum("ij,ij->i", dr, fnj) * sgj < 0.0) & (wr >= threshold)
            if okr.any():
                k = np.flatnonzero(okr)
                parts.append((pj[k] - (sgj[k] * off)[:, None] * fnj[k], dr[k], mf[k], wr[k], radj[k], angj[k],
                              nj[k] + 1, base + ids[k], srcj[k]))
            # transmitted
            wt = wj * (1.0 - refl_p)
            okt = ~tir & (wt >= threshold)
            okt &= np.einsum("ij,ij->i", dt, fnj) * sgj > 0.0
            if okt.any():
                k = np.flatnonzero(okt)
                n1, n2 = n_re[mf[k] + 1], n_re[mt[k] + 1]
                mag = np.maximum(np.maximum(n1 * ci[k] / np.maximum(n2 * ct[k], 1e-3), n1 / n2), 1.0)
                parts.append((pj[k] + (sgj[k] * off)[:, None] * fnj[k], dt[k], mt[k], wt[k], radj[k],
                              angj[k] * np.minimum(mag, 50.0), nj[k] + 1, base + len(ev) + ids[k], srcj[k]))
        if not parts:
            break
        o, d, med, w, rad, ang, nint, hist, src = (
            np.concatenate(a) if len(parts) > 1 else a[0] for a in zip(*parts)
        )
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
