"""A procedural mucosa defined in 3-D on the organ surface: folds, vessels, colour.

Everything is a function of the surface POINT (metres, phantom frame) through the solid noise of
:mod:`vision.noise`, so a wall point looks the same from every pose: consecutive frames are
consistent, as real ones are, and any motion has an exact ground truth. Lengths below are in
millimetres on the wall.

* Folds (shading relief, not geometry: the phantom's GI organs are smooth): a height field
  h (mm, towards the lumen). With ``fold_axis`` (the lumen's axis: circular folds, the small
  bowel's plicae circulares or the colon's haustral folds) h = depth * ((1 + cos 2 pi s) / 2)^p
  with s the distance along the axis in fold spacings, warped by noise so that folds wander and
  fork; with ``fold_path`` (a real, winding lumen: :class:`FoldPath`, its mid-line) the same circular
  folds with s the arc length of the wall point's nearest mid-line point and the axis the mid-line's
  tangent there, so folds ring the tube wherever it turns; without either, ridged noise (gastric
  rugae): h = depth * (1 - |n|)^p. Fine bumps
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
class FoldPath:
    """A lumen's mid-line as the axis of its circular folds (module doc): ``query(points)`` gives each
    point's arc length along the polyline [m] and the unit tangent there, of the polyline's point nearest
    to it (searched on the two segments beside its nearest vertex). ``polylines``: one or more (n, 3)
    polylines in metres, their arc lengths counted on from one to the next."""

    def __init__(self, polylines) -> None:
        from scipy.spatial import cKDTree

        points, starts, ends, s0 = [], [], [], []
        total = 0.0
        for line in polylines:
            p = np.asarray(line, dtype=float)
            if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2 or not np.isfinite(p).all():
                raise VisionInputError("a fold path is (n >= 2, 3) finite points", "texture.fold_path")
            p = p[np.concatenate([[True], np.linalg.norm(np.diff(p, axis=0), axis=1) > 0])]
            length = np.linalg.norm(np.diff(p, axis=0), axis=1)
            points.append(p)
            starts.append(np.full(len(p), len(np.concatenate(points[:-1])) if len(points) > 1 else 0))
            ends.append(starts[-1] + len(p) - 1)
            s0.append(total + np.concatenate([[0.0], np.cumsum(length)]))
            total += float(length.sum())
        self.points_m = np.concatenate(points)
        self.s_m = np.concatenate(s0)  # arc length of every vertex
        self._first = np.concatenate(starts)  # each vertex's polyline: its first and last vertex
        self._last = np.concatenate([np.full(len(p), e) for p, e in zip(points, ends)])
        self.length_m = total
        self._tree = cKDTree(self.points_m)

    def query(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(arc length [m] (N,), unit tangent (N, 3)) of the polyline's points nearest to ``points_m`` (N, 3)."""
        q = np.asarray(points_m, dtype=float)
        _, k = self._tree.query(q, workers=-1)
        best_s = np.empty(len(q))
        best_t = np.empty((len(q), 3))
        best_d = np.full(len(q), np.inf)
        for a in (np.maximum(k - 1, self._first[k]), np.minimum(k, self._last[k] - 1)):  # the two segments
            b = a + 1
            seg = self.points_m[b] - self.points_m[a]
            length = np.linalg.norm(seg, axis=1)
            t = np.clip(np.einsum("ij,ij->i", q - self.points_m[a], seg) / length**2, 0.0, 1.0)
            d = np.linalg.norm(self.points_m[a] + t[:, None] * seg - q, axis=1)
            better = d < best_d
            best_d[better] = d[better]
            best_s[better] = self.s_m[a][better] + t[better] * length[better]
            best_t[better] = seg[better] / length[better, None]
        return best_s, best_t


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
    #: Circular folds around a winding lumen's mid-line instead of a fixed axis (module doc).
    fold_path: FoldPath | None = None

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
        if self.fold_path is not None and not isinstance(self.fold_path, FoldPath):
            raise VisionInputError("must be a FoldPath or None", "texture.fold_path")
        if self.fold_axis is not None:
            a = np.asarray(self.fold_axis, dtype=float)
            if a.shape != (3,) or not np.isfinite(a).all() or np.linalg.norm(a) < 1e-12:
                raise VisionInputError("must be a non-zero 3-vector or None", "texture.fold_axis")

    @classmethod
    def small_intestine(cls, fold_axis=None, seed: int = 0, fold_path: FoldPath | None = None) -> "MucosaTexture":
        """Orange-pink, dense circular folds (plicae) every ~4 mm, velvety villi."""
        return cls(seed=seed, base_rgb=(0.80, 0.33, 0.12), fold_axis=fold_axis, fold_spacing_mm=4.0,
                   fold_depth_mm=0.7, bump_mm=0.06, bump_scale_mm=0.5, fold_path=fold_path)

    @classmethod
    def colon(cls, fold_axis=None, seed: int = 0, fold_path: FoldPath | None = None) -> "MucosaTexture":
        """Paler pink, haustral folds every ~15 mm, smooth, with visible submucosal vessels."""
        return cls(seed=seed, base_rgb=(0.80, 0.34, 0.26), fold_axis=fold_axis, fold_spacing_mm=15.0,
                   fold_depth_mm=2.0, fold_sharpness=4.0, bump_mm=0.03, vessel_strength=0.85, fold_path=fold_path)

    @classmethod
    def stomach(cls, seed: int = 0) -> "MucosaTexture":
        """Red-orange with irregular rugae (ridged noise, no axis)."""
        return cls(seed=seed, base_rgb=(0.78, 0.22, 0.15), fold_axis=None, fold_spacing_mm=14.0,
                   fold_depth_mm=1.2, fold_sharpness=4.0, vessel_strength=0.4)

    def _params(self) -> np.ndarray:
        if self.fold_path is not None:
            axis: tuple = (0.0, 0.0, 1.0, 2.0)
        else:
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
        if self.fold_path is not None:
            s_m, tangents = self.fold_path.query(np.asarray(points_m, dtype=np.float64))
            path_s, path_t = np.ascontiguousarray(s_m * 1e3), np.ascontiguousarray(tangents)
        else:
            path_s, path_t = np.zeros(len(pts)), np.zeros((len(pts), 3))
        if THREADS < 2 or len(pts) < PARALLEL_MIN_POINTS:
            mucosa(*args, pts, nrm, *rest, albedo, bent, path_s, path_t)
            return albedo, bent
        cuts = np.linspace(0, len(pts), THREADS + 1).astype(int)
        futures = [pool().submit(mucosa, *args, pts[a:b], nrm[a:b], *rest, albedo[a:b], bent[a:b], path_s[a:b],
                                 path_t[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]
        for f in futures:
            f.result()
        return albedo, bent


#: The mucosa of each GI organ: its preset and the fixed axis its circular folds run across (the default
#: torso's organs: their long axis in the torso frame, x left-right, z head-ward; the CT abdomen's organs
#: wind, and take their mid-line as the axis instead: :func:`texture_for`'s ``phantom``).
ORGAN_TEXTURES = {
    "stomach": ("stomach", None),
    "small_intestine": ("small_intestine", (1.0, 0.0, 0.0)),
    "ascending_colon": ("colon", (0.0, 0.0, 1.0)),
    "transverse_colon": ("colon", (1.0, 0.0, 0.0)),
    "descending_colon": ("colon", (0.0, 0.0, 1.0)),
    "large_intestine": ("colon", (0.0, 0.0, 1.0)),
    "oesophagus": ("default", None),
}
PRESETS = ("default", "small_intestine", "colon", "stomach")
#: The centreline whose pieces give a winding lumen's folds their axis (raytrace.body.centreline.GI_TRACT).
_GI_TRACT = "gi_tract"


def texture_for(organ: str | None, preset: str = "auto", fold_axis=None, seed: int = 0, *,
                phantom=None) -> MucosaTexture:
    """The texture of a named ``preset`` (one of PRESETS), or for ``preset="auto"`` the one of
    ``organ`` in :data:`ORGAN_TEXTURES` (the plain default for any other organ). ``fold_axis``
    overrides the preset's. With ``phantom`` built from real anatomy (the anatomy pipeline's:
    ``phantom.metadata["source"] == "anatomy"``, e.g. ``abdomen-ct``), circular folds follow the organ's
    pieces of its ``gi_tract`` centreline (:class:`FoldPath`) instead of a fixed axis, unless ``fold_axis``
    is given. Fixed per organ, never per pose, so frames of a sequence agree."""
    if preset == "auto":
        preset, axis = ORGAN_TEXTURES.get(organ or "", ("default", None))
    elif preset in PRESETS:
        axis = ORGAN_TEXTURES.get(organ or "", (None, None))[1]
    else:
        raise VisionInputError(f"must be auto or one of {', '.join(PRESETS)}, got {preset!r}", "texture.preset")
    path = None
    if fold_axis is not None:
        axis = tuple(float(v) for v in np.asarray(fold_axis, float).reshape(-1))
        if len(axis) != 3 or not np.isfinite(axis).all() or np.linalg.norm(axis) < 1e-12:
            raise VisionInputError("must be a non-zero 3-vector", "texture.fold_axis")
    elif phantom is not None and getattr(phantom, "metadata", {}).get("source") == "anatomy":
        line = getattr(phantom, "centrelines", {}).get(_GI_TRACT)
        if line is not None and organ in {p.organ for p in line.pieces}:
            path = _fold_path(line, organ)
    if preset == "stomach":
        return MucosaTexture.stomach(seed=seed)
    if preset == "default":
        return MucosaTexture(seed=seed, fold_axis=axis, fold_path=path if axis is not None else None)
    return getattr(MucosaTexture, preset)(fold_axis=axis, seed=seed, fold_path=path)


@functools.lru_cache(maxsize=16)  # per (centreline, organ): a winding lumen's fold axis, built once
def _fold_path(line, organ: str) -> FoldPath:
    return FoldPath([p.points_m for p in line.pieces if p.organ == organ])


@functools.lru_cache(maxsize=64)  # bounded: a service renders with its callers' seeds
def _perm(seed: int) -> np.ndarray:
    return permutation(seed)
