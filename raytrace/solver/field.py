"""Complex gain of refined paths: Jones field tracking, Fresnel, absorption, ray tube.

Normalisation (``docs/api.md``: ``|a|^2`` is the power transfer
between the two isotropic antennas). An isotropic transmitter of power P_t
in a medium of index n_t has, at 1 m, power density P_t / (4 pi) and field
``|E_1|^2 = 2 eta0 P_t / (4 pi Re n_t)``. Along the ray the field is
``E_rx = E_1 * R`` with the transfer ratio

    R = prod_k c_k sqrt(cos_t,k / cos_i,k) * exp(-j k0 sum_i n_i L_i) / sqrt(|det J|)

where ``c_k`` are the Fresnel field coefficients (TE on the s component, TM
on the p component, Jones calculus with the basis of :mod:`raytrace.physics.em`),
the ``sqrt(cos_t / cos_i)`` factor (refraction only, geometric cosines) is
the jump of the tube's cross-section at the interface so that the power in
the tube changes by exactly the power transmittance
``T = Re(n2 cos_t) |t|^2 / Re(n1 cos_i)``, ``exp(-j k0 n_i L_i)`` is the
phase and absorption of segment i (complex index, ``Im n <= 0``), and
``|det J|`` [m^2/sr] is the tube cross-section at the receiver per unit launch
solid angle (1 m^2/sr at 1 m: the reference), from
:func:`raytrace.solver.refine.refine`. The receiver (effective aperture
``lambda0^2 / (4 pi Re n_r^2)``) collects
``P_r = Re n_r |E_rx|^2 / (2 eta0) * lambda0^2 / (4 pi Re n_r^2)``, hence

    P_r / P_t = (lambda0 / (4 pi))^2 |R|^2 / (Re n_t Re n_r)
    a = lambda0 / (4 pi) * R / sqrt(Re n_t Re n_r)

which gives ``lambda0 / (4 pi n d)`` for a lossless homogeneous line of sight
and the Friis ``lambda0 / (4 pi d)`` in free space. Polarization: the
transmitter radiates a unit field along the projection of its polarization on
the plane normal to the launch direction (``dipole``: not normalised, i.e.
weighted by sin(theta)); the receiver responds with the projection of the
arriving field vector on its own polarization (normalised projection for an
isotropic receiver). Where an isotropic antenna's polarization is parallel to
the ray the projection is undefined; a fixed perpendicular is used instead.

Lossy media: the Fresnel coefficients are the plane-wave ones with complex
indices and the complex ``cos_t`` of Snell's law at the real (geometric)
incidence angle (:func:`raytrace.physics.em.fresnel`; for a ray in lossy tissue the
root continuous with the lossless limit, see :func:`raytrace.physics.em.cos_transmitted`), while the
ray geometry and tube use ``Re n``. This is exact for lossless media and at
normal incidence (tested against ``tmm`` through a lossy slab), and exactly
reciprocal for lossless media; at oblique incidence between media of
different loss tangents the local-plane-wave model is approximate and the
channel is reciprocal only to a few percent / about 0.1 rad per interface
(the reverse ray sees the real refraction angle where the forward Fresnel
formula used the complex one).

Caustics: the tube cross-section is floored at ``(TUBE_FLOOR * L)^2`` (L the
unfolded length) so geometric optics' infinite field at a caustic is capped;
the caustic phase shift is not applied (geometric optics limitation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from raytrace.physics.em import C0, fresnel, interface_basis
from raytrace.solver.media import MediaTable
from raytrace.solver.refine import KIND_PASS, KIND_REFLECTION, Steps

#: Smallest tube cross-section as a fraction of the unfolded length (caps caustic gain at +20 dB).
TUBE_FLOOR = 0.1


def antenna_vector(direction: np.ndarray, polarization: np.ndarray, pattern: str) -> np.ndarray:
    """(P, 3) real vector an antenna couples to along each unit ray direction.

    ``polarization`` is one vector (3,) or one per ray (P, 3). ``dipole``: its
    projection on the plane normal to the ray (length sin theta); ``isotropic``:
    that projection normalised, or a fixed perpendicular where it vanishes."""
    pol = np.broadcast_to(np.asarray(polarization, float), direction.shape)
    pol = pol / np.linalg.norm(pol, axis=1, keepdims=True)
    proj = pol - np.einsum("ij,ij->i", direction, pol)[:, None] * direction
    if pattern == "dipole":
        return proj
    norm = np.linalg.norm(proj, axis=1, keepdims=True)
    ref = np.where(np.abs(direction[:, 0:1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    fallback = np.cross(direction, ref)
    fallback /= np.linalg.norm(fallback, axis=1, keepdims=True)
    return np.where(norm > 1e-9, proj / np.maximum(norm, 1e-300), fallback)


@dataclass
class PathFields:
    gains: np.ndarray  # (P, F) complex
    delay_s: np.ndarray  # (P,) phase delay at the centre frequency, sum L Re n / c
    group_delay_s: np.ndarray  # (P,) group delay at the centre frequency, sum L n_g / c
    length_m: np.ndarray  # (P,)
    reflect_tir: list[np.ndarray]  # per step: (P,) True where a reflection is total (Snell has no real solution)


def path_gains(
    steps: Steps,
    media: MediaTable,
    tx_m: np.ndarray,
    tx_medium: int,
    rx_m: np.ndarray,
    rx_medium: np.ndarray,
    launch_dirs: np.ndarray,
    tube_m2_per_sr: np.ndarray,
    tx_polarization: np.ndarray,
    tx_pattern: str,
    rx_polarization: np.ndarray,
    rx_pattern: np.ndarray,
) -> PathFields:
    """Complex gains at every frequency of ``media`` for recorded paths (vectorised over paths)."""
    p = len(launch_dirs)
    freqs = media.frequencies_hz
    n = media.n  # (F, M+1)
    n_re0 = media.n_real
    n_g0 = media.n_group[0]
    k0 = 2.0 * np.pi * freqs / C0  # (F,)
    e = antenna_vector(launch_dirs, tx_polarization, tx_pattern).astype(complex)
    field = np.repeat(e[:, None, :], len(freqs), axis=1)  # (P, F, 3)
    optical = np.zeros((p, len(freqs)), complex)  # sum n_i(f) L_i
    delay_len = np.zeros(p)  # sum Re n_i(f0) L_i
    group_len = np.zeros(p)  # sum n_g,i(f0) L_i
    length = np.zeros(p)
    prev = np.broadcast_to(np.asarray(tx_m, float), (p, 3)).copy()
    med = np.full(p, tx_medium, np.int64)
    tir_flags: list[np.ndarray] = []
    for s in range(len(steps.valid)):
        v = steps.valid[s]
        tir_step = np.zeros(p, bool)
        if v.any():
            j = np.flatnonzero(v)
            seg = np.linalg.norm(steps.point[s][j] - prev[j], axis=1)
            mf = steps.med_from[s][j]
            optical[j] += n[:, mf + 1].T * seg[:, None]
            delay_len[j] += n_re0[mf + 1] * seg
            group_len[j] += n_g0[mf + 1] * seg
            length[j] += seg
            prev[j] = steps.point[s][j]
            kind = steps.kind[s][j]
            inter = kind != KIND_PASS
            if inter.any():
                i = j[inter]
                mf_i, mt_i = mf[inter], steps.med_to[s][i]
                basis = interface_basis(steps.dir_in[s][i], steps.normal[s][i], n_re0[mf_i + 1], n_re0[mt_i + 1])
                ci = basis.cos_i
                fr = fresnel(n[:, mf_i + 1].T, n[:, mt_i + 1].T, ci[:, None])  # (I, F), ray branch of cos_t
                es = np.einsum("ifj,ij->if", field[i], basis.s)
                ep = np.einsum("ifj,ij->if", field[i], basis.p_in)
                refl = kind[inter] == KIND_REFLECTION
                tir_step[i] = refl & basis.tir
                cs = np.where(refl[:, None], fr.r_te, fr.t_te)
                cp = np.where(refl[:, None], fr.r_tm, fr.t_tm)
                p_t = np.where(refl[:, None], 0.0, np.nan_to_num(basis.p_transmitted))
                p_out = np.where(refl[:, None], basis.p_reflected, p_t)
                ct_geo = np.abs(np.einsum("ij,ij->i", np.nan_to_num(basis.k_transmitted), basis.normal_forward))
                jump = np.where(refl, 1.0, np.sqrt(ct_geo / np.maximum(ci, 1e-300)))
                field[i] = (
                    (cs * es)[:, :, None] * basis.s[:, None, :] + (cp * ep)[:, :, None] * p_out[:, None, :]
                ) * jump[:, None, None]
            med[j] = np.where(kind == KIND_REFLECTION, mf, steps.med_to[s][j])
        tir_flags.append(tir_step)
    seg = np.linalg.norm(rx_m - prev, axis=1)
    optical += n[:, med + 1].T * seg[:, None]
    delay_len += n_re0[med + 1] * seg
    group_len += n_g0[med + 1] * seg
    length += seg
    last_dir = (rx_m - prev) / np.maximum(seg, 1e-300)[:, None]
    # receiver projection
    e_rx = np.zeros((p, 3))
    for pattern in np.unique(rx_pattern):
        sel = rx_pattern == pattern
        e_rx[sel] = antenna_vector(last_dir[sel], rx_polarization[sel], str(pattern))
    response = np.einsum("pfj,pj->pf", field, e_rx)
    tube = np.maximum(tube_m2_per_sr, (TUBE_FLOOR * length) ** 2)
    lam0 = C0 / freqs
    n_norm = np.sqrt(n[:, tx_medium + 1].real[None, :] * n[:, rx_medium + 1].T.real)  # (P, F)
    gains = (lam0 / (4.0 * np.pi))[None, :] * response * np.exp(-1j * k0[None, :] * optical) / np.sqrt(tube)[:, None] / n_norm
    return PathFields(gains=gains, delay_s=delay_len / C0, group_delay_s=group_len / C0, length_m=length,
                      reflect_tir=tir_flags)
