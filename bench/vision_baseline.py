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
"""

from __future__ import annotations

import math

import numpy as np
import SimpleITK as sitk

GRID_ANGLES, GRID_SCALES = 45, 20


def sitk_register(reference: np.ndarray, moving: np.ndarray, *, estimate: str = "both",
                  rotation_range_deg: tuple[float, float] = (-90.0, 90.0),
                  scale_range: tuple[float, float] = (0.5, 2.0), bins: int = 50) -> tuple[float, float]:
    """(rotation_deg, scale) of ``moving`` relative to ``reference`` (grey float frames, same
    shape) by SimpleITK Mattes-MI registration (module doc). ``estimate``: "both", "rotation"
    (scale frozen at 1) or "scale" (rotation frozen at 0)."""
    fixed = sitk.GetImageFromArray(np.asarray(reference, np.float32))
    mov = sitk.GetImageFromArray(np.asarray(moving, np.float32))
    h, w = fixed.GetSize()[1], fixed.GetSize()[0]
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    radius = min(h, w) / 2.0 - 2.0
    yy, xx = np.mgrid[0:h, 0:w]
    mask = sitk.GetImageFromArray((((xx - cx) ** 2 + (yy - cy) ** 2) <= radius**2).astype(np.uint8))
    transform = sitk.Similarity2DTransform()
    transform.SetCenter((cx, cy))
    a_lo, a_hi = (math.radians(v) for v in rotation_range_deg)
    s_lo, s_hi = scale_range
    do_scale, do_angle = estimate != "rotation", estimate != "scale"
    transform.SetScale(0.5 * (s_lo + s_hi) if do_scale else 1.0)
    transform.SetAngle(0.5 * (a_lo + a_hi) if do_angle else 0.0)
    weights = [float(do_scale), float(do_angle), 0.0, 0.0]

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
    descent.SetOptimizerWeights(weights)
    descent.Execute(fixed, mov)
    return -math.degrees(transform.GetAngle()), float(transform.GetScale())
