"""Dielectric properties of human tissues: the Gabriel 1996 four-term Cole-Cole model.

Source
------
S. Gabriel, R. W. Lau, C. Gabriel, "The dielectric properties of biological
tissues: III. Parametric models for the dielectric spectrum of tissues",
Phys. Med. Biol. 41 (1996) 2271-2293, Table 1 / the full parameter table of
Appendix C of report AL/OE-TR-1996-0037 (the same table is used by the
IFAC-CNR "Dielectric properties of body tissues" calculator and by the IT'IS
Foundation tissue database in its "Gabriel" dispersive model). The model,
with time dependence ``exp(+j w t)``, is (paper Eq. 3)::

    eps*(w) = ef + sum_{n=1..4} del_n / (1 + (j w tau_n)^(1 - alf_n)) + sig / (j w eps0)

and what databases tabulate is ``eps_r' = Re eps*`` and the effective
conductivity ``sigma = -Im(eps*) w eps0`` (ionic plus dielectric loss). The
model is fitted over 10 Hz - 20 GHz; outside that range this module raises
:class:`~raytrace.errors.FrequencyOutOfRangeError` instead of extrapolating.
Parameter units in the table below: tau1 in ps, tau2 in ns, tau3 in us,
tau4 in ms, sig in S/m.

Fat
---
Gabriel gives two fat parameter sets: "not infiltrated" (eps_r 5.58, sigma
0.041 S/m at 402 MHz) and "average infiltrated" (eps_r 11.62, sigma 0.081 S/m).
The two reference databases disagree on which one is "fat": the IFAC-CNR
calculator's "Fat" is the not-infiltrated set, while the IT'IS Foundation
database maps "Fat" and "SAT" (subcutaneous adipose tissue) of its anatomical
models to the average-infiltrated set (its exports give 11.67 at 400 MHz for
both). The default torso uses :data:`DEFAULT_FAT` = ``"fat_average_infiltrated"``:
real subcutaneous and visceral fat is perfused and crossed by connective septa
and vessels, the IT'IS/Virtual Population models that most in-body channel
studies build on use it, and it is the more lossy (hence conservative for link
budgets) of the two. The non-infiltrated set stays available by name for users
reproducing layered-model papers that use it; it roughly halves the fat
permittivity and so strengthens the fat/muscle reflections.

``air`` is vacuum: relative permittivity 1 and conductivity 0 at every
frequency in the valid range.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from raytrace.errors import FrequencyOutOfRangeError, UnknownTissueError

__all__ = [
    "DEFAULT_FAT",
    "Dielectric",
    "FREQUENCY_MAX_HZ",
    "FREQUENCY_MIN_HZ",
    "TISSUE_NAMES",
    "complex_relative_permittivity",
    "dielectric",
]

#: Vacuum permittivity (CODATA 2018), F/m. Duplicated from :mod:`raytrace.physics.em`
#: on purpose so that this module stays importable on its own.
_EPS0: Final[float] = 8.8541878128e-12

#: Validity range of the Gabriel 1996 parametric model (paper, section 1/4).
FREQUENCY_MIN_HZ: Final[float] = 10.0
FREQUENCY_MAX_HZ: Final[float] = 20e9

_RANGE_SLACK: Final[float] = 1e-9

#: Fat parameter set used by the default torso (see the module docstring).
DEFAULT_FAT: Final[str] = "fat_average_infiltrated"

# Gabriel 1996 Appendix C. Columns:
# ef, del1, tau1 (ps), alf1, del2, tau2 (ns), alf2, sig (S/m),
# del3, tau3 (us), alf3, del4, tau4 (ms), alf4
_GABRIEL_1996: Final[dict[str, tuple[float, ...]]] = {
    "skin_dry": (4.0, 32.0, 7.234, 0.0, 1100.0, 32.481, 0.2, 0.0002, 0.0, 159.155, 0.2, 0.0, 15.915, 0.2),
    "skin_wet": (4.0, 39.0, 7.958, 0.1, 280.0, 79.577, 0.0, 0.0004, 3e4, 1.592, 0.16, 3e4, 1.592, 0.2),
    "fat_not_infiltrated": (2.5, 3.0, 7.958, 0.2, 15.0, 15.915, 0.1, 0.01, 3.3e4, 159.155, 0.05, 1e7, 7.958, 0.01),
    "fat_average_infiltrated": (2.5, 9.0, 7.958, 0.2, 35.0, 15.915, 0.1, 0.035, 3.3e4, 159.155, 0.05, 1e7, 15.915,
                                0.01),
    "muscle": (4.0, 50.0, 7.234, 0.1, 7000.0, 353.678, 0.1, 0.2, 1.2e6, 318.310, 0.1, 2.5e7, 2.274, 0.0),
    "stomach": (4.0, 60.0, 7.958, 0.1, 2000.0, 79.577, 0.1, 0.5, 1e5, 159.155, 0.2, 4e7, 15.915, 0.0),
    "small_intestine": (4.0, 50.0, 7.958, 0.1, 1e4, 159.155, 0.1, 0.5, 5e5, 159.155, 0.2, 4e7, 15.915, 0.0),
    "colon": (4.0, 50.0, 7.958, 0.1, 3000.0, 159.155, 0.2, 0.01, 1e5, 159.155, 0.2, 4e7, 1.592, 0.0),
    "liver": (4.0, 39.0, 8.842, 0.1, 6000.0, 530.516, 0.2, 0.02, 5e4, 22.736, 0.2, 3e7, 15.915, 0.05),
    "kidney": (4.0, 47.0, 7.958, 0.1, 3500.0, 198.944, 0.22, 0.05, 2.5e5, 79.577, 0.22, 3e7, 4.547, 0.0),
    "spleen": (4.0, 48.0, 7.958, 0.1, 2500.0, 63.662, 0.15, 0.03, 2e5, 265.258, 0.25, 5e7, 6.366, 0.0),
    "heart": (4.0, 50.0, 7.958, 0.1, 1200.0, 159.155, 0.05, 0.05, 4.5e5, 72.343, 0.22, 2.5e7, 4.547, 0.0),
    "lung_inflated": (2.5, 18.0, 7.958, 0.1, 500.0, 63.662, 0.1, 0.03, 2.5e5, 159.155, 0.2, 4e7, 7.958, 0.0),
    "lung_deflated": (4.0, 45.0, 7.958, 0.1, 1000.0, 159.155, 0.1, 0.2, 5e5, 159.155, 0.2, 1e7, 15.915, 0.0),
    "bone_cortical": (2.5, 10.0, 13.263, 0.2, 180.0, 79.577, 0.2, 0.02, 5000.0, 159.155, 0.2, 1e5, 15.915, 0.0),
    "bone_cancellous": (2.5, 18.0, 13.263, 0.22, 300.0, 79.577, 0.25, 0.07, 2e4, 159.155, 0.2, 2e7, 15.915, 0.0),
    "bone_marrow_infiltrated": (2.5, 9.0, 14.469, 0.2, 80.0, 15.915, 0.1, 0.1, 1e4, 1591.549, 0.1, 2e6, 15.915, 0.1),
    "bone_marrow_not_infiltrated": (2.5, 3.0, 7.958, 0.2, 25.0, 15.915, 0.1, 0.0005, 5000.0, 1591.549, 0.1, 2e6,
                                    15.915, 0.1),
    "blood": (4.0, 56.0, 8.377, 0.1, 5200.0, 132.629, 0.1, 0.7, 0.0, 159.155, 0.2, 0.0, 15.915, 0.0),
    "gall_bladder_bile": (4.0, 66.0, 7.579, 0.05, 50.0, 1.592, 0.0, 1.4, 0.0, 159.155, 0.2, 0.0, 15.915, 0.2),
    "gall_bladder": (4.0, 55.0, 7.579, 0.05, 40.0, 1.592, 0.0, 0.9, 1000.0, 159.155, 0.2, 1e4, 15.915, 0.0),
    "bladder": (2.5, 16.0, 8.842, 0.1, 400.0, 159.155, 0.1, 0.2, 1e5, 159.155, 0.2, 1e7, 15.915, 0.0),
    "cartilage": (4.0, 38.0, 13.263, 0.15, 2500.0, 144.686, 0.15, 0.15, 1e5, 318.310, 0.1, 4e7, 15.915, 0.0),
    "aorta": (4.0, 40.0, 8.842, 0.1, 50.0, 3.183, 0.1, 0.25, 1e5, 159.155, 0.2, 1e7, 1.592, 0.0),
    "tendon": (4.0, 42.0, 12.243, 0.1, 60.0, 6.366, 0.1, 0.25, 6e4, 318.310, 0.22, 2e7, 1.326, 0.0),
    "nerve": (4.0, 26.0, 7.958, 0.1, 500.0, 106.103, 0.15, 0.006, 7e4, 15.915, 0.2, 4e7, 15.915, 0.0),
}

#: Every tissue name accepted by :func:`dielectric`, in table order, ``air`` last.
TISSUE_NAMES: Final[tuple[str, ...]] = (*_GABRIEL_1996.keys(), "air")

# Parameters as arrays (one row per tissue) in SI: ef, del[4], tau_s[4], alf[4], sig.
_TAU_UNIT_S: Final[np.ndarray] = np.array([1e-12, 1e-9, 1e-6, 1e-3])


def _params(name: str) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, float]:
    p = _GABRIEL_1996[name]
    ef = p[0]
    delta = np.array([p[1], p[4], p[8], p[11]])
    tau_s = np.array([p[2], p[5], p[9], p[12]]) * _TAU_UNIT_S
    alf = np.array([p[3], p[6], p[10], p[13]])
    sig = p[7]
    return ef, delta, tau_s, alf, sig


@dataclass(frozen=True)
class Dielectric:
    """Relative permittivity and effective conductivity of a medium at given frequencies.

    Scalars when built from a scalar frequency, numpy arrays (same shape as the
    frequency) otherwise. ``conductivity_s_per_m`` is the effective
    conductivity (ionic plus dielectric loss) as tabulated by the IFAC/IT'IS
    databases, i.e. ``sigma = w eps0 eps''``.
    """

    relative_permittivity: float | np.ndarray
    conductivity_s_per_m: float | np.ndarray
    frequency_hz: float | np.ndarray

    @property
    def complex_relative_permittivity(self) -> complex | np.ndarray:
        """``eps' - j sigma / (w eps0)`` (time dependence ``exp(+j w t)``)."""
        w = 2.0 * np.pi * np.asarray(self.frequency_hz, dtype=float)
        eps = np.asarray(self.relative_permittivity, dtype=float) - 1j * (
            np.asarray(self.conductivity_s_per_m, dtype=float) / (w * _EPS0)
        )
        return complex(eps) if eps.ndim == 0 else eps

    @property
    def loss_tangent(self) -> float | np.ndarray:
        """``tan(delta) = eps'' / eps' = sigma / (w eps0 eps')``."""
        w = 2.0 * np.pi * np.asarray(self.frequency_hz, dtype=float)
        tan_d = np.asarray(self.conductivity_s_per_m, dtype=float) / (
            w * _EPS0 * np.asarray(self.relative_permittivity, dtype=float)
        )
        return float(tan_d) if tan_d.ndim == 0 else tan_d


