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

Lossy media (docs/tracer.md "Normalisation", "Reciprocity in lossy media"). The ray
geometry and the tube ``J`` use ``Re n``; the amplitude uses the complex indices in a form
that is exactly reciprocal:

* Fresnel cosines from the ray's Snell invariant. At an interface crossed from medium 1 into
  medium 2 the tangential index is the real ``p = Re n_1 sin th_1 = Re n_2 sin th_2`` of the
  traced (real-index) ray, and each side's cosine is ``c_i = sqrt(1 - (p / n_i)^2)`` with its
  complex index (the decaying root), i.e. the plane wave ``exp(-j k0 (p x + n_i c_i z))`` with
  the same real tangential wavenumber on both sides, as in a transfer-matrix (``tmm``)
  calculation. Both directions of a path see the same ``(c_1, c_2)`` at each interface, so
  ``t_12 / t_21 = n_1 c_1 / (n_2 c_2)``; the tube's jump at the interface is ``sqrt(c_2 / c_1)``
  (the geometric cosine ratio for lossless media), so ``t_12 sqrt(c_2/c_1)`` over
  ``t_21 sqrt(c_1/c_2)`` is ``n_1 / n_2``: the product over a path telescopes to ``n_tx / n_rx``.
  In band mode ``p`` at a frequency f is the geometric mean of ``Re n_1(f) sin th_1`` and
  ``Re n_2(f) sin th_2`` (symmetric in the two directions; the Snell invariant at the carrier).
  Reflections keep the geometric incidence cosine (tangential index ``n_1 sin th_1``, complex):
  for a reflection inside one homogeneous lossy medium that is the saddle point of the
  reflected spectrum, hence asymptotically exact, and it is the same in both directions.
* Complex spreading. The real tube of a point source behind planar interfaces at normal
  incidence is ``(n_tx sum_i L_i / n_i)^2`` with real indices; the exact (paraxial,
  stationary-phase) field of the same source has it with the complex indices, so the
  amplitude is multiplied by ``K = (Re n_tx sum L_i / Re n_i) / (n_tx sum L_i / n_i)``
  (segment lengths ``L_i``, band frequency's indices). ``K = 1`` in a homogeneous medium. With
  the real tube's own reciprocity ``J_fwd / J_rev = (Re n_tx / Re n_rx)^2`` (etendue of the
  real-index problem) the path gain ``a`` is then exactly reciprocal, ``a_AB = a_BA``, for any
  geometry: ``(n_tx/n_rx) (Re n_rx/Re n_tx) K_fwd / K_rev = 1``.

Exact for lossless media, and for lossy planar layers at normal incidence (the paraxial point
source through planes); at oblique incidence and on curved lossy interfaces the complex tube is
approximated by its normal-incidence form (``K`` applied to both principal directions). Before
this form, the Fresnel coefficients used the real geometric incidence cosine and its complex
``cos_t``, the tube ``Re n`` only: forward and reverse differed by ``(n_tx / Re n_tx) /
(n_rx / Re n_rx)`` (0.24 dB, 7.4 deg across muscle/fat at 402 MHz) and, near a critical
angle, by far more (the geometric cosine on the grazing side against a complex one that
loss moves far from it).

Near field (``near_field``, refraction-only paths). The exact field of a Hertzian dipole
``p`` in a homogeneous medium of complex wavenumber ``k`` at distance ``r`` along ``d`` is
the far field ``(I - d d) p`` times ``1 + u + u^2`` plus the longitudinal
``-2 (u + u^2) d (d . p)``, with ``u = 1 / (j k r)`` (Jackson 9.18 in the ``exp(+j w t)``
convention). A straight path in one medium gets exactly this (dipole antennas; an isotropic
antenna has no axis and couples only through its transverse far field, times ``1 + u + u^2``).
A refraction-only path through interfaces gets the transverse factor ``1 + u + u^2`` with
``k r`` replaced by the path's complex electrical length ``k0 sum n_i L_i`` (an approximation:
it is exact where the interfaces are far from the source in wavelengths, where the factor is
1, and at the source's own medium; stated and bounded in docs/validation.md). Both forms are
symmetric in the two antennas, so reciprocity holds with the term on.

Caustics: the tube cross-section is floored at ``(TUBE_FLOOR * L)^2`` (L the
unfolded length) so geometric optics' infinite field at a caustic is capped;
the caustic phase shift is not applied (geometric optics limitation).

