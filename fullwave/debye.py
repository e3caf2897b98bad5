"""A medium's complex permittivity as a few Debye poles over a band: what an FDTD solver runs.

FDTD codes (gprMax's ``#add_dispersion_debye``) integrate Debye poles in the time domain,
not the Cole-Cole model of the tissues (:mod:`raytrace.physics.tissues`). Over a band
``[f_lo, f_hi]`` we fit (time dependence ``exp(+j w t)``)::

    eps(w) ~ eps_inf + sum_k d_k / (1 + j w tau_k) - j sigma / (w eps0)

with ``eps_inf >= 1``, ``d_k >= 0``, ``sigma >= 0`` (a passive, causal medium): for fixed
relaxation times the model is linear in ``(eps_inf, d_k, sigma)`` and solved by non-negative
least squares on the real and imaginary parts, each sample weighted by ``1 / |eps|``; the
``log tau_k`` are then optimised (Nelder-Mead) on that residual. The fit's worst relative
error ``max |eps_fit - eps| / |eps|`` over the band is reported with it, and the tracer-side
comparison (:mod:`fullwave.compare`) uses the FDTD's own (fitted) medium only through the
field it computes: the error shows up as a gain / phase bias the report lists beside it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize, nnls

from raytrace.physics.em import EPS0
from raytrace.physics.materials import Material

#: Frequencies per fit.
SAMPLES = 64


@dataclass(frozen=True)
class DebyeFit:
    """``eps_inf + sum d_k / (1 + j w tau_k) - j sigma / (w eps0)`` over ``band_hz``."""

    eps_inf: float
    sigma_s_per_m: float
    delta_eps: tuple[float, ...]
    tau_s: tuple[float, ...]
    band_hz: tuple[float, float]
    max_relative_error: float

    def permittivity(self, frequency_hz: np.ndarray | float) -> np.ndarray:
        w = 2.0 * np.pi * np.asarray(frequency_hz, float)
        out = self.eps_inf - 1j * self.sigma_s_per_m / (w * EPS0) + 0j
        for d, t in zip(self.delta_eps, self.tau_s):
            out = out + d / (1.0 + 1j * w * t)
        return out


def _design(w: np.ndarray, tau: np.ndarray, weight: np.ndarray) -> np.ndarray:
    cols = [np.ones_like(w) + 0j] + [1.0 / (1.0 + 1j * w * t) for t in tau] + [-1j / (w * EPS0)]
    a = np.stack(cols, axis=1) * weight[:, None]
    return np.concatenate([a.real, a.imag], axis=0)


def _solve(w, eps, tau, weight):
    a = _design(w, tau, weight)
    b = np.concatenate([(eps * weight).real, (eps * weight).imag])
    # eps_inf >= 1: fit eps_inf - 1 >= 0
    b = b - a[:, 0]
    x, _ = nnls(a, b)
    x[0] += 1.0
    return x, np.linalg.norm(a @ x - (b + a[:, 0]))


def fit_debye(material: Material, band_hz: tuple[float, float], poles: int = 2) -> DebyeFit:
    """Fit ``poles`` Debye poles plus a static conductivity to ``material`` over ``band_hz``."""
    f_lo, f_hi = float(band_hz[0]), float(band_hz[1])
    if not 0.0 < f_lo < f_hi:
        raise ValueError(f"band must be 0 < f_lo < f_hi, got {band_hz}")
    f = np.geomspace(f_lo, f_hi, SAMPLES)
    w = 2.0 * np.pi * f
    eps = np.asarray(material.complex_relative_permittivity(f), complex)
    weight = 1.0 / np.abs(eps)
    if material.tissue is None or poles == 0:  # constant eps' and sigma: exact without poles
        eps_r = float(material.relative_permittivity)
        return DebyeFit(eps_r, float(material.conductivity_s_per_m), (), (), (f_lo, f_hi), 0.0)
    f_c = np.sqrt(f_lo * f_hi)
    # starting relaxation times: one pole well above the band (the tissues' gamma/beta tail), the rest below
    start = np.log(np.concatenate([[1.0 / (2 * np.pi * f_c * 20.0)],
                                   1.0 / (2 * np.pi * f_c / 10.0 ** np.arange(1, poles))]))

    def cost(log_tau):
        return _solve(w, eps, np.exp(log_tau), weight)[1]

    best = minimize(cost, start, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-12, "maxiter": 4000})
    tau = np.exp(best.x)
    x, _ = _solve(w, eps, tau, weight)
    order = np.argsort(tau)
    fit = DebyeFit(eps_inf=float(x[0]), sigma_s_per_m=float(x[-1]), delta_eps=tuple(float(v) for v in x[1:-1][order]),
                   tau_s=tuple(float(t) for t in tau[order]), band_hz=(f_lo, f_hi), max_relative_error=0.0)
    err = np.abs(fit.permittivity(f) - eps) / np.abs(eps)
    return DebyeFit(fit.eps_inf, fit.sigma_s_per_m, fit.delta_eps, fit.tau_s, (f_lo, f_hi), float(err.max()))
