"""Plane-wave electromagnetics in lossy media: propagation constants, Snell, Fresnel.

Everything is vectorised with numpy broadcasting (no Python loop per ray).

Conventions (stated once, used everywhere in CapsuleRT)
-------------------------------------------------------
* Time dependence ``exp(+j w t)``; a plane wave is ``E0 exp(-j k . r)``.
* Complex relative permittivity ``eps = eps' - j eps''`` with
  ``eps'' = sigma / (w eps0) >= 0`` for a passive medium (``sigma`` is the
  effective conductivity tabulated by tissue databases).
* Complex refractive index ``n = sqrt(eps)`` on the branch ``Re n > 0``,
  ``Im n <= 0``.
* Wavenumber ``k = (w / c0) n = beta - j alpha``: ``beta`` (rad/m) sets the
  phase, ``alpha >= 0`` (Np/m) the amplitude decay ``exp(-alpha L)``.
  Phase velocity ``w / beta``, wavelength ``2 pi / beta``.
  (docs/science.md "Physics of the ray model"; thesis Ch. 5.)
* Loss is a NEGATIVE imaginary part of ``eps`` and ``n``. Optics packages
  with ``exp(-j w t)`` (e.g. ``tmm``) use ``n + j kappa``: pass ``conj(n)``.

Interface geometry and Fresnel basis
------------------------------------
At an interface with unit normal ``nf`` oriented along the incident
propagation (from medium 1 into medium 2, ``k_in . nf = cos_i >= 0``):

* ``s`` is the unit vector perpendicular to the plane of incidence,
  ``s = (k_in x nf) / |k_in x nf|`` (common to all three waves). At normal
  incidence (``|k_in x nf| < 1e-9``) the plane of incidence is undefined and
  ``s`` is taken from a fixed reference axis: ``s = (x_hat x nf)/|.|``, or
  ``(y_hat x nf)/|.|`` when ``|nf . x_hat| > 0.9``.
* For each wave ``j`` (incident, reflected, transmitted) with unit direction
  ``k_j``: ``p_j = s x k_j``. Then ``(p_j, s, k_j)`` is right-handed and the
  magnetic field of a TM wave is ``H_j = (n_j / eta0) E_j s``.
* A field is written ``E = E_s s + E_p p_j`` (the 2-vector ``(E_s, E_p)`` is
  the Jones vector of the ray in that local basis). With this basis the
  field amplitude coefficients are those of the ``tmm`` package / Born & Wolf
  (Byrnes, "Multilayer optical calculations", arXiv:1603.02720, Eq. 4-5)::

      r_te = (n1 ci - n2 ct) / (n1 ci + n2 ct)     t_te = 2 n1 ci / (n1 ci + n2 ct)
      r_tm = (n2 ci - n1 ct) / (n2 ci + n1 ct)     t_tm = 2 n1 ci / (n2 ci + n1 ct)

  i.e. ``E_s,refl = r_te E_s,inc``, ``E_p,refl = r_tm E_p,inc`` (along
  ``p_reflected``), ``E_s,tr = t_te E_s,inc``, ``E_p,tr = t_tm E_p,inc`` (along
  ``p_transmitted``). Tangential ``E`` and ``H`` are then continuous. At normal
  incidence ``p_reflected = -p_in`` and ``r_tm = -r_te``: the reflected field
  is ``r_te`` times the incident one for every polarization, as it must be.
  Flipping the sign of ``s`` flips every ``p_j`` and leaves the coefficients
  unchanged.

``ci`` is ``cos(theta_i)`` and ``ct`` the complex ``cos(theta_t)`` of
:func:`cos_transmitted`. Geometry (ray directions, total internal reflection
masks) uses the real parts of the indices; the Fresnel coefficients use the
complex indices.

It stays one module (about 500 lines) because every function in it depends on the sign and basis
conventions stated above; keeping them together keeps those conventions in one place.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import scipy.constants

from raytrace.errors import FrequencyOutOfRangeError, InputError, InvalidGeometryError

__all__ = [
    "C0",
    "EPS0",
    "MU0",
    "ETA0",
    "Fresnel",
    "InterfaceBasis",
    "attenuation_db_per_m",
    "attenuation_np_per_m",
    "complex_relative_permittivity",
    "cos_transmitted",
    "critical_angle",
    "fresnel",
    "interface_basis",
    "is_total_internal_reflection",
    "phase_velocity_m_per_s",
    "power_reflectance",
    "propagation_factor",
    "power_transmittance",
    "reflect_direction",
    "refract_direction",
    "refractive_index",
    "snell_angle",
    "wavelength_m",
    "wavenumber",
]

#: Speed of light in vacuum, m/s (exact by the SI definition of the metre).
C0: Final[float] = scipy.constants.c
#: Vacuum permeability, H/m (CODATA 2018). Written here rather than taken from scipy.constants:
#: since the 2019 SI it is measured, and scipy's value follows the CODATA edition of the
#: installed scipy (2018 up to 1.14, 2022 from 1.15: 7e-10 relative apart), which would make
#: the same request's gains depend on the scipy installed.
MU0: Final[float] = 1.25663706212e-6
#: Vacuum permittivity, F/m (CODATA 2018; as :data:`MU0`).
EPS0: Final[float] = 8.8541878128e-12
#: Impedance of free space, ohm.
ETA0: Final[float] = MU0 * C0

#: 20 log10(e): nepers to decibels for field amplitudes.
_DB_PER_NP: Final[float] = 20.0 / np.log(10.0)
#: Relative tolerance on a passive medium's imaginary part (allows round-off).
_PASSIVE_TOL: Final[float] = 1e-12
#: Below this |k x n| the incidence is treated as normal (plane of incidence undefined).
_NORMAL_INCIDENCE_TOL: Final[float] = 1e-9


# --------------------------------------------------------------------------- validation


def _frequency(frequency_hz: float | np.ndarray) -> np.ndarray:
    f = np.asarray(frequency_hz, dtype=float)
    if not np.all(np.isfinite(f)) or np.any(f <= 0.0):
        raise FrequencyOutOfRangeError(
            "frequency must be finite and strictly positive (hertz)", field="frequency_hz"
        )
    return f


def _passive(x: complex | np.ndarray, field: str, what: str) -> np.ndarray:
    """Check a passive medium quantity (Im <= 0) with finite values."""
    z = np.asarray(x, dtype=complex)
    if not np.all(np.isfinite(z)):
        raise InputError(f"{what} must be finite", field=field)
    if np.any(z.imag > _PASSIVE_TOL * np.maximum(np.abs(z), 1.0)):
        raise InputError(
            f"{what} has a positive imaginary part; CapsuleRT writes loss as a negative "
            "imaginary part (time dependence exp(+j w t), eps = eps' - j eps''): pass conj()",
            field=field,
        )
    return z


def _index(n: complex | np.ndarray, field: str) -> np.ndarray:
    z = _passive(n, field, "refractive index")
    if np.any(z.real <= 0.0):
        raise InputError("refractive index must have a positive real part", field=field)
    return z


def _cos_incidence(cos_i: float | np.ndarray) -> np.ndarray:
    c = np.asarray(cos_i)
    if not np.all(np.isfinite(c)):
        raise InvalidGeometryError("cosine of the incidence angle must be finite", field="cos_i")
    if not np.iscomplexobj(c):
        c = c.astype(float)
        if np.any((c < -1e-12) | (c > 1.0 + 1e-12)):
            raise InvalidGeometryError(
                "cosine of the incidence angle must lie in [0, 1] (angle measured from the "
                "normal oriented into the second medium)",
                field="cos_i",
            )
        c = np.clip(c, 0.0, 1.0)
    return c


def _unit(v: np.ndarray, field: str) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    if v.shape[-1:] != (3,):
        raise InvalidGeometryError(f"expected 3-vectors (shape (..., 3)), got shape {v.shape}", field=field)
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    if not np.all(np.isfinite(v)) or np.any(norm == 0.0):
        raise InvalidGeometryError("vectors must be finite and non-zero", field=field)
    return v / norm


# --------------------------------------------------------------------------- media


def complex_relative_permittivity(
    relative_permittivity: float | np.ndarray,
    conductivity_s_per_m: float | np.ndarray,
    frequency_hz: float | np.ndarray,
) -> np.ndarray:
    """``eps = eps' - j sigma / (w eps0)`` (docs/science.md "Physics of the ray model")."""
    f = _frequency(frequency_hz)
    eps_r = np.asarray(relative_permittivity, dtype=float)
    sigma = np.asarray(conductivity_s_per_m, dtype=float)
    if not (np.all(np.isfinite(eps_r)) and np.all(eps_r > 0.0)):
        raise InputError("relative permittivity must be finite and positive", field="relative_permittivity")
    if not (np.all(np.isfinite(sigma)) and np.all(sigma >= 0.0)):
        raise InputError("conductivity must be finite and non-negative (S/m)", field="conductivity_s_per_m")
    return eps_r - 1j * sigma / (2.0 * np.pi * f * EPS0)