Group delay (docs/science.md (S22)). A path's ``group_delay_s`` is the phase slope of its own
gain at the carrier, ``tau_g = -d arg a / d w``, with everything in ``a`` that varies with
frequency: the tissues' dispersion, the lossy Fresnel coefficients (with their cosines' own
dependence on the indices), the complex spreading ``K``, the near-field factor, on the geometry
traced at the carrier (as band mode; by Fermat the optical length does not move to first order
when the geometry does). Writing ``a = b exp(-j k0 Re sum n_i L_i)``, the propagation phase's
slope is the analytic ``sum L_i n_g,i / c`` (the tissues' group index, Cole-Cole derivative) and
``b``, which varies slowly, is evaluated at ``f0 (1 +- GROUP_DELAY_STEP)`` by the same code as the
band and differentiated centrally: ``tau_g = sum L_i n_g,i / c - d arg b / d w``. In the near
field's reactive zone the factor ``1 + u + u^2`` can turn the slope negative (lossless media
below ``k r`` ~ 1.45; two dipoles 2-3 cm apart in fat at 402 MHz: -26 to -145 ps): ``tau_g``
is then the phase slope, not an arrival.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from raytrace.physics.em import C0, fresnel, interface_basis, refractive_index
from raytrace.solver import stratified
from raytrace.solver.media import MediaTable
from raytrace.solver.refine import KIND_PASS, KIND_REFLECTION, Steps

