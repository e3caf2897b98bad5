"""Compiled inner loop of the motion search: warp + quantise + joint histogram in one pass.

Every probe of the search (:mod:`vision.motion`) needs the joint histogram of the reference's
quantised grey levels against the moving frame resampled at the probed rotation and scale. In
numpy that is 16 gathers of the frame plus temporaries per probe (~25 ms for 512 x 512 on this
machine); here one compiled loop per pixel computes the Eq 3.5-3.9 interpolation (the same
weights as :func:`vision.interpolation.cubic_weights`; checked against it in
tests/vision/test_vision_motion.py), quantises and counts. Several probes (a grid) go in one call.

Threads: the kernel releases the GIL; a large call is cut into :data:`~vision.pool.THREADS`
parts (probes, or pixels of one probe), each counted into its own histogram by a worker of
:func:`vision.pool.pool`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .interpolation import EDGE_SLACK_PX
from .pool import THREADS, pool

#: Pixel samples per call below which one thread does it all (a thread hand-off costs ~50 us).
PARALLEL_MIN_SAMPLES = 60_000


@njit(cache=True, inline="always", fastmath=True)
def _inner(t, a):
    return ((a + 2.0) * t - (a + 3.0)) * t * t + 1.0


@njit(cache=True, inline="always", fastmath=True)
def _outer(t, a):
    return ((a * t - 5.0 * a) * t + 8.0 * a) * t - 4.0 * a


@njit(cache=True, nogil=True, fastmath=True)
def _histograms(rows, cols, ref_bins, padded, params, center_r, center_c, radius2, lo, inv_width, bins, a):
    """``padded``: the moving frame with 2 edge-replicated pixels on every side, so pixel (i, j)
    is ``padded[i + 2, j + 2]`` and the 4 x 4 neighbourhood of any sample inside the frame needs
    no index clamping (the edge replication of :func:`vision.interpolation.interpolate`)."""
    n = rows.shape[0]
    slack = EDGE_SLACK_PX
    r_max = padded.shape[0] - 5.0  # H - 1
    c_max = padded.shape[1] - 5.0
    out = np.zeros((params.shape[0], bins, bins), np.int64)
    for k in range(params.shape[0]):
        m00, m01, m10, m11 = params[k, 0], params[k, 1], params[k, 2], params[k, 3]
        hist = out[k]
        for p in range(n):
            dr = rows[p] - center_r
            dc = cols[p] - center_c
            sr = m00 * dr + m01 * dc
            sc = m10 * dr + m11 * dc
            if sr * sr + sc * sc > radius2:
                continue
            r = center_r + sr
            c = center_c + sc
            if r < -slack or c < -slack or r > r_max + slack or c > c_max + slack:
                continue
            r = min(max(r, 0.0), r_max)
            c = min(max(c, 0.0), c_max)
            i0 = int(r)  # floor: r >= 0
            j0 = int(c)
            u = r - i0
            v = c - j0
            # A and C of Eq 3.6 / 3.8
            wr0, wr1, wr2, wr3 = _outer(u + 1.0, a), _inner(u, a), _inner(1.0 - u, a), _outer(2.0 - u, a)
            wc0, wc1, wc2, wc3 = _outer(v + 1.0, a), _inner(v, a), _inner(1.0 - v, a), _outer(2.0 - v, a)
            r0, r1, r2, r3 = padded[i0 + 1], padded[i0 + 2], padded[i0 + 3], padded[i0 + 4]  # rows i0-1 .. i0+2
            j = j0 + 1  # column j0 - 1
            value = (wr0 * (wc0 * r0[j] + wc1 * r0[j + 1] + wc2 * r0[j + 2] + wc3 * r0[j + 3])
                     + wr1 * (wc0 * r1[j] + wc1 * r1[j + 1] + wc2 * r1[j + 2] + wc3 * r1[j + 3])
                     + wr2 * (wc0 * r2[j] + wc1 * r2[j + 1] + wc2 * r2[j + 2] + wc3 * r2[j + 3])
                     + wr3 * (wc0 * r3[j] + wc1 * r3[j + 1] + wc2 * r3[j + 2] + wc3 * r3[j + 3]))
            b = int((value - lo) * inv_width + 1.0) - 1  # floor for the values that matter; < 0 -> bin 0
            if b < 0:
                b = 0
            elif b >= bins:
                b = bins - 1
            hist[ref_bins[p], b] += 1
    return out


@njit(cache=True, nogil=True, fastmath=True)
def _fisheye_histograms(theta, cos_phi, sin_phi, ref_bins, padded, params, center_r, center_c, focal, radius2,
                        lo, inv_width, bins, a):
    """The camera-rotation model of :func:`fisheye_joint_histograms`: per compared pixel its
    angle ``theta`` from the axis [rad] and azimuth (``cos_phi``, ``sin_phi``; x = column,
    y = up); per probe ``params[k]`` = (pre, post, A row-major 3 x 3): the pixel's ray at angle
    pre * theta, turned by A, lands at image radius post * focal * theta' in the other frame."""
    n = theta.shape[0]
    slack = EDGE_SLACK_PX
    r_max = padded.shape[0] - 5.0
    c_max = padded.shape[1] - 5.0
    out = np.zeros((params.shape[0], bins, bins), np.int64)
    for k in range(params.shape[0]):
        pre, post = params[k, 0], params[k, 1]
        a00, a01, a02, a10, a11, a12, a20, a21, a22 = (params[k, 2], params[k, 3], params[k, 4], params[k, 5],
                                                       params[k, 6], params[k, 7], params[k, 8], params[k, 9],
                                                       params[k, 10])
        hist = out[k]
        for p in range(n):
            t = pre * theta[p]
            st = math.sin(t)
            x, y, z = st * cos_phi[p], st * sin_phi[p], math.cos(t)
            x2 = a00 * x + a01 * y + a02 * z
            y2 = a10 * x + a11 * y + a12 * z
            z2 = a20 * x + a21 * y + a22 * z
            rho = math.sqrt(x2 * x2 + y2 * y2)
            radius = post * focal * math.atan2(rho, z2)
            if radius * radius > radius2:
                continue
            if rho > 0.0:
                sc = radius * x2 / rho
                sr = -radius * y2 / rho
            else:
                sc = 0.0
                sr = 0.0
            r = center_r + sr
            c = center_c + sc
            if r < -slack or c < -slack or r > r_max + slack or c > c_max + slack:
                continue
            r = min(max(r, 0.0), r_max)
            c = min(max(c, 0.0), c_max)
            i0 = int(r)
            j0 = int(c)
            u = r - i0
            v = c - j0
            wr0, wr1, wr2, wr3 = _outer(u + 1.0, a), _inner(u, a), _inner(1.0 - u, a), _outer(2.0 - u, a)
            wc0, wc1, wc2, wc3 = _outer(v + 1.0, a), _inner(v, a), _inner(1.0 - v, a), _outer(2.0 - v, a)
            r0, r1, r2, r3 = padded[i0 + 1], padded[i0 + 2], padded[i0 + 3], padded[i0 + 4]
            j = j0 + 1
            value = (wr0 * (wc0 * r0[j] + wc1 * r0[j + 1] + wc2 * r0[j + 2] + wc3 * r0[j + 3])
                     + wr1 * (wc0 * r1[j] + wc1 * r1[j + 1] + wc2 * r1[j + 2] + wc3 * r1[j + 3])
                     + wr2 * (wc0 * r2[j] + wc1 * r2[j + 1] + wc2 * r2[j + 2] + wc3 * r2[j + 3])
                     + wr3 * (wc0 * r3[j] + wc1 * r3[j + 1] + wc2 * r3[j + 2] + wc3 * r3[j + 3]))
            b = int((value - lo) * inv_width + 1.0) - 1
            if b < 0:
                b = 0
            elif b >= bins:
                b = bins - 1
            hist[ref_bins[p], b] += 1
    return out