def _check_name(name: object) -> str:
    if not isinstance(name, str) or name not in TISSUE_NAMES:
        raise UnknownTissueError(
            f"unknown tissue {name!r}; known tissues are: {', '.join(TISSUE_NAMES)}",
            field="tissue",
        )
    return name


def _check_frequency(frequency_hz: float | np.ndarray) -> np.ndarray:
    try:
        f = np.asarray(frequency_hz, dtype=float)
    except (TypeError, ValueError) as exc:
        raise FrequencyOutOfRangeError(
            f"frequency must be a real number in hertz, got {frequency_hz!r}",
            field="frequency_hz",
        ) from exc
    valid_range = "the Gabriel 1996 tissue model is valid from 10 Hz to 20 GHz (1e1 to 2e10 Hz)"
    if f.size == 0:
        raise FrequencyOutOfRangeError(f"no frequency given; {valid_range}", field="frequency_hz")
    if not np.all(np.isfinite(f)):
        raise FrequencyOutOfRangeError(
            f"frequency must be finite (got NaN or infinity); {valid_range}", field="frequency_hz"
        )
    # 1e-9 relative slack so that e.g. np.logspace(1, log10(20e9)) round-off is accepted;
    # that is far below any physical extrapolation.
    bad = (f < FREQUENCY_MIN_HZ * (1.0 - _RANGE_SLACK)) | (f > FREQUENCY_MAX_HZ * (1.0 + _RANGE_SLACK))
    if np.any(bad):
        first = float(f[bad].flat[0])
        raise FrequencyOutOfRangeError(
            f"frequency {first:g} Hz is out of range: {valid_range}", field="frequency_hz"
        )
    return f


