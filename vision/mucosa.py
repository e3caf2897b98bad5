"""A procedural mucosa defined in 3-D on the organ surface: folds, vessels, colour.

Everything is a function of the surface POINT (metres, phantom frame) through the solid noise of
:mod:`vision.noise`, so a wall point looks the same from every pose: consecutive frames are
consistent, as real ones are, and any motion has an exact ground truth. Lengths below are in
millimetres on the wall.

* Folds (shading relief, not geometry: the phantom's GI organs are smooth): a height field
  h (mm, towards the lumen). With ``fold_axis`` (the lumen's axis: circular folds, the small
  bowel's plicae circulares or the colon's haustral folds) h = depth * ((1 + cos 2 pi s) / 2)^p
  with s the distance along the axis in fold spacings, warped by noise so that folds wander and
  fork; without an axis, ridged noise (gastric rugae): h = depth * (1 - |n|)^p. Fine bumps
  (villi, mucus) add low-amplitude two-octave noise. The wall is shaded with the normal bent by
  the surface gradient of h (bump mapping: n' = normalize(n - grad_s h)), and fold valleys are
  darkened (``valley_darkening``), as light reaches them less.
* Colour: a base reflectance (linear RGB) modulated by two-octave noise (+-``colour_variation``).
* Vessels: the zero set of domain-warped noise, |n| < ``vessel_width``, blended towards the
  vessel colour where a low-frequency noise mask allows (so vessel trees are patchy).

Presets for the GI organs: :meth:`MucosaTexture.small_intestine`, :meth:`~MucosaTexture.colon`,
:meth:`~MucosaTexture.stomach`. A texture's :meth:`shade_inputs` returns what the renderer needs:
the reflectance and the bent normal of each wall point.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from .errors import VisionInputError
from .kernels import mucosa
from .noise import gradients, permutation
from .pool import THREADS, pool

#: Points below which one thread shades them all.
PARALLEL_MIN_POINTS = 4096


@dataclass(frozen=True)
class MucosaTexture:
    """Parameters of the procedural mucosa (module doc); lengths in millimetres on the wall,
    reflectances linear RGB in [0, 1]."""

    seed: int = 0
    base_rgb: tuple[float, float, float] = (0.80, 0.30, 0.20)
    vessel_rgb: tuple[float, float, float] = (0.35, 0.02, 0.02)
    fold_axis: tuple[float, float, float] | None = None
    fold_spacing_mm: float = 6.0
    fold_depth_mm: float = 0.8
    fold_sharpness: float = 3.0
    fold_warp: float = 0.25
    fold_warp_scale_mm: float = 12.0
    bump_mm: float = 0.08
    bump_scale_mm: float = 0.8
    colour_variation: float = 0.18
    colour_scale_mm: float = 9.0
    vessel_scale_mm: float = 5.0
    vessel_width: float = 0.06
    vessel_strength: float = 0.7
    valley_darkening: float = 0.35

    def __post_init__(self) -> None:
        for name in ("fold_spacing_mm", "fold_warp_scale_mm", "bump_scale_mm", "colour_scale_mm", "vessel_scale_mm",
                     "vessel_width", "fold_sharpness"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0.0):
                raise VisionInputError(f"must be a finite number > 0, got {v!r}", f"texture.{name}")
        for name in ("fold_depth_mm", "bump_mm", "fold_warp", "colour_variation", "vessel_strength",
                     "valley_darkening"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v >= 0.0):
                raise VisionInputError(f"must be a finite number >= 0, got {v!r}", f"texture.{name}")
        for name in ("base_rgb", "vessel_rgb"):
            c = np.asarray(getattr(self, name), dtype=float)
            if c.shape != (3,) or not (np.isfinite(c).all() and (c >= 0).all() and (c <= 1).all()):
                raise VisionInputError("must be 3 reflectances in [0, 1]", f"texture.{name}")
        if self.fold_axis is not None:
            a = np.asarray(self.fold_axis, dtype=float)
            if a.shape != (3,) or not np.isfinite(a).all() or np.linalg.norm(a) < 1e-12:
                raise VisionInputError("must be a non-zero 3-vector or None", "texture.fold_axis")

    @classmethod
    def small_intestine(cls, fold_axis=None, seed: int = 0) -> "MucosaTexture":
        """Orange-pink, dense circular folds (plicae) every ~4 mm, velvety villi."""
        return cls(seed=seed, base_rgb=(0.80, 0.33, 0.12), fold_axis=fold_axis, fold_spacing_mm=4.0,
                   fold_depth_mm=0.7, bump_mm=0.06, bump_scale_mm=0.5)

    @classmethod
    def colon(cls, fold_axis=None, seed: int = 0) -> "MucosaTexture":
        """Paler pink, haustral folds every ~15 mm, smooth, with visible submucosal vessels."""
        return cls(seed=seed, base_rgb=(0.80, 0.34, 0.26), fold_axis=fold_axis, fold_spacing_mm=15.0,
                   fold_depth_mm=2.0, fold_sharpness=4.0, bump_mm=0.03, vessel_strength=0.85)

    @classmethod
    def stomach(cls, seed: int = 0) -> "MucosaTexture":
        """Red-orange with irregular rugae (ridged noise, no axis)."""
        return cls(seed=seed, base_rgb=(0.78, 0.22, 0.15), fold_axis=None, fold_spacing_mm=14.0,
                   fold_depth_mm=1.2, fold_sharpness=4.0, vessel_strength=0.4)

    def _params(self) -> np.ndarray:
        axis = (0.0, 0.0, 1.0, 0.0) if self.fold_axis is None else (
            *(np.asarray(self.fold_axis, float) / np.linalg.norm(self.fold_axis)), 1.0)
        return np.array([*axis, self.fold_spacing_mm, self.fold_depth_mm, self.fold_sharpness, self.fold_warp,
                         self.fold_warp_scale_mm, self.bump_mm, self.bump_scale_mm, self.colour_variation,
                         self.colour_scale_mm, self.vessel_scale_mm, self.vessel_width, self.vessel_strength,
                         self.valley_darkening], dtype=np.float64)

    def shade_inputs(self, points_m: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(albedo (N, 3), bent normals (N, 3)) of wall points (N, 3) [m] whose unit normals
        (N, 3) face the lumen."""
        pts = np.ascontiguousarray(np.asarray(points_m, dtype=np.float64) * 1e3)
        nrm = np.ascontiguousarray(normals, dtype=np.float64)
        albedo, bent = np.empty_like(pts), np.empty_like(pts)
        args = (_perm(self.seed), gradients())
        rest = (self._params(), np.asarray(self.base_rgb, float), np.asarray(self.vessel_rgb, float))
        if THREADS < 2 or len(pts) < PARALLEL_MIN_POINTS:
            mucosa(*args, pts, nrm, *rest, albedo, bent)
            return albedo, bent
        cuts = np.linspace(0, len(pts), THREADS + 1).astype(int)
        futures = [pool().submit(mucosa, *args, pts[a:b], nrm[a:b], *rest, albedo[a:b], bent[a:b])
                   for a, b in zip(cuts[:-1], cuts[1:])]
        for f in futures:
            f.result()
        return albedo, bent


