"""Result dataclasses of the position estimators."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class PositionBound:
    """Cramér-Rao bound on the position (docs/localization.md, "Bounds").

    covariance_m2: (3, 3) inverse Fisher information, position block (nuisance parameters
    such as an unknown velocity eliminated). sigma_m: per-axis standard deviations
    sqrt(diag). rms_m: sqrt(trace), the bound on the 3-D RMS error. gdop / pdop: dilution
    of precision for unit range sigma (pdop: position block; gdop: every parameter, the
    velocity's slowness scaled to metres by the mean range -- equal to pdop when the
    velocity is known).
    """

    covariance_m2: np.ndarray
    sigma_m: np.ndarray
    rms_m: float
    gdop: float
    pdop: float


@dataclass(frozen=True)
class PositionResult:
    """One position fix.

    position_m: the estimate. covariance_m2: its covariance, the inverse Fisher information
    at the estimate (linearised; for the closed-form linear fix, the first-order propagation of
    the range variances through it). residuals_m: measurement minus model, per sensor, in
    metres (delays are converted with the method's velocity; RSS residuals are log-distance
    residuals times the inverted distance). iterations: solver function evaluations (0 for a
    closed form). converged: the solver's own termination test passed. bound: the position
    CRLB at the estimate for the same sensors and sigmas. velocity_m_per_s /
    velocity_sigma_m_per_s: joint-velocity only. cost: the final weighted least-squares cost
    0.5 sum(r_i / sigma_i)^2 (before any robust loss).
    """

    method: str
    position_m: np.ndarray
    covariance_m2: np.ndarray
    residuals_m: np.ndarray
    iterations: int
    converged: bool
    bound: PositionBound
    cost: float
    message: str = ""
    velocity_m_per_s: float | None = None
    velocity_sigma_m_per_s: float | None = None
    extra: dict = field(default_factory=dict, compare=False)

    @property
    def crlb_m(self) -> float:
        """Bound on the 3-D RMS position error, sqrt(trace CRLB) [m]."""
        return self.bound.rms_m

    @property
    def gdop(self) -> float:
        return self.bound.gdop

    @property
    def pdop(self) -> float:
        return self.bound.pdop
