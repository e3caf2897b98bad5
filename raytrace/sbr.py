"""Shooting and bouncing rays: candidate interaction signatures for every receiver.

One launch (a Fibonacci sphere of directions at the transmitter) serves all
receivers. Per bounce, every live ray is cast at once (one Embree batch);
at each non-transparent hit it splits into a reflected ray and, unless Snell
has no real solution (total internal reflection), a transmitted ray, up to
``max_interactions`` events. A ray's power factor (Fresnel power
reflectance / transmittance, mean of TE and TM, times absorption
``exp(-2 alpha L)``) prunes it once below the dynamic range; a cap on live
rays keeps the strongest (stable sort: deterministic).

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
from raytrace.em import refract_direction
from raytrace.field import ray_fresnel
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
    kmax = int(max_interactions)
    launch = fibonacci_sphere(rays)
    spacing = angular_spacing_rad(rays)
    n_re = media.n_real
    n_c = media.n[0]
    alpha = (2.0 * np.pi * media.frequencies_hz[0] / 299_792_458.0) * -n_c.imag  # (M+1,) Np/m
    threshold = 10.0 ** (-dynamic_range_db / 10.0)
    off = scene.offset_m

    o = np.broadcast_to(np.asarray(tx_m, float), (rays, 3)).copy()
    d = launch.copy()
    med = np.full(rays, tx_medium, np.int64)
    push = np.zeros((rays, 3))
    w = np.ones(rays)
    rad = np.zeros(rays)
    ang = np.full(rays, spacing)
    nint = np.zeros(rays, np.int64)
    sig = np.full((rays, max(kmax, 1)), -1, np.int64)
    fseq = np.full((rays, max(kmax, 1)), -1, np.int64)
    src = np.arange(rays)

    out_rx, out_codes, out_faces, out_n, out_src, out_close = [], [], [], [], [], []
    segments = 0
    max_steps = 4 * kmax + 2 * len(media.materials) + 8
    for _ in range(max_steps):
        if len(o) == 0:
            break
        face, t = scene.first_hit(o, d, push)
        segments += len(o)
        if budget is not None:
            budget.charge(len(o))
        # reception
        for r in range(len(rx_m)):
            vec = rx_m[r] - o
            tt = np.einsum("ij,ij->i", vec, d)
            near = (med == rx_medium[r]) & (tt > 0.0) & (tt < t)
            if not near.any():
                continue
            i = np.flatnonzero(near)
            perp = np.linalg.norm(vec[i] - tt[i, None] * d[i], axis=1)
            radius = RECEPTION_FACTOR * (rad[i] + tt[i] * ang[i])
            hit_rx = perp <= radius
            if hit_rx.any():
                i = i[hit_rx]
                out_rx.append(np.full(len(i), r))
                out_codes.append(sig[i])
                out_faces.append(fseq[i])
                out_n.append(nint[i])
                out_src.append(src[i])
                out_close.append(perp[hit_rx] / np.maximum(radius[hit_rx], 1e-300))
        hit = face >= 0
        # advance all hitting rays to their hit point
        keep = hit.copy()
        if not keep.any():
            break
        f = face[keep]
        tk = t[keep]
        ok_, dk, mk = o[keep], d[keep], med[keep]
        pt = ok_ + tk[:, None] * dk
        wk = w[keep] * np.exp(-2.0 * alpha[mk + 1] * tk)
        radk = rad[keep] + tk * ang[keep]
        angk, nk, sk, fsk, srck = ang[keep], nint[keep], sig[keep], fseq[keep], src[keep]
        fn = scene.face_normals[f]
        dn = np.einsum("ij,ij->i", dk, fn)
        leaving = dn > 0.0
        organ = scene.face_organ[f]
        parent = media.parent[organ]
        m_from = np.where(leaving, organ, parent)
        m_to = np.where(leaving, parent, organ)
        sgn = np.where(leaving, 1.0, -1.0)[:, None]
        valid = (m_from == mk) & (wk >= threshold)
        transparent = media.face_transparent[f]

        new = []  # (rows, dir, med, push, w, rad, ang, nint, sig, fseq, src)
        ps = valid & transparent
        if ps.any():
            new.append((pt[ps], dk[ps], m_to[ps], sgn[ps] * fn[ps] * off, wk[ps], radk[ps], angk[ps],
                        nk[ps], sk[ps], fsk[ps], srck[ps]))
        ev = np.flatnonzero(valid & ~transparent & (nk < kmax))
        if len(ev):
            dj, fj = dk[ev], f[ev]
            ns = scene.smooth_normals(fj, pt[ev])
            n1, n2 = n_re[m_from[ev] + 1], n_re[m_to[ev] + 1]
            dns = np.einsum("ij,ij->i", dj, ns)
            ci = np.abs(dns)
            dt, tir = refract_direction(dj, ns, n1, n2)
            fr = ray_fresnel(n_c[m_from[ev] + 1], n_c[m_to[ev] + 1], ci, tir)
            refl_p = np.clip(0.5 * (np.abs(fr.r_te) ** 2 + np.abs(fr.r_tm) ** 2), 0.0, 1.0)
            refl_p = np.where(tir, 1.0, refl_p)
            sg = sgn[ev]
            # reflected
            dr = dj - 2.0 * dns[:, None] * ns
            okr = np.einsum("ij,ij->i", dr, fn[ev]) * sg[:, 0] < 0.0
            wr = wk[ev] * refl_p
            okr &= wr >= threshold
            slot = nk[ev]
            rows = np.arange(len(ev))
            sig_r = sk[ev].copy()
            sig_r[rows, slot] = encode(organ[ev], leaving[ev], 1)
            fs_r = fsk[ev].copy()
            fs_r[rows, slot] = fj
            if okr.any():
                new.append((pt[ev][okr], dr[okr], m_from[ev][okr], -sg[okr] * fn[ev][okr] * off, wr[okr],
                            radk[ev][okr], angk[ev][okr], slot[okr] + 1, sig_r[okr], fs_r[okr], srck[ev][okr]))
            # transmitted
            ct = np.sqrt(np.clip(1.0 - (n1 / n2) ** 2 * (1.0 - ci * ci), 0.0, None))
            okt = ~tir
            dt = np.where(okt[:, None], dt, dj)
            okt &= np.einsum("ij,ij->i", dt, fn[ev]) * sg[:, 0] > 0.0
            wt = wk[ev] * (1.0 - refl_p)
            okt &= wt >= threshold
            if okt.any():
                mag = np.maximum.reduce([
                    n1 * ci / np.maximum(n2 * ct, 1e-3),
                    n1 / n2,
                    np.ones_like(n1),
                ])
                mag = np.minimum(mag, 50.0)
                sig_t = sk[ev].copy()
                sig_t[rows, slot] = encode(organ[ev], leaving[ev], 0)
                new.append((pt[ev][okt], dt[okt], m_to[ev][okt], sg[okt] * fn[ev][okt] * off, wt[okt],
                            radk[ev][okt], (angk[ev] * mag)[okt], slot[okt] + 1, sig_t[okt], fs_r[okt], srck[ev][okt]))
        if not new:
            o = np.zeros((0, 3))
            break
        o, d, med, push, w, rad, ang, nint, sig, fseq, src = (np.concatenate(parts) for parts in zip(*new))
        if len(o) > MAX_LIVE_RAYS:
            order = np.argsort(-w, kind="stable")[:MAX_LIVE_RAYS]
            order.sort()
            o, d, med, push, w, rad, ang, nint, sig, fseq, src = (
                a[order] for a in (o, d, med, push, w, rad, ang, nint, sig, fseq, src)
            )
    k = max(kmax, 1)
    if out_rx:
        return Candidates(
            receiver=np.concatenate(out_rx),
            codes=np.concatenate(out_codes),
            faces=np.concatenate(out_faces),
            nint=np.concatenate(out_n),
            launch_dir=launch[np.concatenate(out_src)],
            closeness=np.concatenate(out_close),
            rays_launched=rays,
            segments=segments,
        )
    return Candidates(
        receiver=np.zeros(0, np.int64), codes=np.zeros((0, k), np.int64), faces=np.zeros((0, k), np.int64),
        nint=np.zeros(0, np.int64), launch_dir=np.zeros((0, 3)), closeness=np.zeros(0),
        rays_launched=rays, segments=segments,
    )