def refractive_index(eps: complex | np.ndarray) -> np.ndarray:
    """Complex refractive index ``n = sqrt(eps)`` with ``Re n > 0``, ``Im n <= 0``."""
    z = _passive(eps, "eps", "complex relative permittivity")
    n = np.sqrt(z)
    # Principal root already has Re >= 0; for a passive eps it also has Im <= 0
    # except on the negative real axis (eps' < 0, eps'' = 0) where it returns +j|n|.
    return np.where(n.imag > 0.0, np.conj(n), n)


def group_index(eps: complex | np.ndarray, deps_dw: complex | np.ndarray,
                frequency_hz: float | np.ndarray) -> np.ndarray:
    """Group index ``n_g = Re(n + w dn/dw)`` with ``dn/dw = (d eps/d w) / (2 n)``
    (docs/science.md (S22)): ``c / n_g`` is the speed of a narrow-band pulse's envelope,
    and a segment of length L delays it by ``L n_g / c`` where its carrier phase is delayed
    by ``L Re n / c``. ``deps_dw`` in s/rad (:func:`raytrace.physics.tissues.\
complex_relative_permittivity_derivative`)."""
    n = refractive_index(eps)
    w = 2.0 * np.pi * _frequency(frequency_hz)
    return (n + w * np.asarray(deps_dw, complex) / (2.0 * n)).real