def _cole_cole(name: str, f: np.ndarray) -> np.ndarray:
    """Complex relative permittivity eps' - j eps'' of Gabriel 1996 Eq. 3 (vectorised)."""
    if name == "air":
        return np.ones_like(f, dtype=complex)
    ef, delta, tau_s, alf, sig = _params(name)
    w = 2.0 * np.pi * f[..., np.newaxis]  # broadcast over the four dispersion terms
    jwt = (1j * w * tau_s) ** (1.0 - alf)
    eps = ef + np.sum(delta / (1.0 + jwt), axis=-1) + sig / (1j * w[..., 0] * _EPS0)
    return eps


def _cole_cole_derivative(name: str, f: np.ndarray) -> np.ndarray:
    """``d eps / d w`` of :func:`_cole_cole`, term by term (analytic, docs/science.md (S23)):
    with ``u = (j w tau)^(1 - alpha)``, ``du/dw = (1 - alpha) u / w``, so a dispersion term
    ``D / (1 + u)`` contributes ``-D (1 - alpha) u / (w (1 + u)^2)``, and the conductivity
    term ``sigma / (j w eps0)`` contributes ``-sigma / (j w^2 eps0)`` [s/rad]."""
    if name == "air":
        return np.zeros_like(f, dtype=complex)
    ef, delta, tau_s, alf, sig = _params(name)
    w = 2.0 * np.pi * f[..., np.newaxis]
    u = (1j * w * tau_s) ** (1.0 - alf)
    terms = -delta * (1.0 - alf) * u / (w * (1.0 + u) ** 2)
    w0 = w[..., 0]
    return np.sum(terms, axis=-1) - sig / (1j * w0 * w0 * _EPS0)


