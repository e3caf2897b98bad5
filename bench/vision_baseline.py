"""SimpleITK's Mattes mutual-information registration: the independent baseline of vision/.

Nothing here is CapsuleRT's code: SimpleITK (ITK 5) registers the pair with its own metric
(Mattes et al. 2003: MI from B-spline Parzen-windowed histograms, so the metric is smooth),
its own interpolator (linear) and its own optimisers. To make the comparison fair it gets the
same frames (Butterworth-filtered as ours), the same disc mask, and a bracketing stage like
ours: an exhaustive grid over scale and angle at 1/4 resolution, then a multi-resolution
regular-step gradient descent (1/2, then full resolution). The model is ITK's
Similarity2DTransform about the frame centre with its translation frozen (weights 0): the same
two parameters as ours. Sign conventions: ITK maps reference points (x = column, y = row) to
moving points, x_m = s R(phi) (x - c) + c, so our counter-clockwise-as-displayed rotation is
-phi (rows point down).

Overlap: ITK's metric runs over the fixed image's mask points that map inside the moving image,
so at scales above 1 it compares ever fewer points, whose MI is biased upwards (a first run
with one grid over 0.15-5 landed at the top of the range for true scales 0.6-1.4). As our
estimator does (vision.motion, "Overlap"), a scale range straddling 1 is therefore registered
twice, each time with the zoomed-in frame as the fixed one and scales <= 1 -- the reference
onto the moving frame for [low, 1], the moving onto the reference for [1 / high, 1] (then
inverted: rotation -phi, scale 1 / s). The two runs' final metric values are not comparable
(different fixed frames), so the candidate kept is the one with the better SYMMETRIC Mattes
metric, ITK's metric of the reference onto the moving frame plus that of the moving frame onto
the reference under the inverse transform, both at full resolution over the disc.
"""

from __future__ import annotations

import math

import numpy as np
import SimpleITK as sitk

GRID_ANGLES, GRID_SCALES = 45, 20


def _images(fixed_a: np.ndarray, moving_a: np.ndarray):
    fixed = sitk.GetImageFromArray(np.asarray(fixed_a, np.float32))
    mov = sitk.GetImageFromArray(np.asarray(moving_a, np.float32))
    h, w = fixed_a.shape
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    radius = min(h, w) / 2.0 - 2.0
    yy, xx = np.mgrid[0:h, 0:w]
    mask = sitk.GetImageFromArray((((xx - cx) ** 2 + (yy - cy) ** 2) <= radius**2).astype(np.uint8))
    return fixed, mov, mask, (cx, cy)


def _metric(fixed_a: np.ndarray, moving_a: np.ndarray, angle: float, scale: float, bins: int) -> float:
    """ITK's Mattes metric (-MI) of ``moving_a`` under the similarity (angle [rad], scale) about
    the centre, over the disc of ``fixed_a``, full resolution."""
    fixed, mov, mask, center = _images(fixed_a, moving_a)
    transform = sitk.Similarity2DTransform()
    transform.SetCenter(center)
    transform.SetAngle(angle)
    transform.SetScale(scale)
    reg = sitk.ImageRegistrationMethod()
    reg.SetMetricAsMattesMutualInformation(bins)
    reg.SetMetricFixedMask(mask)
    reg.SetInterpolator(sitk.sitkLinear)
    reg.SetInitialTransform(transform)
    return float(reg.MetricEvaluate(fixed, mov))


def _register(fixed_a: np.ndarray, moving_a: np.ndarray, estimate: str, rotation_range_deg, scale_range,
              bins: int) -> tuple[float, float]:
    """One ITK registration: (ITK angle [rad], scale)."""
    fixed, mov, mask, center = _images(fixed_a, moving_a)
    transform = sitk.Similarity2DTransform()
    transform.SetCenter(center)
    a_lo, a_hi = (math.radians(v) for v in rotation_range_deg)
    s_lo, s_hi = scale_range
    do_scale, do_angle = estimate != "rotation", estimate != "scale"
    transform.SetScale(0.5 * (s_lo + s_hi) if do_scale else 1.0)
    transform.SetAngle(0.5 * (a_lo + a_hi) if do_angle else 0.0)

    def method(shrink: list[int], sigma: list[float]) -> sitk.ImageRegistrationMethod:
        reg = sitk.ImageRegistrationMethod()
        reg.SetMetricAsMattesMutualInformation(bins)
        reg.SetMetricSamplingStrategy(reg.NONE)
        reg.SetMetricFixedMask(mask)
        reg.SetInterpolator(sitk.sitkLinear)
        reg.SetShrinkFactorsPerLevel(shrink)
        reg.SetSmoothingSigmasPerLevel(sigma)
        reg.SetInitialTransform(transform, inPlace=True)
        return reg

    grid = method([4], [2.0])
    grid.SetOptimizerAsExhaustive([GRID_SCALES if do_scale else 0, GRID_ANGLES if do_angle else 0, 0, 0])
    grid.SetOptimizerScales([(s_hi - s_lo) / (2 * GRID_SCALES), (a_hi - a_lo) / (2 * GRID_ANGLES), 1.0, 1.0])
    grid.Execute(fixed, mov)
    descent = method([2, 1], [1.0, 0.0])
    descent.SetOptimizerAsRegularStepGradientDescent(learningRate=0.05, minStep=1e-7, numberOfIterations=500,
                                                     relaxationFactor=0.5, gradientMagnitudeTolerance=1e-10)
    descent.SetOptimizerScalesFromPhysicalShift()
    descent.SetOptimizerWeights([float(do_scale), float(do_angle), 0.0, 0.0])
    descent.Execute(fixed, mov)
    return transform.GetAngle(), float(transform.GetScale())


def sitk_register(reference: np.ndarray, moving: np.ndarray, *, estimate: str = "both",
                  rotation_range_deg: tuple[float, float] = (-90.0, 90.0),
                  scale_range: tuple[float, float] = (0.5, 2.0), bins: int = 50) -> tuple[float, float]:
    """(rotation_deg, scale) of ``moving`` relative to ``reference`` (grey float frames, same
    shape) by SimpleITK Mattes-MI registration (module doc). ``estimate``: "both", "rotation"
    (scale frozen at 1) or "scale" (rotation frozen at 0)."""
    s_lo, s_hi = scale_range
    if estimate == "rotation" or s_hi <= 1.0:
        angle, scale = _register(reference, moving, estimate, rotation_range_deg, scale_range, bins)
        return -math.degrees(angle), scale
    # ITK angle and scale of moving relative to reference, from each side
    b_angle, b_scale = _register(moving, reference, estimate, (-rotation_range_deg[1], -rotation_range_deg[0]),
                                 (1.0 / s_hi, 1.0), bins)
    candidates = [(-b_angle, 1.0 / b_scale)]
    if s_lo < 1.0:
        candidates.append(_register(reference, moving, estimate, rotation_range_deg, (s_lo, 1.0), bins))

    def symmetric(candidate: tuple[float, float]) -> float:
        angle, scale = candidate
        return _metric(reference, moving, angle, scale, bins) + _metric(moving, reference, -angle, 1.0 / scale, bins)

    angle, scale = min(candidates, key=symmetric)  # ITK's metric is -MI: lower is better
    return -math.degrees(angle), scale