def wavenumber(eps: complex | np.ndarray, frequency_hz: float | np.ndarray) -> np.ndarray:
    """Complex wavenumber ``k = (w / c0) sqrt(eps) = beta - j alpha`` in rad/m."""
    f = _frequency(frequency_hz)
    return (2.0 * np.pi * f / C0) * refractive_index(eps)


def phase_velocity_m_per_s(eps: complex | np.ndarray, frequency_hz: float | np.ndarray) -> np.ndarray:
    """Phase velocity ``w / Re k`` (below ``c0 / sqrt(eps')`` in a lossy medium)."""
    f = _frequency(frequency_hz)
    return 2.0 * np.pi * f / wavenumber(eps, f).real


def attenuation_np_per_m(eps: complex | np.ndarray, frequency_hz: float | np.ndarray) -> np.ndarray:
    """Field attenuation constant ``alpha = -Im k`` in Np/m (amplitude ``exp(-alpha L)``)."""
    return -wavenumber(eps, frequency_hz).imag


def attenuation_db_per_m(eps: complex | np.ndarray, frequency_hz: float | np.ndarray) -> np.ndarray:
    """Field (and power) attenuation ``20 log10(e) alpha`` in dB/m."""
    return _DB_PER_NP * attenuation_np_per_m(eps, frequency_hz)


def wavelength_m(eps: complex | np.ndarray, frequency_hz: float | np.ndarray) -> np.ndarray:
    """Wavelength in the medium ``2 pi / Re k`` in metres."""
    return 2.0 * np.pi / wavenumber(eps, frequency_hz).real


def propagation_factor(
    eps: complex | np.ndarray, frequency_hz: float | np.ndarray, length_m: float | np.ndarray
) -> np.ndarray:
    """Plane-wave field factor ``exp(-j k L) = exp(-alpha L) exp(-j beta L)`` over a path length ``L``.

    Amplitude decays as ``exp(-Im(-k) L)`` and the phase lags by ``Re(k) L``
    (docs/science.md "Physics of the ray model"). ``length_m`` must be finite and >= 0.
    """
    length = np.asarray(length_m, dtype=float)
    if not np.all(np.isfinite(length)) or np.any(length < 0.0):
        raise InputError("path length must be finite and non-negative (metres)", field="length_m")
    return np.exp(-1j * wavenumber(eps, frequency_hz) * length)


# --------------------------------------------------------------------------- Snell


