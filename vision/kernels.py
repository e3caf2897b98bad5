"""The package's compiled (numba) code, all of it in this one module (docs/architecture.md, "One
engine fence"): the motion search's warp + quantise + joint histogram, the solid noise and the
mucosa of the texture (:mod:`vision.noise`, :mod:`vision.mucosa`), the wall hits' geometry and
the LEDs' shading (:mod:`vision.render`). The modules named hold the models and their
documentation; here is only their inner loops.

The motion search: warp + quantise + joint histogram in one pass.

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


@njit(cache=True, nogil=True)
def histogram_mutual_information(hist):
    """Eq 3.2-3.4 (nats) of each joint histogram (K, B, B) of counts: with N the count, c_x, c_y
    the marginals, I = ln N + (sum c_xy ln c_xy - sum c_x ln c_x - sum c_y ln c_y) / N (0 ln 0 = 0),
    the same as :func:`vision.mutual_information.mutual_information_from_histogram` in one pass
    over the non-empty bins (no probabilities formed)."""
    k_count, bx, by = hist.shape
    out = np.zeros(k_count)
    cx, cy = np.empty(bx), np.empty(by)
    for k in range(k_count):
        cx[:] = 0.0
        cy[:] = 0.0
        sxy = 0.0
        for i in range(bx):
            for j in range(by):
                c = hist[k, i, j]
                if c > 0:
                    cf = float(c)
                    cx[i] += cf
                    cy[j] += cf
                    sxy += cf * math.log(cf)
        n = 0.0
        sx = 0.0
        for i in range(bx):
            if cx[i] > 0.0:
                n += cx[i]
                sx += cx[i] * math.log(cx[i])
        sy = 0.0
        for j in range(by):
            if cy[j] > 0.0:
                sy += cy[j] * math.log(cy[j])
        if n > 0.0:
            out[k] = math.log(n) + (sxy - sx - sy) / n
    return out


def pad_frame(frame: np.ndarray) -> np.ndarray:
    """The frame (float64) with 2 edge-replicated pixels on every side, as :func:`_histograms`
    wants it (made once per pyramid level, not per probe)."""
    a = np.asarray(frame, dtype=np.float64)
    out = np.empty((a.shape[0] + 4, a.shape[1] + 4))
    out[2:-2, 2:-2] = a  # np.pad(a, 2, mode="edge"), without its generality's cost
    out[:2, 2:-2], out[-2:, 2:-2] = a[0], a[-1]
    out[:, :2], out[:, -2:] = out[:, 2:3], out[:, -3:-2]
    return out


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


# --- solid gradient noise (vision.noise: Perlin 2002, exact gradient)

@njit(cache=True, inline="always", fastmath=True)
def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@njit(cache=True, inline="always", fastmath=True)
def _dfade(t):
    return 30.0 * t * t * (t - 1.0) * (t - 1.0)


@njit(cache=True, inline="always", fastmath=True)
def _dot(g, k, x, y, z):
    return g[k, 0] * x + g[k, 1] * y + g[k, 2] * z


@njit(cache=True, inline="always", fastmath=True)
def _blend(g, c, i000, i100, i010, i110, i001, i101, i011, i111, u, v, w):
    g0, g1, g2, g3 = g[i000, c], g[i100, c], g[i010, c], g[i110, c]
    g4, g5, g6, g7 = g[i001, c], g[i101, c], g[i011, c], g[i111, c]
    return (g0 + u * (g1 - g0) + v * (g2 - g0) + w * (g4 - g0) + u * v * (g0 - g1 - g2 + g3)
            + v * w * (g0 - g2 - g4 + g6) + w * u * (g0 - g1 - g4 + g5)
            + u * v * w * (-g0 + g1 + g2 - g3 + g4 - g5 - g6 + g7))


@njit(cache=True, fastmath=True)
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


@njit(cache=True, fastmath=True)
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


# --- the procedural mucosa (vision.mucosa)

@njit(cache=True, inline="always", fastmath=True)
def _smoothstep(e0, e1, x):
    t = min(max((x - e0) / (e1 - e0), 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


@njit(cache=True, nogil=True, fastmath=True)
def mucosa(perm, g, points_mm, normals, params, base, vessel_rgb, albedo, bent, path_s_mm, path_t):
    """Per point: reflectance (N, 3) into ``albedo`` and bent unit normal into ``bent``
    (``normals`` face the lumen). ``params``: see vision.mucosa.MucosaTexture._params; with folds
    along a path (its fourth entry 2) each point's arc length ``path_s_mm`` (N,) and the path's unit
    tangent there ``path_t`` (N, 3) take the place of the fixed axis (vision.mucosa.FoldPath)."""
    (axis_x, axis_y, axis_z, has_axis, spacing, depth, sharp, warp_amp, warp_scale, bump_mm, bump_scale,
     colour_var, colour_scale, vessel_scale, vessel_width, vessel_strength, valley) = params
    for i in range(points_mm.shape[0]):
        x, y, z = points_mm[i, 0], points_mm[i, 1], points_mm[i, 2]
        # --- folds: height (mm) and its gradient (mm / mm)
        nw, wx, wy, wz = noise_grad(perm, g, x / warp_scale + 17.3, y / warp_scale + 5.1, z / warp_scale + 9.7)
        if has_axis > 0.5:
            if has_axis > 1.5:  # along a path: its arc length, its tangent as the local axis
                ax, ay, az = path_t[i, 0], path_t[i, 1], path_t[i, 2]
                s = path_s_mm[i] / spacing + warp_amp * nw
            else:
                ax, ay, az = axis_x, axis_y, axis_z
                s = (x * axis_x + y * axis_y + z * axis_z) / spacing + warp_amp * nw
            sx = ax / spacing + warp_amp * wx / warp_scale
            sy = ay / spacing + warp_amp * wy / warp_scale
            sz = az / spacing + warp_amp * wz / warp_scale
            c = 0.5 + 0.5 * math.cos(2.0 * math.pi * s)
            fold = c**sharp
            dfold = sharp * c ** (sharp - 1.0) * (-math.pi * math.sin(2.0 * math.pi * s)) if c > 0.0 else 0.0
            gx, gy, gz = dfold * sx, dfold * sy, dfold * sz
        else:
            nr, rx, ry, rz = noise_grad(perm, g, x / spacing, y / spacing, z / spacing)
            ridge = 1.0 - abs(nr)
            fold = ridge**sharp
            d = -sharp * ridge ** (sharp - 1.0) * (1.0 if nr >= 0.0 else -1.0) / spacing
            gx, gy, gz = d * rx, d * ry, d * rz
        hx, hy, hz = depth * gx, depth * gy, depth * gz
        # --- fine bumps, two octaves
        for octave in range(2):
            f = (2.0**octave) / bump_scale
            amp = bump_mm / (2.0**octave)
            _, bx, by, bz = noise_grad(perm, g, x * f + 3.3, y * f + 7.7, z * f + 1.1)
            hx += amp * f * bx
            hy += amp * f * by
            hz += amp * f * bz
        # --- bend the normal: n' = normalize(n - (grad h - (grad h . n) n))
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        dn = hx * nx + hy * ny + hz * nz
        px, py, pz = nx - (hx - dn * nx), ny - (hy - dn * ny), nz - (hz - dn * nz)
        norm = math.sqrt(px * px + py * py + pz * pz)
        bent[i, 0], bent[i, 1], bent[i, 2] = px / norm, py / norm, pz / norm
        # --- colour: two octaves of noise
        c1 = noise_value(perm, g, x / colour_scale + 41.0, y / colour_scale + 43.0, z / colour_scale + 47.0)
        c2 = noise_value(perm, g, 2 * x / colour_scale + 53.0, 2 * y / colour_scale, 2 * z / colour_scale)
        tone = 1.0 + colour_var * (c1 + 0.5 * c2)
        # --- vessels: zero set of domain-warped noise, patchy by the low-frequency colour noise
        wv = noise_value(perm, g, x / (2 * vessel_scale) + 61.0, y / (2 * vessel_scale), z / (2 * vessel_scale))
        nv = noise_value(perm, g, x / vessel_scale + 1.5 * wv + 71.0, y / vessel_scale + 1.5 * wv,
                         z / vessel_scale - 1.5 * wv)
        vessel = (1.0 - _smoothstep(0.0, vessel_width, abs(nv))) * _smoothstep(-0.2, 0.3, c1) * vessel_strength
        shade = tone * (1.0 - valley * (1.0 - fold))
        for k in range(3):
            albedo[i, k] = min(max(shade * ((1.0 - vessel) * base[k] + vessel * vessel_rgb[k]), 0.0), 1.0)


# --- the camera's rays (vision.render)

@njit(cache=True, nogil=True)
def wall_hits(prim, tfar, origin, dirs, face_map, face_normals, plane_d, frame, face, t, points, normals):
    """From Embree's first hits (``prim``, float32 ``tfar``) of rays from ``origin`` along the
    unit ``dirs``: the phantom face, the float64 distance to its plane (Embree's where the ray is
    parallel to it), the wall point and the smooth unit normal turned to face the camera; the
    same arithmetic as :meth:`raytrace.engine.scene.TracerScene.first_hit` and
    :meth:`~raytrace.engine.scene.TracerScene.smooth_normals` (barycentrics from the face's
    ``frame`` row clipped to [0, 1], corner normals interpolated, the facet normal if that
    degenerates or flips), in one pass. A miss: face -1, t inf, point NaN, normal 0."""
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in range(prim.shape[0]):
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        if prim[i] < 0:
            face[i], t[i] = -1, np.inf
            points[i, 0] = points[i, 1] = points[i, 2] = np.nan
            normals[i, 0] = normals[i, 1] = normals[i, 2] = 0.0
            continue
        f = face_map[prim[i]]
        fx, fy, fz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
        denom = fx * dx + fy * dy + fz * dz
        dist = np.float64(tfar[i])
        if abs(denom) > 1e-12:
            t64 = (plane_d[f] - (fx * ox + fy * oy + fz * oz)) / denom
            if math.isfinite(t64):
                dist = max(t64, 0.0)
        x, y, z = ox + dist * dx, oy + dist * dy, oz + dist * dz
        fr = frame[f]
        v2x, v2y, v2z = x - fr[0], y - fr[1], z - fr[2]
        d20 = v2x * fr[3] + v2y * fr[4] + v2z * fr[5]
        d21 = v2x * fr[6] + v2y * fr[7] + v2z * fr[8]
        bv = (fr[11] * d20 - fr[10] * d21) / fr[12]
        bw = (fr[9] * d21 - fr[10] * d20) / fr[12]
        bu = min(max(1.0 - bv - bw, 0.0), 1.0)
        bv = min(max(bv, 0.0), 1.0)
        bw = min(max(bw, 0.0), 1.0)
        nx = bu * fr[13] + bv * fr[16] + bw * fr[19]
        ny = bu * fr[14] + bv * fr[17] + bw * fr[20]
        nz = bu * fr[15] + bv * fr[18] + bw * fr[21]
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        if norm > 1e-12:
            nx, ny, nz = nx / norm, ny / norm, nz / norm
        if not norm > 1e-12 or nx * fx + ny * fy + nz * fz <= 0.0:
            nx, ny, nz = fx, fy, fz
        if nx * dx + ny * dy + nz * dz > 0.0:  # the side facing the camera
            nx, ny, nz = -nx, -ny, -nz
        face[i], t[i] = f, dist
        points[i, 0], points[i, 1], points[i, 2] = x, y, z
        normals[i, 0], normals[i, 1], normals[i, 2] = nx, ny, nz


# --- the LEDs (vision.render)

@njit(cache=True, nogil=True)
def shade_points(points, normals, albedo, view_dirs, leds, forward, per_led, exponent, spec_norm, shininess, out):
    """The LEDs' radiance of each wall point (vision.render module doc): inverse square, Lambert,
    normalised Blinn-Phong; into ``out`` (N, 3)."""
    for i in range(points.shape[0]):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        diffuse = 0.0
        specular = 0.0
        for k in range(leds.shape[0]):
            vx, vy, vz = points[i, 0] - leds[k, 0], points[i, 1] - leds[k, 1], points[i, 2] - leds[k, 2]
            d2 = vx * vx + vy * vy + vz * vz
            dist = math.sqrt(d2)
            lx, ly, lz = -vx / dist, -vy / dist, -vz / dist
            cos_i = nx * lx + ny * ly + nz * lz
            cos_e = (vx * forward[0] + vy * forward[1] + vz * forward[2]) / dist
            if cos_i <= 0.0 or cos_e <= 0.0:
                continue
            e = per_led * (cos_e if exponent == 1.0 else cos_e**exponent) * cos_i / d2
            diffuse += e
            if spec_norm > 0.0:
                hx, hy, hz = lx - view_dirs[i, 0], ly - view_dirs[i, 1], lz - view_dirs[i, 2]
                n_h = (nx * hx + ny * hy + nz * hz) / math.sqrt(hx * hx + hy * hy + hz * hz)
                if n_h > 0.0:
                    specular += e * spec_norm * n_h**shininess
        for c in range(3):
            out[i, c] = diffuse * albedo[i, c] / math.pi + specular
