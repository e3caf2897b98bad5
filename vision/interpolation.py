"""Bicubic (cubic-convolution) interpolation and the similarity warp of a frame (thesis Eq 3.5-3.9).

A grey level between pixels, at row i + u and column j + v (i, j integers, 0 <= u, v < 1), is
(Eq 3.5-3.8)

    f(i + u, j + v) = A B C,   A = [S(u + 1)  S(u)  S(u - 1)  S(u - 2)],
                               B = f(i - 1 .. i + 2, j - 1 .. j + 2)   (4 x 4 neighbourhood),
                               C = [S(v + 1)  S(v)  S(v - 1)  S(v - 2)]^T,

with the cubic-convolution kernel of Keys (1981, "Cubic convolution interpolation for digital
image processing", IEEE Trans. ASSP 29(6)):

    S(x) = (a + 2)|x|^3 - (a + 3)|x|^2 + 1          |x| < 1
           a|x|^3 - 5a|x|^2 + 8a|x| - 4a            1 <= |x| < 2
           0                                       2 <= |x|

The thesis' Eq 3.9, |x|^3 - 2|x|^2 + 1 and -|x|^3 + 5|x|^2 - 8|x| + 4, is this kernel with
``a = -1`` (:data:`THESIS_A`). What each ``a`` reproduces EXACTLY (integer samples of a
polynomial interpolated back without error; derived from the weights above, checked in
tests/vision/test_vision_interpolation.py):

* every ``a``: constants (the weights sum to 1);
* ``a = -1/2`` (:data:`KEYS_A`) only: also linear and quadratic polynomials; a cubic c x^3 is
  off by exactly c u (1 - u)(1 - 2u) (|error| <= 0.096 c), Keys' third-order accuracy;
* ``a = -1`` (the thesis): not even a ramp: f = x comes back as x - (2a + 1) u (1 - u)(1 - 2u),
  an error up to 0.096 pixel of slope.

No 4-tap cubic-convolution kernel reproduces cubics; "bicubic" here is the cubic convolution
the thesis' text describes. Erratum: the thesis' listing (A.3) interpolates BILINEARLY.

Edges: a sample inside the frame ([0, H - 1] x [0, W - 1], to :data:`EDGE_SLACK_PX`) uses the 4 x 4 neighbourhood with
indices clamped to the frame (edge pixels replicated); a sample outside gets ``fill``, as the
listing sets pixels mapped outside the frame to 0.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import VisionInputError

#: Eq 3.9 of the thesis: the Keys kernel with a = -1.
THESIS_A = -1.0
#: Keys' a = -1/2: the cubic convolution that reproduces quadratics (third-order accurate).
KEYS_A = -0.5
#: Positions this close outside the frame count as on its edge (rounding of cos 90 deg etc.).
EDGE_SLACK_PX = 1e-9


def check_kernel_a(a, field: str = "kernel_a") -> float:
    """The kernel parameter as a float in [-3, 0], else :class:`VisionInputError`."""
    try:
        out = float(a)
    except (TypeError, ValueError):
        raise VisionInputError(f"must be a number, got {a!r}", field) from None
    if not (math.isfinite(out) and -3.0 <= out <= 0.0):
        raise VisionInputError(f"must be in [-3, 0] (Keys' a; -1 thesis, -0.5 Keys), got {a!r}", field)
    return out


def cubic_kernel(x: np.ndarray, a: float = THESIS_A) -> np.ndarray:
    """S(x) of Eq 3.9 (Keys' cubic-convolution kernel with parameter ``a``, module doc)."""
    t = np.abs(np.asarray(x, dtype=float))
    inner = ((a + 2.0) * t - (a + 3.0)) * t * t + 1.0
    outer = ((a * t - 5.0 * a) * t + 8.0 * a) * t - 4.0 * a
    return np.where(t < 1.0, inner, np.where(t < 2.0, outer, 0.0))


def cubic_weights(frac: np.ndarray, a: float = THESIS_A) -> np.ndarray:
    """The four weights [S(u + 1), S(u), S(u - 1), S(u - 2)] of Eq 3.6 / 3.8 for fractional
    offsets ``u`` in [0, 1): shape (4, *u.shape)."""
    u = np.asarray(frac, dtype=float)
    return np.stack([cubic_kernel(u + 1.0, a), cubic_kernel(u, a), cubic_kernel(u - 1.0, a),
                     cubic_kernel(u - 2.0, a)])


def interpolate(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, a: float = THESIS_A,
                fill: float = 0.0) -> np.ndarray:
    """Grey levels of a (H, W) frame at fractional (row, col) positions by Eq 3.5-3.8 (module doc:
    edges, ``fill``), vectorised over the positions (any common shape)."""
    img = np.asarray(image, dtype=float)
    h, w = img.shape
    r = np.asarray(rows, dtype=float)
    c = np.asarray(cols, dtype=float)
    r, c = np.broadcast_arrays(r, c)
    e = EDGE_SLACK_PX
    inside = (r >= -e) & (r <= h - 1 + e) & (c >= -e) & (c <= w - 1 + e)
    rs, cs = np.where(inside, np.clip(r, 0.0, h - 1), 0.0), np.where(inside, np.clip(c, 0.0, w - 1), 0.0)
    i0, j0 = np.floor(rs), np.floor(cs)
    wr, wc = cubic_weights(rs - i0, a), cubic_weights(cs - j0, a)  # A and C^T
    i0, j0 = i0.astype(np.int64), j0.astype(np.int64)
    out = np.zeros(r.shape)
    for m in range(4):
        ri = np.clip(i0 + (m - 1), 0, h - 1)
        row_sum = np.zeros(r.shape)
        for n in range(4):
            row_sum += wc[n] * img[ri, np.clip(j0 + (n - 1), 0, w - 1)]  # (B C) row m
        out += wr[m] * row_sum
    return np.where(inside, out, fill)


def frame_center(shape: tuple[int, int]) -> tuple[float, float]:
    """The centre (row, col) of a frame: ((H - 1) / 2, (W - 1) / 2), the optical axis of a
    centred fisheye."""
    return (shape[0] - 1) / 2.0, (shape[1] - 1) / 2.0


def similarity_matrix(rotation_deg: float, scale: float) -> np.ndarray:
    """The 2 x 2 matrix, acting on (row, col) offsets from the centre, that rotates frame
    content by ``rotation_deg`` COUNTER-CLOCKWISE as displayed (rows down, columns right) and
    magnifies it by ``scale``: content at offset d appears at offset M d. Vectorised: arrays of
    angles and scales give (..., 2, 2)."""
    t = np.radians(np.asarray(rotation_deg, dtype=float))
    ct, st = np.cos(t), np.sin(t)
    s = np.asarray(scale, dtype=float)
    return np.moveaxis(s * np.array([[ct, -st], [st, ct]]), (0, 1), (-2, -1))


def warp_similarity(image: np.ndarray, rotation_deg: float, scale: float = 1.0,
                    center: tuple[float, float] | None = None, a: float = THESIS_A,
                    fill: float = 0.0) -> np.ndarray:
    """The frame with its content rotated by ``rotation_deg`` (counter-clockwise as displayed)
    and magnified by ``scale`` about ``center`` (default :func:`frame_center`), resampled by
    Eq 3.5-3.9: out(q) = in(c + M^-1 (q - c)), M = :func:`similarity_matrix`. The synthetic
    rotations and scalings of the thesis' evaluation (Section 3.3)."""
    img = np.asarray(image, dtype=float)
    if img.ndim != 2:
        raise VisionInputError(f"must be a grey (H, W) image, got shape {img.shape}", "image")
    if not (math.isfinite(scale) and scale > 0.0):
        raise VisionInputError(f"must be a finite number > 0, got {scale!r}", "scale")
    cr, cc = frame_center(img.shape) if center is None else center
    inv = np.linalg.inv(similarity_matrix(rotation_deg, scale))
    dr = np.arange(img.shape[0], dtype=float)[:, None] - cr
    dc = np.arange(img.shape[1], dtype=float)[None, :] - cc
    rows = cr + inv[0, 0] * dr + inv[0, 1] * dc
    cols = cc + inv[1, 0] * dr + inv[1, 1] * dc
    return interpolate(img, rows, cols, a, fill)
