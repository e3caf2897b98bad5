"""Materials: what fills an organ, a Gabriel 1996 tissue or an explicit medium."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from raytrace.errors import PhantomValidationError, UnknownTissueError
from raytrace.physics import em, tissues


@dataclass(frozen=True)
class Material:
    """The dielectric filling of an organ: a Gabriel 1996 tissue by name, or
    an explicit frequency-independent relative permittivity and conductivity.
    """

    tissue: str | None = None
    relative_permittivity: float | None = None
    conductivity_s_per_m: float | None = None

    def __post_init__(self) -> None:
        explicit = self.relative_permittivity is not None
        if (self.tissue is None) == (not explicit):
            raise PhantomValidationError(
                "give either a tissue name or relative_permittivity (+ conductivity_s_per_m)",
                field="material",
            )
        if explicit:
            eps = float(self.relative_permittivity)
            sigma = float(self.conductivity_s_per_m or 0.0)
            if not (np.isfinite(eps) and eps >= 1.0):
                raise PhantomValidationError(
                    f"relative_permittivity must be finite and >= 1, got {eps}",
                    field="relative_permittivity",
                )
            if not (np.isfinite(sigma) and sigma >= 0.0):
                raise PhantomValidationError(
                    f"conductivity_s_per_m must be finite and >= 0, got {sigma}",
                    field="conductivity_s_per_m",
                )
            object.__setattr__(self, "conductivity_s_per_m", sigma)
        else:
            if self.tissue not in tissues.TISSUE_NAMES:
                raise UnknownTissueError(
                    f"unknown tissue {self.tissue!r}; known: {', '.join(tissues.TISSUE_NAMES)}",
                    field="tissue",
                )

    @property
    def label(self) -> str:
        """The tissue name, or ``eps_r=..,sigma=..`` for an explicit medium."""
        if self.tissue is not None:
            return self.tissue
        return f"eps_r={self.relative_permittivity:g},sigma={self.conductivity_s_per_m:g}S/m"

    def complex_relative_permittivity_derivative(self, frequency_hz: float | np.ndarray) -> np.ndarray:
        """``d eps / d w`` [s/rad]: the Cole-Cole model's, analytic, for a tissue; for an explicit
        medium (constant eps' and sigma) that of ``-j sigma / (w eps0)``, ``j sigma / (w^2 eps0)``."""
        if self.tissue is not None:
            return np.asarray(tissues.complex_relative_permittivity_derivative(self.tissue, frequency_hz))
        w = 2.0 * np.pi * np.asarray(frequency_hz, dtype=float)
        return np.asarray(1j * float(self.conductivity_s_per_m) / (w * w * em.EPS0) + 0j)

    def group_index(self, frequency_hz: float | np.ndarray) -> np.ndarray:
        """Group index ``Re(n + w dn/dw)`` (:func:`raytrace.physics.em.group_index`)."""
        return em.group_index(self.complex_relative_permittivity(frequency_hz),
                              self.complex_relative_permittivity_derivative(frequency_hz), frequency_hz)

    def complex_relative_permittivity(self, frequency_hz: float | np.ndarray) -> np.ndarray:
        """eps' - j sigma / (w eps0) (time convention exp(+j w t); Gabriel 1996 Eq. 3
        for tissues, the definition for an explicit medium)."""
        if self.tissue is not None:
            return np.asarray(tissues.complex_relative_permittivity(self.tissue, frequency_hz))
        return np.asarray(
            em.complex_relative_permittivity(
                self.relative_permittivity, self.conductivity_s_per_m, frequency_hz
            )
        )


AIR = Material(relative_permittivity=1.0, conductivity_s_per_m=0.0)
