"""What the capsule's image sensor adds to the scene radiance: vignetting, noise, response.

Applied to a linear RGB frame (radiance times exposure, 1 = full scale), in this order:

1. vignetting: V(r) = 1 - ``vignetting`` (r / R)^2, r the distance from the principal point and
   R the image-circle radius (a smooth fall-off towards the rim of the fisheye circle);
2. shot noise (``full_well_electrons``: photo-electrons at full scale; Poisson, drawn exactly)
   and read noise (``read_noise``: Gaussian standard deviation in full-scale units);
3. the response: clip to [0, 1], then the display gamma (value^(1 / ``gamma``); None: linear);
4. salt-and-pepper noise (``salt_pepper``: the fraction of pixels set to 0 or 1, each with
   probability 1/2, all channels; the transmission errors of the thesis' Fig 3.1);
5. 8-bit quantisation (``quantize_8bit``).

Deterministic: all noise is drawn from ``seed`` (a frame index can be added by the caller).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import VisionInputError


@dataclass(frozen=True)
class SensorModel:
    """Sensor effects (module doc). The default: mild vignetting, gamma 2.2, 8-bit, no noise."""

    vignetting: float = 0.3
    full_well_electrons: float | None = None
    read_noise: float = 0.0
    gamma: float | None = 2.2
    salt_pepper: float = 0.0
    quantize_8bit: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        checks = (("vignetting", 0.0, 1.0), ("read_noise", 0.0, 1.0), ("salt_pepper", 0.0, 1.0))
        for name, lo, hi in checks:
            v = float(getattr(self, name))
            if not (math.isfinite(v) and lo <= v <= hi):
                raise VisionInputError(f"must be in [{lo}, {hi}], got {v!r}", f"sensor.{name}")
        if self.full_well_electrons is not None:
            v = float(self.full_well_electrons)
            if not (math.isfinite(v) and 1.0 <= v <= 1e7):
                raise VisionInputError(f"must be in [1, 1e7] or None, got {v!r}", "sensor.full_well_electrons")
        if self.gamma is not None:
            v = float(self.gamma)
            if not (math.isfinite(v) and 0.2 <= v <= 5.0):
                raise VisionInputError(f"must be in [0.2, 5] or None, got {v!r}", "sensor.gamma")

    def apply(self, linear: np.ndarray, radius_fraction: np.ndarray, mask: np.ndarray,
              frame_index: int = 0) -> np.ndarray:
        """The sensor's output (S, S, 3) in [0, 1] for a linear frame (S, S, 3); ``radius_fraction``
        (S, S): r / R of every pixel; pixels outside ``mask`` (the image circle) stay 0."""
        rng = np.random.default_rng([int(self.seed), int(frame_index)])
        out = linear * (1.0 - self.vignetting * radius_fraction**2)[..., None]
        if self.full_well_electrons is not None:
            electrons = rng.poisson(np.clip(out, 0.0, None) * self.full_well_electrons)
            out = electrons / self.full_well_electrons
        if self.read_noise > 0.0:
            out = out + rng.normal(0.0, self.read_noise, out.shape)
        out = np.clip(out, 0.0, 1.0)
        if self.gamma is not None:
            out = out ** (1.0 / self.gamma)
        if self.salt_pepper > 0.0:
            hit = rng.random(out.shape[:2]) < self.salt_pepper
            out[hit] = rng.integers(0, 2, int(hit.sum()))[:, None].astype(float)
        if self.quantize_8bit:
            out = np.round(out * 255.0) / 255.0
        out[~mask] = 0.0
        return out