def pad_frame(frame: np.ndarray) -> np.ndarray:
    """The frame (float64) with 2 edge-replicated pixels on every side, as :func:`_histograms`
    wants it (made once per pyramid level, not per probe)."""
    return np.pad(np.asarray(frame, dtype=np.float64), 2, mode="edge")


def warped_joint_histograms(rows: np.ndarray, cols: np.ndarray, ref_bins: np.ndarray, padded: np.ndarray,
                            matrices: np.ndarray, center: tuple[float, float], radius_px: float, lo: float,
                            width: float, bins: int, a: float) -> np.ndarray:
    """Joint histograms (K, bins, bins) of the reference pixels (``rows``, ``cols``, their bins
    ``ref_bins``) against the moving frame sampled at ``center + M_k (q - center)`` for each of
    the K similarity matrices ``matrices`` (K, 2, 2) (:func:`vision.interpolation.similarity_matrix`);
    ``padded`` is the moving frame through :func:`pad_frame`. Samples are quantised into ``bins``
    over [lo, lo + width]; samples farther than ``radius_px`` from the centre (outside the moving
    frame's field of view) or outside the frame are not counted."""
    params = np.ascontiguousarray(np.asarray(matrices, dtype=np.float64).reshape(-1, 4))
    args = (float(center[0]), float(center[1]), float(radius_px) ** 2, float(lo), bins / float(width), int(bins),
            float(a))
    n, k = len(rows), len(params)
    if THREADS < 2 or n * k < PARALLEL_MIN_SAMPLES:
        return _histograms(rows, cols, ref_bins, padded, params, *args)
    if k >= THREADS:  # share the probes
        parts = np.array_split(np.arange(k), THREADS)
        futures = [pool().submit(_histograms, rows, cols, ref_bins, padded, params[p], *args) for p in parts]
        return np.concatenate([f.result() for f in futures])
    parts = np.array_split(np.arange(n), THREADS)  # one probe: share its pixels
    futures = [pool().submit(_histograms, rows[p[0]:p[-1] + 1], cols[p[0]:p[-1] + 1], ref_bins[p[0]:p[-1] + 1],
                              padded, params, *args) for p in parts]
    return sum(f.result() for f in futures)


