"""What a channel computation is asked: antennas (and, next, the channel spec)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np


@dataclass(frozen=True)
class Antenna:
    """An antenna: position, polarization (unit vector) and pattern.

    An isotropic antenna radiates unit field along the projection of its
    polarization onto the plane normal to the ray; a ``dipole`` also weights
    by sin(theta) from its axis (= the polarization). A receiver's response is
    the projection of the arriving field onto its polarization.
    """

    position_m: np.ndarray
    name: str = ""
    polarization: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    pattern: Literal["isotropic", "dipole"] = "isotropic"