#: Smallest tube cross-section as a fraction of the unfolded length (caps caustic gain at +20 dB).
TUBE_FLOOR = 0.1
#: Relative half-step of the central difference of a path's slowly varying phase (module docstring,
#: "Group delay"): 40 kHz at 402 MHz. Its truncation error is ~(step f0)^2 / 6 of the third
#: derivative of that phase (below 1e-6 ps on the test cases) and its round-off ~1e-15 rad over
#: 2 pi 80 kHz (1e-21 s): the propagation phase, whose slope is the analytic sum L n_g / c, is
#: taken out first.
GROUP_DELAY_STEP = 1e-4


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
    group_delay_s: np.ndarray  # (P,) group delay at the centre frequency, -d arg(gain) / dw (module docstring)
    length_m: np.ndarray  # (P,)
    reflect_tir: list[np.ndarray]  # per step: (P,) True where a reflection is total (Snell has no real solution)
    max_sin_t: np.ndarray | None = None  # (P,) largest sin(transmitted angle) of the path's refractions into tissue
    exit_sin_t: np.ndarray | None = None  # (P,) the same for its refractions into air (0 where none)
    stratified: np.ndarray | None = None  # (P,) True where the gain is the generalized-ray integral on layers
    stack_tilt_deg: np.ndarray | None = None  # (P,) there, the layers' largest tilt from parallel (NaN elsewhere)


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
    near_field: bool = False,
) -> PathFields:
    """Complex gains at every frequency of ``media`` for recorded paths (vectorised over paths);
    ``near_field`` adds the dipole near-field terms to the refraction-only paths (module docstring).
    Group delays: module docstring, "Group delay"."""
    p = len(launch_dirs)
    n_band = len(media.frequencies_hz)
    aux_hz = media.frequencies_hz[0] * (1.0 + GROUP_DELAY_STEP * np.array([-1.0, 1.0]))
    freqs = np.concatenate([media.frequencies_hz, aux_hz])  # the band, then the carrier's two neighbours
    n = np.concatenate([media.n, _indices(media, aux_hz)])  # (F + 2, M+1)
    n_re0 = media.n_real
    n_g0 = media.n_group[0]
    k0 = 2.0 * np.pi * freqs / C0  # (F + 2,)
    e = antenna_vector(launch_dirs, tx_polarization, tx_pattern).astype(complex)
    field = np.repeat(e[:, None, :], len(freqs), axis=1)  # (P, F, 3)
    optical = np.zeros((p, len(freqs)), complex)  # sum n_i(f) L_i
    inv_n = np.zeros((p, len(freqs)), complex)  # sum L_i / n_i(f): the complex spreading (module docstring)
    inv_re = np.zeros((p, len(freqs)))  # sum L_i / Re n_i(f)
    direct = np.ones(p, bool)  # refraction-only so far
    straight = np.ones(p, bool)  # no interaction so far
    max_sin_t = np.zeros(p)
    exit_sin_t = np.zeros(p)
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
            inv_n[j] += seg[:, None] / n[:, mf + 1].T
            inv_re[j] += seg[:, None] / n[:, mf + 1].T.real
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
                refl = kind[inter] == KIND_REFLECTION
                direct[i] &= ~refl
                straight[i] = False
                n1, n2 = n[:, mf_i + 1].T, n[:, mt_i + 1].T  # (I, F)
                c1 = _incident_cosines(n1, n2, ci, basis, refl)
                ct_g = np.abs(np.einsum("ij,ij->i", np.nan_to_num(basis.k_transmitted), basis.normal_forward))
                sin_t = np.where(refl, 0.0, np.sqrt(np.clip(1.0 - ct_g * ct_g, 0.0, 1.0)))
                into_air = mt_i < 0
                max_sin_t[i] = np.maximum(max_sin_t[i], np.where(into_air, 0.0, sin_t))
                exit_sin_t[i] = np.maximum(exit_sin_t[i], np.where(into_air, sin_t, 0.0))
                fr = fresnel(n1, n2, c1)
                es = np.einsum("ifj,ij->if", field[i], basis.s)
                ep = np.einsum("ifj,ij->if", field[i], basis.p_in)
                tir_step[i] = refl & basis.tir
                cs = np.where(refl[:, None], fr.r_te, fr.t_te)
                cp = np.where(refl[:, None], fr.r_tm, fr.t_tm)
                p_t = np.where(refl[:, None], 0.0, np.nan_to_num(basis.p_transmitted))
                p_out = np.where(refl[:, None], basis.p_reflected, p_t)
                with np.errstate(invalid="ignore", divide="ignore"):
                    jump = np.where(refl[:, None], 1.0, np.sqrt(fr.cos_t / c1))
                cs, cp = cs * jump, cp * jump
                field[i] = (cs * es)[:, :, None] * basis.s[:, None, :] + (cp * ep)[:, :, None] * p_out[:, None, :]
            med[j] = np.where(kind == KIND_REFLECTION, mf, steps.med_to[s][j])
        tir_flags.append(tir_step)
    seg = np.linalg.norm(rx_m - prev, axis=1)
    optical += n[:, med + 1].T * seg[:, None]
    inv_n += seg[:, None] / n[:, med + 1].T
    inv_re += seg[:, None] / n[:, med + 1].T.real
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
    n_tx = n[:, tx_medium + 1]  # (F,)
    spreading = (n_tx.real[None, :] * inv_re) / (n_tx[None, :] * inv_n)  # K of the module docstring
    if near_field and direct.any():
        response[direct] = _near_field_response(
            response[direct], k0[None, :] * optical[direct], straight=straight[direct],
            d=last_dir[direct], tx_pol=np.broadcast_to(np.asarray(tx_polarization, float), (p, 3))[direct],
            tx_dipole=tx_pattern == "dipole", rx_pol=np.asarray(rx_polarization, float)[direct],
            rx_dipole=np.asarray(rx_pattern)[direct] == "dipole")
    tube = np.maximum(tube_m2_per_sr, (TUBE_FLOOR * length) ** 2)
    lam0 = C0 / freqs
    n_norm = np.sqrt(n_tx.real[None, :] * n[:, rx_medium + 1].T.real)  # (P, F)
    # the slowly varying part (absorption, Fresnel, spreading, near field, antennas) and the
    # propagation phase exp(-j k0 Re(sum n_i L_i)), apart for the group delay
    slow = ((lam0 / (4.0 * np.pi))[None, :] * response * spreading * np.exp(k0[None, :] * optical.imag)
            / np.sqrt(tube)[:, None] / n_norm)
    gains = slow * np.exp(-1j * k0[None, :] * optical.real)
    spectral = np.zeros(p, bool)
    tilt = np.full(p, np.nan)
    if near_field and tx_pattern == "dipole":
        for q in np.flatnonzero(np.asarray(rx_pattern) == "dipole"):
            found = _stratified_gain(steps, q, n, freqs, tx_m, tx_medium, rx_m[q], tx_polarization,
                                     rx_polarization[q], rx_medium[q])
            if found is not None:
                gains[q], tilt[q] = found
                spectral[q] = True
                slow[q] = gains[q] * np.exp(1j * k0 * optical[q].real)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = np.angle(slow[:, n_band + 1] / slow[:, n_band]) / (2.0 * np.pi * (aux_hz[1] - aux_hz[0]))
    return PathFields(gains=gains[:, :n_band], delay_s=delay_len / C0, group_delay_s=group_len / C0 - slope,
                      length_m=length, reflect_tir=tir_flags, max_sin_t=max_sin_t, exit_sin_t=exit_sin_t,
                      stratified=spectral, stack_tilt_deg=tilt)