#: The mucosa of each GI organ of the default torso: its preset and the fixed axis its circular
#: folds run across (the organ's long axis in the torso frame: x left-right, z head-ward).
ORGAN_TEXTURES = {
    "stomach": ("stomach", None),
    "small_intestine": ("small_intestine", (1.0, 0.0, 0.0)),
    "ascending_colon": ("colon", (0.0, 0.0, 1.0)),
    "transverse_colon": ("colon", (1.0, 0.0, 0.0)),
    "descending_colon": ("colon", (0.0, 0.0, 1.0)),
}
PRESETS = ("default", "small_intestine", "colon", "stomach")


def texture_for(organ: str | None, preset: str = "auto", fold_axis=None, seed: int = 0) -> MucosaTexture:
    """The texture of a named ``preset`` (one of PRESETS), or for ``preset="auto"`` the one of
    ``organ`` in :data:`ORGAN_TEXTURES` (the plain default for any other organ). ``fold_axis``
    overrides the preset's. Fixed per organ, never per pose, so frames of a sequence agree."""
    if preset == "auto":
        preset, axis = ORGAN_TEXTURES.get(organ or "", ("default", None))
    elif preset in PRESETS:
        axis = ORGAN_TEXTURES.get(organ or "", (None, None))[1]
    else:
        raise VisionInputError(f"must be auto or one of {', '.join(PRESETS)}, got {preset!r}", "texture.preset")
    if fold_axis is not None:
        axis = tuple(float(v) for v in np.asarray(fold_axis, float).reshape(-1))
        if len(axis) != 3 or not np.isfinite(axis).all() or np.linalg.norm(axis) < 1e-12:
            raise VisionInputError("must be a non-zero 3-vector", "texture.fold_axis")
    if preset == "stomach":
        return MucosaTexture.stomach(seed=seed)
    if preset == "default":
        return MucosaTexture(seed=seed, fold_axis=axis)
    return getattr(MucosaTexture, preset)(fold_axis=axis, seed=seed)


@functools.lru_cache(maxsize=64)  # bounded: a service renders with its callers' seeds
def _perm(seed: int) -> np.ndarray:
    return permutation(seed)
