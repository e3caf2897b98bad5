"""Solid (3-D) gradient noise with its analytic gradient, compiled: the raw material of the
procedural mucosa (:mod:`vision.mucosa`).

Perlin's improved noise (K. Perlin, "Improving noise", SIGGRAPH 2002): a pseudo-random unit-cube
lattice, at every corner a gradient from the 12 cube-edge directions picked by a seeded
permutation table, the corner's linear ramps blended with the quintic fade
6t^5 - 15t^4 + 10t^3 (C2-continuous, so shading from the gradient has no creases). The value
lies in about [-1, 1], is 0 on every lattice point and has no period shorter than 256 cells.
The gradient is exact (the derivative of the blend, as in I. Quilez's "gradient noise
derivatives"): bump mapping needs it at no finite-difference cost.

Defined in 3-D, the noise is a property of the SURFACE POINT, not of the pixel: the same wall
point has the same texture in every frame, whatever the pose.

The compiled noise (``noise_grad``, ``noise_value``, ``noise_field``) lives with the package's other
numba code in :mod:`vision.kernels`; this module holds its tables.
"""

from __future__ import annotations

import numpy as np

from .kernels import noise_field, noise_grad, noise_value

#: Perlin's 12 edge gradients, padded to 16 by repeating four (his improved-noise table).
_GRADIENTS = np.array([
    [1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0], [1, 0, 1], [-1, 0, 1], [1, 0, -1], [-1, 0, -1],
    [0, 1, 1], [0, -1, 1], [0, 1, -1], [0, -1, -1], [1, 1, 0], [0, -1, 1], [-1, 1, 0], [0, -1, -1]],
    dtype=np.float64)


def permutation(seed: int) -> np.ndarray:
    """The doubled permutation table (512,) of a seed."""
    p = np.random.default_rng(seed).permutation(256).astype(np.int64)
    return np.concatenate([p, p])


def gradients() -> np.ndarray:
    return _GRADIENTS


__all__ = ["gradients", "noise_field", "noise_grad", "noise_value", "permutation"]