def _stratified_gain(steps: Steps, j: int, n: np.ndarray, freqs: np.ndarray, tx_m: np.ndarray, tx_medium: int,
                     rx_m: np.ndarray, tx_pol: np.ndarray, rx_pol: np.ndarray,
                     rx_medium: int) -> tuple[np.ndarray, float] | None:
    """Path ``j``'s gain (F,) as the integral of its generalized ray through planar layers
    (:mod:`raytrace.solver.stratified`) and the layers' tilt [deg], or None where its interfaces are
    too far from parallel."""
    rows = [s for s in range(len(steps.valid)) if steps.valid[s][j] and steps.kind[s][j] != KIND_PASS]
    if not rows:
        return None  # one medium: the near-field term is already the exact dipole field
    points = np.concatenate([[tx_m], [steps.point[s][j] for s in rows], [rx_m]])
    reflect = np.array([steps.kind[s][j] == KIND_REFLECTION for s in rows])
    media = [tx_medium]
    for s, r in zip(rows, reflect):
        media.append(int(steps.med_from[s][j]) if r else int(steps.med_to[s][j]))
    beyond = np.array([steps.med_to[s][j] for s in rows]) + 1
    ray = stratified.stack_ray(points, np.array([steps.normal[s][j] for s in rows]), reflect,
                               np.asarray(media) + 1, beyond, n, np.asarray(tx_pol, float), np.asarray(rx_pol, float))
    if ray is None or stratified.node_count(ray, freqs) > stratified.MAX_NODES:
        return None
    return stratified.gain(ray, freqs, n[:, tx_medium + 1], n[:, rx_medium + 1]), ray.tilt_deg


def _indices(media: MediaTable, frequencies_hz: np.ndarray) -> np.ndarray:
    """(F, M+1) complex indices of ``media``'s materials at other frequencies (its own rule:
    :meth:`raytrace.solver.media.MediaTable.build`)."""
    f = np.asarray(frequencies_hz, float)
    return np.stack([refractive_index(np.broadcast_to(m.complex_relative_permittivity(f), f.shape))
                     for m in media.materials], axis=1).astype(complex)



def _incident_cosines(n1: np.ndarray, n2: np.ndarray, cos_i: np.ndarray, basis, refl: np.ndarray) -> np.ndarray:
    """Complex incidence cosines (I, F) that :func:`raytrace.physics.em.fresnel` takes (module
    docstring). Reflections: the geometric ``cos_i`` (tangential index ``n_1 sin th_1``, the
    saddle point of a reflection in one homogeneous lossy medium). Refractions: ``c_1 =
    sqrt(1 - (p / n_1)^2)`` from the real Snell invariant ``p`` of the traced ray, so that the
    far side's cosine :func:`raytrace.physics.em.cos_transmitted` derives is ``sqrt(1 - (p /
    n_2)^2)``, the same pair in both directions."""
    sin1 = np.sqrt(np.clip(1.0 - cos_i * cos_i, 0.0, 1.0))  # (I,)
    ct_geo = np.abs(np.einsum("ij,ij->i", np.nan_to_num(basis.k_transmitted), basis.normal_forward))
    sin2 = np.sqrt(np.clip(1.0 - ct_geo * ct_geo, 0.0, 1.0))
    p = np.sqrt(n1.real * sin1[:, None] * n2.real * sin2[:, None])  # Re n_1 sin th_1 = Re n_2 sin th_2 at f0
    c1 = np.sqrt(1.0 - (p / n1) ** 2 + 0j)
    c1 = np.where(c1.real < 0.0, -c1, c1)
    return np.where(refl[:, None], cos_i[:, None] + 0j, c1)


def _near_field_response(far: np.ndarray, electrical: np.ndarray, *, straight: np.ndarray, d: np.ndarray,
                         tx_pol: np.ndarray, tx_dipole: bool, rx_pol: np.ndarray, rx_dipole: np.ndarray) -> np.ndarray:
    """Receiver responses (D, F) of refraction-only paths with the dipole near-field terms
    (module docstring, Jackson 9.18): ``far * (1 + u + u^2) - 2 (u + u^2) (d . p_tx)(d . p_rx)``
    with ``u = 1 / (j k0 sum n_i L_i)``; the longitudinal term only on straight paths (one
    medium) between two dipoles. ``d`` is the arrival direction (= the launch one when straight)."""
    u = 1.0 / (1j * electrical)
    out = far * (1.0 + u + u * u)
    both = straight & tx_dipole & rx_dipole
    if both.any():
        tx_u = tx_pol[both] / np.linalg.norm(tx_pol[both], axis=1, keepdims=True)
        rx_u = rx_pol[both] / np.linalg.norm(rx_pol[both], axis=1, keepdims=True)
        axial = np.einsum("ij,ij->i", d[both], tx_u) * np.einsum("ij,ij->i", d[both], rx_u)
        out[both] -= 2.0 * (u[both] + u[both] ** 2) * axial[:, None]
    return out
