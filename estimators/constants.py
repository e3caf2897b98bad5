"""Physical constants and the velocity assumption used to turn delays into distances."""

from __future__ import annotations

import math

import scipy.constants

from ._checks import relative_permittivity as _check_eps

SPEED_OF_LIGHT_M_PER_S: float = scipy.constants.c
"""c, exact (SI)."""

DEFAULT_RELATIVE_PERMITTIVITY = 27.9
"""Average torso relative permittivity used for ranging in the thesis (Sec 4.4.1, 5.4)."""


def velocity_m_per_s(relative_permittivity: float = DEFAULT_RELATIVE_PERMITTIVITY) -> float:
    """Propagation speed v = c / sqrt(eps_r) (thesis Eq 4.17 / 5.1); 0.568e8 m/s at eps_r 27.9."""
    eps = _check_eps(relative_permittivity)
    return SPEED_OF_LIGHT_M_PER_S / math.sqrt(eps)