def cos_transmitted(
    n1: complex | np.ndarray, n2: complex | np.ndarray, cos_i: float | np.ndarray
) -> np.ndarray:
    """Complex ``cos(theta_t) = sqrt(1 - (n1/n2)^2 (1 - cos_i^2))`` on the physical branch.

    Snell's law ``n1 sin_i = n2 sin_t`` (Born & Wolf 1.5.2). Which of the two
    roots is physical depends on the tangential index ``n1 sin_i``:

    * **Real** ``n1 sin_i`` (a lossless first medium, or a wave that entered
      the layer stack from one, e.g. the complex ``cos`` inside a slab): the
      transmitted wave ``exp(-j k0 n2 ct z)`` must decay away from the
      interface, ``Im(n2 ct) < 0``; when ``n2 ct`` is real (lossless, no total
      internal reflection) the forward root ``Re(n2 ct) > 0``. For lossless
      total internal reflection this is the evanescent root ``ct = -j |ct|``.
      Same rule as ``tmm.is_forward_angle`` up to the conjugate time convention.
    * **Complex** ``n1 sin_i``: a ray in lossy tissue, i.e. a wave decaying
      along its own real direction (the ray tracer's case). Along the
      interface the incident field then varies as ``exp(-j k0 n1 sin_i x)``
      with a real decay, and the transmitted field at a fixed ``x`` legitimately
      *grows* away from the interface (the field seen further out was launched
      from further back, where the incident wave was stronger), so the decay
      rule would pick the backward root (``Re ct < 0``, ``|r| > 1``: a ray
      leaving muscle into air). Below the geometric critical angle (real
      parts) the root continuous with the lossless limit is used, the
      principal root ``Re ct >= 0``; beyond it the evanescent root with
      ``Im(n2 ct) <= 0``.
    """
    n1 = _index(n1, "n1")
    n2 = _index(n2, "n2")
    ci = _cos_incidence(cos_i)
    sin2_t = (n1 / n2) ** 2 * (1.0 - ci * ci)
    ct = np.sqrt(1.0 - sin2_t + 0j)
    nct = n2 * ct
    tiny = 100.0 * np.finfo(float).eps
    lossy = np.abs(nct.imag) > tiny * np.maximum(np.abs(nct), 1e-300)
    decaying_backward = np.where(lossy, nct.imag > 0.0, nct.real < 0.0)
    kx = n1 * np.sqrt(1.0 - ci * ci + 0j)  # tangential index n1 sin_i
    complex_kx = np.abs(kx.imag) > 1e3 * np.finfo(float).eps * np.maximum(np.abs(kx), 1e-300)
    geometric_tir = (n1.real / n2.real) ** 2 * (1.0 - np.real(ci) ** 2) > 1.0
    ray_backward = np.where(geometric_tir, nct.imag > 0.0, ct.real < 0.0)
    backward = np.where(complex_kx, ray_backward, decaying_backward)
    return np.where(backward, -ct, ct)


def snell_angle(
    n1: float | np.ndarray, n2: float | np.ndarray, theta_i: float | np.ndarray
) -> np.ndarray:
    """Refraction angle (rad) from ``n1 sin theta_i = n2 sin theta_t`` for real indices.

    The real parts of ``n1``, ``n2`` are used. NaN where the wave is totally
    internally reflected (``n1 sin theta_i / n2 > 1``).
    """
    n1r = np.real(np.asarray(n1))
    n2r = np.real(np.asarray(n2))
    s = n1r * np.sin(np.asarray(theta_i, dtype=float)) / n2r
    with np.errstate(invalid="ignore"):
        return np.where(np.abs(s) <= 1.0, np.arcsin(np.clip(s, -1.0, 1.0)), np.nan)


def critical_angle(n1: float | np.ndarray, n2: float | np.ndarray) -> np.ndarray:
    """Critical angle ``arcsin(n2 / n1)`` (rad) from real parts; NaN when ``Re n2 >= Re n1``."""
    ratio = np.real(np.asarray(n2)) / np.real(np.asarray(n1))
    return np.where(ratio < 1.0, np.arcsin(np.clip(ratio, 0.0, 1.0)), np.nan)


def is_total_internal_reflection(
    n1: complex | np.ndarray, n2: complex | np.ndarray, cos_i: float | np.ndarray
) -> np.ndarray:
    """True where ``(Re n1 / Re n2)^2 (1 - cos_i^2) > 1`` (geometric TIR, real parts)."""
    ci = np.real(np.asarray(cos_i))
    ratio = np.real(np.asarray(n1)) / np.real(np.asarray(n2))
    return ratio * ratio * (1.0 - ci * ci) > 1.0


# --------------------------------------------------------------------------- Fresnel