def fisheye_joint_histograms(theta: np.ndarray, cos_phi: np.ndarray, sin_phi: np.ndarray, ref_bins: np.ndarray,
                             padded: np.ndarray, params: np.ndarray, center: tuple[float, float], focal_px: float,
                             radius_px: float, lo: float, width: float, bins: int, a: float) -> np.ndarray:
    """Joint histograms (K, bins, bins) like :func:`warped_joint_histograms`, but the compared
    pixels (angle ``theta`` from the optical axis, azimuth ``cos_phi``/``sin_phi``) are mapped into
    the other frame through the equidistant fisheye of ``focal_px`` (r = f theta) and a 3-D
    rotation: ``params`` (K, 11) = (pre, post, A (3 x 3, row-major)) per probe
    (:func:`vision.motion` builds them; docs/vision.md, "Tilt")."""
    params = np.ascontiguousarray(np.asarray(params, dtype=np.float64).reshape(-1, 11))
    args = (float(center[0]), float(center[1]), float(focal_px), float(radius_px) ** 2, float(lo),
            bins / float(width), int(bins), float(a))
    n, k = len(theta), len(params)
    if THREADS < 2 or n * k < PARALLEL_MIN_SAMPLES:
        return _fisheye_histograms(theta, cos_phi, sin_phi, ref_bins, padded, params, *args)
    if k >= THREADS:
        parts = np.array_split(np.arange(k), THREADS)
        futures = [pool().submit(_fisheye_histograms, theta, cos_phi, sin_phi, ref_bins, padded, params[p], *args)
                   for p in parts]
        return np.concatenate([f.result() for f in futures])
    parts = np.array_split(np.arange(n), THREADS)
    futures = [pool().submit(_fisheye_histograms, theta[p[0]:p[-1] + 1], cos_phi[p[0]:p[-1] + 1],
                              sin_phi[p[0]:p[-1] + 1], ref_bins[p[0]:p[-1] + 1], padded, params, *args)
               for p in parts]
    return sum(f.result() for f in futures)
