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
from numba import njit

from .errors import VisionInputError
from .noise import gradients, noise_grad, noise_value, permutation
from .pool import THREADS, pool

#: Points below which one thread shades them all.
PARALLEL_MIN_POINTS = 4096


@njit(cache=True, inline="always")
def _smoothstep(e0, e1, x):
    t = min(max((x - e0) / (e1 - e0), 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


@njit(cache=True, nogil=True)
def _mucosa(perm, g, points_mm, normals, params, base, vessel_rgb, albedo, bent):
    """Per point: reflectance (N, 3) into ``albedo`` and bent unit normal into ``bent``
    (``normals`` face the lumen). ``params``: see MucosaTexture._params."""
    (axis_x, axis_y, axis_z, has_axis, spacing, depth, sharp, warp_amp, warp_scale, bump_mm, bump_scale,
     colour_var, colour_scale, vessel_scale, vessel_width, vessel_strength, valley) = params
    for i in range(points_mm.shape[0]):
        x, y, z = points_mm[i, 0], points_mm[i, 1], points_mm[i, 2]
        # --- folds: height (mm) and its gradient (mm / mm)
        nw, wx, wy, wz = noise_grad(perm, g, x / warp_scale + 17.3, y / warp_scale + 5.1, z / warp_scale + 9.7)
        if has_axis > 0.5:
            s = (x * axis_x + y * axis_y + z * axis_z) / spacing + warp_amp * nw
            sx = axis_x / spacing + warp_amp * wx / warp_scale
            sy = axis_y / spacing + warp_amp * wy / warp_scale
            sz = axis_z / spacing + warp_amp * wz / warp_scale
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
            _mucosa(*args, pts, nrm, *rest, albedo, bent)
            return albedo, bent
        cuts = np.linspace(0, len(pts), THREADS + 1).astype(int)
        futures = [pool().submit(_mucosa, *args, pts[a:b], nrm[a:b], *rest, albedo[a:b], bent[a:b])
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
