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
"""

from __future__ import annotations

import numpy as np
from numba import njit

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


@njit(cache=True, inline="always")
def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@njit(cache=True, inline="always")
def _dfade(t):
    return 30.0 * t * t * (t - 1.0) * (t - 1.0)


@njit(cache=True, inline="always")
def _dot(g, k, x, y, z):
    return g[k, 0] * x + g[k, 1] * y + g[k, 2] * z


@njit(cache=True, inline="always")
def _blend(g, c, i000, i100, i010, i110, i001, i101, i011, i111, u, v, w):
    g0, g1, g2, g3 = g[i000, c], g[i100, c], g[i010, c], g[i110, c]
    g4, g5, g6, g7 = g[i001, c], g[i101, c], g[i011, c], g[i111, c]
    return (g0 + u * (g1 - g0) + v * (g2 - g0) + w * (g4 - g0) + u * v * (g0 - g1 - g2 + g3)
            + v * w * (g0 - g2 - g4 + g6) + w * u * (g0 - g1 - g4 + g5)
            + u * v * w * (-g0 + g1 + g2 - g3 + g4 - g5 - g6 + g7))


@njit(cache=True)
def noise_grad(perm, g, x, y, z):
    """(value, d/dx, d/dy, d/dz) of the noise at (x, y, z) (lattice units)."""
    xf, yf, zf = np.floor(x), np.floor(y), np.floor(z)
    xi, yi, zi = int(xf) & 255, int(yf) & 255, int(zf) & 255
    fx, fy, fz = x - xf, y - yf, z - zf
    u, v, w = _fade(fx), _fade(fy), _fade(fz)
    du, dv, dw = _dfade(fx), _dfade(fy), _dfade(fz)
    a = perm[xi] + yi
    aa, ab = perm[a] + zi, perm[a + 1] + zi
    b = perm[xi + 1] + yi
    ba, bb = perm[b] + zi, perm[b + 1] + zi
    i000, i100, i010, i110 = perm[aa] & 15, perm[ba] & 15, perm[ab] & 15, perm[bb] & 15
    i001, i101, i011, i111 = perm[aa + 1] & 15, perm[ba + 1] & 15, perm[ab + 1] & 15, perm[bb + 1] & 15
    n000 = _dot(g, i000, fx, fy, fz)
    n100 = _dot(g, i100, fx - 1.0, fy, fz)
    n010 = _dot(g, i010, fx, fy - 1.0, fz)
    n110 = _dot(g, i110, fx - 1.0, fy - 1.0, fz)
    n001 = _dot(g, i001, fx, fy, fz - 1.0)
    n101 = _dot(g, i101, fx - 1.0, fy, fz - 1.0)
    n011 = _dot(g, i011, fx, fy - 1.0, fz - 1.0)
    n111 = _dot(g, i111, fx - 1.0, fy - 1.0, fz - 1.0)
    k1 = n100 - n000
    k2 = n010 - n000
    k3 = n001 - n000
    k4 = n000 - n100 - n010 + n110
    k5 = n000 - n010 - n001 + n011
    k6 = n000 - n100 - n001 + n101
    k7 = -n000 + n100 + n010 - n110 + n001 - n101 - n011 + n111
    value = n000 + k1 * u + k2 * v + k3 * w + k4 * u * v + k5 * v * w + k6 * w * u + k7 * u * v * w
    # the blend of the corner gradients, then the fade derivatives' terms
    bx = _blend(g, 0, i000, i100, i010, i110, i001, i101, i011, i111, u, v, w)
    by = _blend(g, 1, i000, i100, i010, i110, i001, i101, i011, i111, u, v, w)
    bz = _blend(g, 2, i000, i100, i010, i110, i001, i101, i011, i111, u, v, w)
    gx = bx + du * (k1 + k4 * v + k6 * w + k7 * v * w)
    gy = by + dv * (k2 + k4 * u + k5 * w + k7 * u * w)
    gz = bz + dw * (k3 + k5 * v + k6 * u + k7 * u * v)
    return value, gx, gy, gz


@njit(cache=True)
def noise_value(perm, g, x, y, z):
    """The noise at (x, y, z) without its gradient (the first half of :func:`noise_grad`)."""
    xf, yf, zf = np.floor(x), np.floor(y), np.floor(z)
    xi, yi, zi = int(xf) & 255, int(yf) & 255, int(zf) & 255
    fx, fy, fz = x - xf, y - yf, z - zf
    u, v, w = _fade(fx), _fade(fy), _fade(fz)
    a = perm[xi] + yi
    aa, ab = perm[a] + zi, perm[a + 1] + zi
    b = perm[xi + 1] + yi
    ba, bb = perm[b] + zi, perm[b + 1] + zi
    x00 = _dot(g, perm[aa] & 15, fx, fy, fz) + u * (_dot(g, perm[ba] & 15, fx - 1.0, fy, fz)
                                                   - _dot(g, perm[aa] & 15, fx, fy, fz))
    x10 = _dot(g, perm[ab] & 15, fx, fy - 1.0, fz) + u * (_dot(g, perm[bb] & 15, fx - 1.0, fy - 1.0, fz)
                                                         - _dot(g, perm[ab] & 15, fx, fy - 1.0, fz))
    x01 = _dot(g, perm[aa + 1] & 15, fx, fy, fz - 1.0) + u * (_dot(g, perm[ba + 1] & 15, fx - 1.0, fy, fz - 1.0)
                                                             - _dot(g, perm[aa + 1] & 15, fx, fy, fz - 1.0))
    x11 = _dot(g, perm[ab + 1] & 15, fx, fy - 1.0, fz - 1.0) + u * (
        _dot(g, perm[bb + 1] & 15, fx - 1.0, fy - 1.0, fz - 1.0) - _dot(g, perm[ab + 1] & 15, fx, fy - 1.0, fz - 1.0))
    y0 = x00 + v * (x10 - x00)
    y1 = x01 + v * (x11 - x01)
    return y0 + w * (y1 - y0)


@njit(cache=True)
def noise_field(perm, g, points):
    """(N, 4): value and gradient at each of the points (N, 3) (lattice units)."""
    out = np.empty((points.shape[0], 4))
    for i in range(points.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = noise_grad(perm, g, points[i, 0], points[i, 1], points[i, 2])
    return out