def complex_relative_permittivity_derivative(name: str, frequency_hz: float | np.ndarray) -> complex | np.ndarray:
    """``d eps / d w`` [s/rad] of a tissue's complex relative permittivity (Gabriel 1996 Eq. 3
    differentiated analytically, docs/science.md (S23)); what the group index needs. Errors
    as :func:`complex_relative_permittivity`."""
    name = _check_name(name)
    f = _check_frequency(frequency_hz)
    d = _cole_cole_derivative(name, f)
    return complex(d) if d.ndim == 0 else d


def complex_relative_permittivity(name: str, frequency_hz: float | np.ndarray) -> complex | np.ndarray:
    """Complex relative permittivity ``eps' - j sigma/(w eps0)`` of a tissue (Gabriel 1996 Eq. 3).

    Raises :class:`UnknownTissueError` (field ``tissue``) for an unknown name and
    :class:`FrequencyOutOfRangeError` (field ``frequency_hz``) outside 10 Hz - 20 GHz
    or for a non-finite frequency. Returns a complex scalar for a scalar
    frequency, a complex array of the frequency's shape otherwise.
    """
    name = _check_name(name)
    f = _check_frequency(frequency_hz)
    eps = _cole_cole(name, f)
    return complex(eps) if eps.ndim == 0 else eps


def dielectric(name: str, frequency_hz: float | np.ndarray) -> Dielectric:
    """Relative permittivity and effective conductivity of a tissue (Gabriel 1996 Eq. 3).

    ``relative_permittivity = Re eps*`` and ``conductivity_s_per_m = -Im(eps*) w eps0``,
    the quantities tabulated by the IFAC-CNR and IT'IS databases. Vectorised over
    ``frequency_hz``; a scalar frequency gives Python floats. Errors as
    :func:`complex_relative_permittivity`.
    """
    name = _check_name(name)
    f = _check_frequency(frequency_hz)
    eps = _cole_cole(name, f)
    eps_r = eps.real
    sigma = -eps.imag * 2.0 * np.pi * f * _EPS0 + 0.0  # + 0.0: air gives 0.0, not -0.0
    if f.ndim == 0:
        return Dielectric(float(eps_r), float(sigma), float(f))
    return Dielectric(eps_r, sigma, f.copy())