@dataclass(frozen=True)
class Fresnel:
    """Field amplitude coefficients at one interface (arrays, broadcast shape).

    ``r_te``/``t_te`` act on the ``s`` component, ``r_tm``/``t_tm`` on the ``p``
    component in the basis of :func:`interface_basis` (``p_j = s x k_j``); see
    the module docstring. ``cos_t`` is the complex cosine of the transmission
    angle (:func:`cos_transmitted`).
    """

    r_te: np.ndarray
    t_te: np.ndarray
    r_tm: np.ndarray
    t_tm: np.ndarray
    cos_t: np.ndarray


def fresnel(
    n1: complex | np.ndarray, n2: complex | np.ndarray, cos_i: float | np.ndarray
) -> Fresnel:
    """Fresnel field coefficients for TE (s) and TM (p), lossy media, any incidence.

    Born & Wolf Eq. 1.5.20-21 in the ``tmm`` sign convention (Byrnes,
    arXiv:1603.02720): see the module docstring for the formulas and the basis
    vectors they refer to. ``cos_i`` is ``k_in . nf`` in ``[0, 1]`` (or complex
    for an inhomogeneous incident wave).
    """
    n1 = _index(n1, "n1")
    n2 = _index(n2, "n2")
    ci = _cos_incidence(cos_i)
    ct = cos_transmitted(n1, n2, ci)
    n1ci, n2ct, n2ci, n1ct = n1 * ci, n2 * ct, n2 * ci, n1 * ct
    same = np.broadcast_to(n1 == n2, np.broadcast(n1ci, n2ct).shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        d_te = n1ci + n2ct
        d_tm = n2ci + n1ct
        r_te = np.where(same, 0.0, (n1ci - n2ct) / d_te)
        t_te = np.where(same, 1.0, 2.0 * n1ci / d_te)
        r_tm = np.where(same, 0.0, (n2ci - n1ct) / d_tm)
        t_tm = np.where(same, 1.0, 2.0 * n1ci / d_tm)
    ct = np.broadcast_to(ct, r_te.shape)
    return Fresnel(r_te=r_te + 0j, t_te=t_te + 0j, r_tm=r_tm + 0j, t_tm=t_tm + 0j, cos_t=ct + 0j)


def power_reflectance(r: complex | np.ndarray) -> np.ndarray:
    """Power reflectance ``R = |r|^2`` (either polarization)."""
    return np.abs(np.asarray(r)) ** 2


def power_transmittance(
    n1: complex | np.ndarray,
    n2: complex | np.ndarray,
    cos_i: float | np.ndarray,
    t: complex | np.ndarray,
    polarization: Literal["te", "tm"],
) -> np.ndarray:
    """Power transmittance (normal Poynting flux ratio), ``tmm`` forms (Byrnes Eq. 21-22).

    ``T_te = Re(n2 ct) / Re(n1 ci) |t|^2``,
    ``T_tm = Re(n2 conj(ct)) / Re(n1 conj(ci)) |t|^2``. These are unchanged by
    conjugating every quantity, so they hold in our ``exp(+j w t)``
    convention as written. For a lossless first medium ``R + T = 1``.
    """
    n1 = _index(n1, "n1")
    n2 = _index(n2, "n2")
    ci = _cos_incidence(cos_i)
    ct = cos_transmitted(n1, n2, ci)
    t = np.asarray(t)
    if polarization == "te":
        return np.real(n2 * ct) / np.real(n1 * ci) * np.abs(t) ** 2
    if polarization == "tm":
        return np.real(n2 * np.conj(ct)) / np.real(n1 * np.conj(ci)) * np.abs(t) ** 2
    raise InputError(f"polarization must be 'te' or 'tm', got {polarization!r}", field="polarization")


# --------------------------------------------------------------------------- ray geometry


def reflect_direction(d: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Specular reflection ``d - 2 (d . n) n`` of unit directions (..., 3); either normal sign."""
    d = _unit(d, "direction")
    n = _unit(n, "normal")
    return d - 2.0 * np.sum(d * n, axis=-1, keepdims=True) * n


def refract_direction(
    d: np.ndarray, n: np.ndarray, n1: complex | np.ndarray, n2: complex | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Refracted unit directions (vector Snell law) and the total-internal-reflection mask.

    ``t = eta (d - ci nf) + ct nf`` with ``nf`` the normal oriented along ``d``,
    ``eta = Re n1 / Re n2``, ``ci = d . nf``, ``ct = sqrt(1 - eta^2 (1 - ci^2))``.
    Real parts of the indices are used (ray geometry). Rows under total
    internal reflection get NaN directions and ``True`` in the mask. ``n1``
    and ``n2`` broadcast against the leading shape of ``d``.
    """
    d = _unit(d, "direction")
    n = _unit(n, "normal")
    dn = np.sum(d * n, axis=-1, keepdims=True)
    nf = np.where(dn < 0.0, -n, n) + 0.0  # + 0.0: no negative zeros
    ci = np.abs(dn)
    eta = (np.real(np.asarray(n1, dtype=complex)) / np.real(np.asarray(n2, dtype=complex)))[..., np.newaxis]
    sin2_t = eta * eta * (1.0 - ci * ci)
    tir = sin2_t > 1.0
    ct = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    t = eta * (d - ci * nf) + ct * nf
    t = t / np.linalg.norm(t, axis=-1, keepdims=True)
    t = np.where(tir, np.nan, t)
    return t, tir[..., 0]


@dataclass(frozen=True)
class InterfaceBasis:
    """Local polarization bases at an interface (arrays of shape (..., 3)).

    Iterating yields ``(s, p_in, p_reflected, p_transmitted)`` so the object
    unpacks like a tuple. ``p_transmitted`` and ``k_transmitted`` are ``None``
    when the indices were not given, NaN rows under total internal reflection.
    ``normal_forward`` is the unit normal oriented along the incident direction
    and ``cos_i = k_in . normal_forward``.
    """

    s: np.ndarray
    p_in: np.ndarray
    p_reflected: np.ndarray
    p_transmitted: np.ndarray | None
    k_in: np.ndarray
    k_reflected: np.ndarray
    k_transmitted: np.ndarray | None
    normal_forward: np.ndarray
    cos_i: np.ndarray
    tir: np.ndarray | None

    def __iter__(self):  # noqa: D105 - tuple-like unpacking
        return iter((self.s, self.p_in, self.p_reflected, self.p_transmitted))


def interface_basis(
    k_in: np.ndarray,
    normal: np.ndarray,
    n1: complex | np.ndarray | None = None,
    n2: complex | np.ndarray | None = None,
) -> InterfaceBasis:
    """Unit vectors ``s``, ``p_in``, ``p_reflected``, ``p_transmitted`` for rays hitting an interface.

    ``k_in`` (..., 3) incident directions, ``normal`` (..., 3) surface normals of
    either orientation (normalised here). ``s = k_in x nf / |.|`` and
    ``p_j = s x k_j`` (module docstring), which is the basis the coefficients of
    :func:`fresnel` refer to. Normal incidence picks ``s`` from a fixed
    reference axis, so the result is deterministic. Pass ``n1`` and ``n2`` to
    also get the transmitted direction (:func:`refract_direction`) and basis.
    """
    k = _unit(k_in, "k_in")
    n = _unit(normal, "normal")
    k, n = np.broadcast_arrays(k, n)
    dn = np.sum(k * n, axis=-1, keepdims=True)
    nf = np.where(dn < 0.0, -n, n) + 0.0  # + 0.0: no negative zeros
    cos_i = np.abs(dn)[..., 0]

    kxn = np.cross(k, nf)
    norm = np.linalg.norm(kxn, axis=-1, keepdims=True)
    x_hat = np.array([1.0, 0.0, 0.0])
    y_hat = np.array([0.0, 1.0, 0.0])
    ref = np.where(np.abs(nf[..., :1]) > 0.9, y_hat, x_hat)
    fallback = np.cross(ref, nf)
    fallback /= np.linalg.norm(fallback, axis=-1, keepdims=True)
    normal_inc = norm < _NORMAL_INCIDENCE_TOL
    s = np.where(normal_inc, fallback, kxn / np.where(normal_inc, 1.0, norm))

    k_r = k - 2.0 * dn * n
    p_in = np.cross(s, k)
    p_r = np.cross(s, k_r)
    if n1 is None or n2 is None:
        k_t = p_t = tir = None
    else:
        k_t, tir = refract_direction(k, n, n1, n2)
        p_t = np.cross(s, k_t)
    return InterfaceBasis(
        s=s,
        p_in=p_in,
        p_reflected=p_r,
        p_transmitted=p_t,
        k_in=k,
        k_reflected=k_r,
        k_transmitted=k_t,
        normal_forward=nf,
        cos_i=cos_i,
        tir=tir,
    )
