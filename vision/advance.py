"""From the estimated scale between two frames to the capsule's advance, through the rendered
geometry.

What scale means for a capsule in a lumen. The estimator (:mod:`vision.motion`) explains the
second frame as the first magnified by one factor s about the optical axis. That is exact for a
pinhole camera advancing by d towards a wall perpendicular to its axis at distance Z
(s = Z / (Z - d)); inside a lumen it is not: advancing along the axis moves every wall point
RADIALLY in the fisheye image, but by an amount that depends on its depth (a wall point at
angle theta from the axis of a tube of radius R goes from theta to atan(R / (R / tan theta - d)):
the near wall at the rim sweeps outwards fast, the far lumen barely moves). The MI scale is the
single magnification that best fits this flow, so s - 1 grows with d / (lumen radius), by a
geometry factor of order one that the rendered frame knows exactly.

Conversion. For a trial advance d along the view direction, every wall pixel of the reference
frame (camera-frame point X from the render's depth) moves to X - d z; with r and r'(d) its image
radii before and after (equidistant fisheye, r = f theta), the least-squares magnification of
that flow is

    s(d) = sum w r r'(d) / sum w r^2

over the wall pixels of the estimator's disc that stay in view (weights w: uniform). s(d) grows
monotonically with d, and the advance of an estimated scale is the root of s(d) = scale
(:func:`advance_for_scale`). Lateral motion and tilt are outside the model (they are not a
similarity about the centre).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq

from .errors import VisionInputError
from .render import Frame

#: Advances searched for the root, as a fraction of the smallest on-axis depth seen.
MAX_ADVANCE_FRACTION = 0.9


def _flow_geometry(frame: Frame, radius_px: float | None):
    cam = frame.camera
    c = cam.center_px
    rows, cols = np.indices(frame.mask.shape, dtype=float)
    r_pix = np.hypot(rows - c, cols - c)
    radius = cam.size_px / 2.0 - 2.0 if radius_px is None else float(radius_px)
    keep = frame.mask & (r_pix <= radius) & (r_pix > 0.5)
    if keep.sum() < 16:
        raise VisionInputError("the frame shows too little wall to convert a scale", "reference")
    x = frame.pose.to_camera(frame.points_m[keep])
    return x, r_pix[keep], cam.focal_px, radius


def scale_for_advance(frame: Frame, advance_m: float, radius_px: float | None = None) -> float:
    """s(d): the least-squares magnification of the flow of an advance ``advance_m`` along the
    view direction, seen from ``frame`` (module doc)."""
    x, r, f, radius = _flow_geometry(frame, radius_px)
    z = x[:, 2] - advance_m
    rho = np.hypot(x[:, 0], x[:, 1])
    r_new = f * np.arctan2(rho, z)
    stay = (r_new <= radius) & (z > 0.0)
    if stay.sum() < 16:
        raise VisionInputError(f"an advance of {advance_m} m leaves too little of the frame in view", "advance_m")
    return float(np.sum(r[stay] * r_new[stay]) / np.sum(r[stay] ** 2))


def advance_for_scale(frame: Frame, scale: float, radius_px: float | None = None) -> float:
    """The advance d [m] along the view direction whose flow has the magnification ``scale``
    (module doc), seen from the reference ``frame``; negative: a retreat."""
    if not (math.isfinite(scale) and scale > 0.0):
        raise VisionInputError(f"must be a finite number > 0, got {scale!r}", "scale")
    x, _, _, _ = _flow_geometry(frame, radius_px)
    ahead = x[:, 2][(np.hypot(x[:, 0], x[:, 1]) < 0.2 * x[:, 2]) & (x[:, 2] > 0)]
    depth = float(np.min(ahead)) if ahead.size else float(np.min(np.linalg.norm(x, axis=1)))
    lo, hi = -MAX_ADVANCE_FRACTION * depth, MAX_ADVANCE_FRACTION * depth

    def g(d: float) -> float:
        return scale_for_advance(frame, d, radius_px) - scale

    g_lo, g_hi = g(lo), g(hi)
    if g_lo > 0.0 or g_hi < 0.0:
        raise VisionInputError(f"scale {scale:.6g} is outside what advances within +-{hi:.4g} m give "
                               f"({g_lo + scale:.6g} to {g_hi + scale:.6g})", "scale")
    return float(brentq(g, lo, hi, xtol=1e-9))
