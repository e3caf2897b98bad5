"""Rotation and scale between two capsule frames by maximum mutual information (thesis Ch. 3).

The pipeline of Section 3.2: both frames are smoothed by the Butterworth low-pass (Eq 3.1,
:mod:`vision.filters`); the moving frame is resampled by cubic convolution (Eq 3.5-3.9,
:mod:`vision.interpolation`) at a trial rotation about the optical axis and a trial scale; the
mutual information of the pair (Eq 3.2-3.4, :mod:`vision.mutual_information`) is maximised over
the trial parameters by Fibonacci (or golden-section) search (:mod:`vision.search`).

Model: the moving frame is the reference with its content rotated by ``rotation_deg``
(counter-clockwise as displayed) and magnified by ``scale`` about the frame centre (the optical
axis of a centred fisheye): moving(c + M d) = reference(c + d), M = scale * R(rotation)
(:func:`vision.interpolation.similarity_matrix`, :func:`~vision.interpolation.warp_similarity`).

What the thesis leaves open, decided here (docs/vision.md, "The estimator"):

* Bracketing. The MI is unimodal only near its peak; over the thesis' ranges (rotations to
  45 deg, scales 0.2 to 3.0) a bracketing search started on the whole range can converge to a
  side lobe. The search therefore runs coarse to fine on an image pyramid (2 x 2 block means,
  down to ``coarse_size_px``, or to the disc radius that still shows the zoomed-out frame's
  content over 3.5 pixels at the extreme scales of the range, never finer than 64 px; a grid
  beyond MAX_GRID_SAMPLES gets a coarser step): at the coarsest level a grid
  with a step of one pixel of arc at the disc's edge finds the bracket; at every level the
  search shrinks a bracket of +-2 grid steps of the coarser level (+-1 at full resolution) to
  a quarter of this level's step, and at full resolution to the requested tolerances.
* Field of view. Pixels are compared inside a disc (``radius_px``, default the inscribed disc
  less 2 pixels): rotations about the centre never move pixels in or out of it.
* Overlap. The comparison runs over the frame that is zoomed IN (the reference disc for
  scale <= 1, the moving disc, sampling the reference at M^-1, for scale > 1), so every probe
  compares a whole disc and the MI of probes at different scales has the same pixel count and
  the same histogram bias. One search uses one side (the side of its bracket's middle).
* Bins per level: ``min(bins, sqrt(N) / 2)`` (at least 8) for N disc pixels, so coarse levels
  are not dominated by the (B - 1)^2 / (2 N) bias; full resolution uses ``bins``.
* Pixels per level: at most ``max_pixels`` (default 2^17) are compared, a regular diagonal
  lattice of the disc beyond (a checkerboard for 512 px frames), as registration libraries
  sample their metric: it halves the cost of the finest level of a 512 px pair; the coarser
  levels, which only bracket the next, compare at most a quarter of that (COARSE_PIXELS_FRACTION);
  the bins and grey ranges still come from every pixel of the disc.
* Parameters: the rotation in degrees, the scale through its logarithm (a step in log scale is
  the same image displacement at every scale).

Strategies: ``in_turn`` (the thesis' way: a rotation search, then a scale search; on the
coarsest grid rotation, scale and rotation again) or ``joint`` (default: a 2-D grid of rotation
and scale at the coarsest level). Both then refine one rotation and one scale search per level;
at full resolution the pair repeats in narrow brackets until neither moves (a cyclic coordinate
ascent to the joint maximum). ``in_turn`` fails when both parameters are far from identity at
once (a rotation grid at scale 1 sees nothing of a frame zoomed by 1.5); ``joint`` does not.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from .errors import VisionInputError
from .filters import DEFAULT_CUTOFF, DEFAULT_ORDER, butterworth_lowpass, to_grey
from .interpolation import THESIS_A, check_kernel_a, frame_center, similarity_matrix
from .kernels import fisheye_joint_histograms, histogram_mutual_information, pad_frame, warped_joint_histograms
from .mutual_information import DEFAULT_BINS, check_bins, grey_range, quantize
from .pool import pool
from .search import SEARCHES, maximise

ESTIMATES = ("both", "rotation", "scale")
STRATEGIES = ("in_turn", "joint")
#: Pixels on a side of a frame: below, too little to register; above, the work bound.
MIN_SIZE_PX, MAX_SIZE_PX = 16, 2048
#: The bracketing (coarsest) level keeps a disc radius of at least MIN_RADIUS_PX pixels, and
#: of CONTENT_RADIUS_PX pixels for the content of the zoomed-out frame at the extreme scales.
MIN_RADIUS_PX, CONTENT_RADIUS_PX = 7.0, 3.5
#: ... but never finer than a 64 px level (a grid of 1 px steps on a finer one costs too much).
MAX_BRACKET_RADIUS_PX = 31.0
#: Default scale ranges: estimating both (consecutive frames), estimating scale alone (the
#: thesis' synthetic scalings 0.2 to 3.0).
SCALE_RANGE_BOTH, SCALE_RANGE_ALONE = (0.5, 2.0), (0.15, 5.0)
#: Refinement bracket: +- this many grid steps of the next coarser level (+- FINE_BRACKET_STEPS
#: at full resolution, where the coarser level has seen the frame's content).
BRACKET_STEPS, FINE_BRACKET_STEPS = 2.0, 1.0
#: Work bound of the bracketing grid: probes x compared pixels (~0.5 s); beyond, the grid
#: step grows (and the first refinement bracket with it).
MAX_GRID_SAMPLES = 2e7
#: Compared pixels per level at most (default of ``max_pixels``; a regular lattice beyond).
MAX_PIXELS = 2**17
#: ... and at the coarser levels, which only bracket the next one (to a quarter of their grid
#: step), at most this fraction of it (a checkerboard of the 256 px level of a 512 px pair).
COARSE_PIXELS_FRACTION = 0.25
#: At full resolution, rotation and scale searches alternate at most this many times.
FINAL_CYCLES = 2
#: Tilt model: the largest tilt searched by default [deg] and the default tolerance [deg].
TILT_RANGE_DEG, TILT_TOLERANCE_DEG = 12.0, 0.01


@dataclass(frozen=True)
class MotionEstimate:
    """The result of :func:`estimate_motion`: the estimates, the MI reached (nats, full
    resolution, ``bins`` bins), search iterations (bracket reductions) and MI evaluations over
    all levels, and the pyramid levels used."""

    rotation_deg: float
    scale: float
    mutual_information: float
    iterations: int
    evaluations: int
    levels: int
    settings: dict = field(default_factory=dict, compare=False)
    #: The moving camera's optical axis as seen from the reference camera, (x right, y up) [deg]
    #: (module doc, "Tilt"); (0, 0) when the tilt is not estimated.
    tilt_deg: tuple[float, float] = (0.0, 0.0)


def _tilt_matrices(tx: np.ndarray, ty: np.ndarray) -> np.ndarray:
    """(K, 3, 3) the smallest rotations taking the optical axis z to the direction of tilt
    (tx, ty) [rad] (x right, y up: the moving camera's axis seen from the reference camera at
    angle hypot(tx, ty) from the axis, azimuth atan2(ty, tx)); Rodrigues' formula about
    z x d."""
    beta = np.hypot(tx, ty)
    safe = np.where(beta > 0.0, beta, 1.0)
    kx, ky = -ty / safe, tx / safe
    sb, cb1 = np.sin(beta), 1.0 - np.cos(beta)
    zero = np.zeros_like(beta)
    k = np.stack([np.stack([zero, zero, ky], -1), np.stack([zero, zero, -kx], -1),
                  np.stack([-ky, kx, zero], -1)], -2)
    return np.eye(3) + sb[:, None, None] * k + cb1[:, None, None] * (k @ k)


def _roll_matrices(rotation_deg: np.ndarray) -> np.ndarray:
    """(K, 3, 3) rotations by ``rotation_deg`` about z, (x, y) -> (c x - s y, s x + c y)."""
    t = np.radians(rotation_deg)
    c, s = np.cos(t), np.sin(t)
    one, zero = np.ones_like(t), np.zeros_like(t)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)


def camera_rotation_params(rotation_deg, log_scale, tilt_x_rad, tilt_y_rad, side: int) -> np.ndarray:
    """(K, 11) probes of :func:`vision.kernels.fisheye_joint_histograms` (module doc, "Tilt"):
    a reference ray u_ref and a moving ray u_mov see the same wall point when
    u_ref = T(tilt) Rz(-rotation) u_mov(theta / scale). ``side`` 0 maps reference pixels into the
    moving frame (A = Rz(rotation) T^T, then radius * scale), 1 moving pixels into the reference
    (angle / scale, then A = T Rz(-rotation))."""
    rot, ls, tx, ty = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float))
                                            for v in (rotation_deg, log_scale, tilt_x_rad, tilt_y_rad)))
    t = _tilt_matrices(tx.ravel(), ty.ravel())
    if side == 0:
        mats = _roll_matrices(rot.ravel()) @ np.swapaxes(t, 1, 2)
        pre, post = np.ones(rot.size), np.exp(ls.ravel())
    else:
        mats = t @ _roll_matrices(-rot.ravel())
        pre, post = np.exp(-ls.ravel()), np.ones(rot.size)
    return np.concatenate([pre[:, None], post[:, None], mats.reshape(-1, 9)], axis=1)


@dataclass
class _Level:
    """One pyramid level of the pair: per side (0 reference, 1 moving) the disc pixels, their
    bins, and the frame with its quantisation range."""

    frames: tuple[np.ndarray, np.ndarray]  # padded (kernels.pad_frame)
    center: tuple[float, float]
    radius_px: float
    bins: int
    pixels: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]
    ranges: tuple[tuple[float, float], tuple[float, float]]
    focal_px: float | None = None  # the fisheye's f (tilt model), None: the similarity model
    rays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # theta, cos phi, sin phi

    @classmethod
    def build(cls, ref: np.ndarray, mov: np.ndarray, center, radius_px: float, bins: int,
              max_pixels: float = math.inf, focal_px: float | None = None) -> "_Level":
        n, disc, compared, rows, cols = _disc_geometry(ref.shape, center, radius_px, max_pixels)
        bins = int(min(bins, max(8, math.isqrt(n) // 2)))
        flat = (ref.ravel(), mov.ravel())
        ranges = tuple(grey_range(img[disc]) for img in flat)
        pixels = tuple((rows, cols, quantize(img[compared], bins, *rng)) for img, rng in zip(flat, ranges))
        rays = None
        if focal_px is not None:
            x, y = cols - center[1], center[0] - rows
            r = np.hypot(x, y)
            safe = np.where(r > 0.0, r, 1.0)
            rays = (r / focal_px, np.where(r > 0.0, x / safe, 1.0), np.where(r > 0.0, y / safe, 0.0))
        return cls((pad_frame(ref), pad_frame(mov)), center, radius_px, bins, pixels, ranges, focal_px, rays)

    def mutual_information(self, rotation_deg: np.ndarray, log_scale: np.ndarray, side: int | None = None,
                           a: float = THESIS_A, tilt=(0.0, 0.0)) -> np.ndarray:
        """MI at each (rotation, log scale[, tilt x, tilt y in rad]) probe; ``side`` 0 compares
        over the reference disc, 1 over the moving disc, None picks per probe by the sign of log
        scale (module doc). The tilt is used only by a level built with ``focal_px``."""
        rot = np.atleast_1d(np.asarray(rotation_deg, float))
        ls = np.atleast_1d(np.asarray(log_scale, float))
        tx, ty = (np.atleast_1d(np.asarray(v, float)) for v in tilt)
        rot, ls, tx, ty = np.broadcast_arrays(rot, ls, tx, ty)
        sides = (ls > 0.0).astype(int) if side is None else np.full(rot.shape, side)
        out = np.empty(rot.shape)
        for s in (0, 1):
            pick = sides == s
            if not pick.any():
                continue
            rows, cols, qbins = self.pixels[s]
            lo, width = self.ranges[1 - s]
            if self.focal_px is not None:
                params = camera_rotation_params(rot[pick], ls[pick], tx[pick], ty[pick], s)
                hist = fisheye_joint_histograms(*self.rays, qbins, self.frames[1 - s], params, self.center,
                                                self.focal_px, self.radius_px, lo, width, self.bins, a)
                out[pick] = histogram_mutual_information(hist)
                continue
            # side 1 samples the reference at M^-1 = similarity(-rotation, 1 / scale)
            sign = 1.0 if s == 0 else -1.0
            mats = similarity_matrix(sign * rot[pick], np.exp(sign * ls[pick]))
            hist = warped_joint_histograms(rows, cols, qbins, self.frames[1 - s], mats, self.center,
                                           self.radius_px, lo, width, self.bins, a)
            out[pick] = histogram_mutual_information(hist)
        return out


@functools.lru_cache(maxsize=8)  # bounded: a 2048 px frame's entry holds ~7 MB
def _disc_geometry(shape: tuple[int, int], center: tuple[float, float], radius_px: float, max_pixels: float):
    """(n, disc, compared, rows, cols) of a level (module doc): the disc's pixel count and flat
    mask, the flat indices of the compared pixels (the disc, or a diagonal lattice of it when it
    holds more than ``max_pixels``: a checkerboard for stride 2) and their rows and columns
    (float). The same for every pair of one frame size, so made once (read-only arrays)."""
    r = np.arange(shape[0])[:, None]
    c = np.arange(shape[1])[None, :]
    inside = (r - center[0]) ** 2 + (c - center[1]) ** 2 <= radius_px**2
    n = int(inside.sum())
    stride = max(1, math.ceil(n / max_pixels))
    lattice = inside & ((r + c) % stride == 0) if stride > 1 else inside
    disc, compared = inside.ravel(), np.flatnonzero(lattice)
    rows, cols = (x.astype(float) for x in np.divmod(compared, shape[1]))
    for x in (disc, compared, rows, cols):
        x.flags.writeable = False
    return n, disc, compared, rows, cols


def _downsample(img: np.ndarray) -> np.ndarray:
    """2 x 2 block means (odd trailing row / column dropped)."""
    h, w = img.shape[0] // 2 * 2, img.shape[1] // 2 * 2
    return 0.25 * (img[0:h:2, 0:w:2] + img[1:h:2, 0:w:2] + img[0:h:2, 1:w:2] + img[1:h:2, 1:w:2])


def _pyramid(ref, mov, radius_px: float, bins: int, coarse_size_px: int, min_radius_px: float,
             max_pixels: float = math.inf, focal_px: float | None = None) -> list[_Level]:
    """Levels finest first, down to frames of ``coarse_size_px`` pixels a side or a disc radius
    of ``min_radius_px``, whichever comes first; a coarse pixel k covers fine pixels 2k, 2k + 1,
    so the centre maps as c_coarse = (c_fine - 1/2) / 2 and the same rotation and scale hold at
    every level (and the same tilt, with the fisheye's f halved per level)."""
    center = frame_center(ref.shape)
    levels = [_Level.build(ref, mov, center, radius_px, bins, max_pixels, focal_px)]
    while min(ref.shape) // 2 >= coarse_size_px and radius_px / 2.0 >= min_radius_px:
        ref, mov = _downsample(ref), _downsample(mov)
        center = ((center[0] - 0.5) / 2.0, (center[1] - 0.5) / 2.0)
        radius_px /= 2.0
        focal_px = None if focal_px is None else focal_px / 2.0
        levels.append(_Level.build(ref, mov, center, radius_px, bins, max_pixels * COARSE_PIXELS_FRACTION,
                                   focal_px=focal_px))
    return levels


def _range(value, field_name: str, lo: float, hi: float) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in value)
    except (TypeError, ValueError):
        raise VisionInputError(f"must be a pair of numbers (low, high), got {value!r}", field_name) from None
    if not (math.isfinite(a) and math.isfinite(b) and lo <= a < b <= hi):
        raise VisionInputError(f"must satisfy {lo} <= low < high <= {hi}, got ({a}, {b})", field_name)
    return a, b


def _positive(value, field_name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise VisionInputError(f"must be a number, got {value!r}", field_name) from None
    if not (math.isfinite(out) and out > 0.0):
        raise VisionInputError(f"must be a finite number > 0, got {value!r}", field_name)
    return out


class _Search:
    """The coarse-to-fine maximisation of :func:`estimate_motion` (module doc) over the pyramid
    ``levels`` (finest first), counting iterations and MI evaluations. ``tilt_range`` [rad] > 0:
    the tilt (x, y) is searched too (levels built with the fisheye's f); it is kept in
    ``self.tilt``."""

    def __init__(self, levels: list[_Level], a: float, method: str, estimate: str,
                 rot_range: tuple[float, float], ls_range: tuple[float, float], tilt_range: float = 0.0) -> None:
        self.levels, self.a, self.method = levels, a, method
        self.do_rot = estimate in ("both", "rotation")
        self.do_scale = estimate in ("both", "scale")
        self.do_tilt = tilt_range > 0.0
        self.rot_range, self.ls_range = rot_range, ls_range
        self.tilt_range = (-tilt_range, tilt_range)
        self.tilt = [0.0, 0.0]
        self.iterations = 0
        self.evaluations = 0
        self.grid_factor = 1.0  # > 1 when the coarsest grid was coarsened (work bound)
        self._memo: dict = {}  # single probes already evaluated: (level, rot, ls, side, tilt) -> MI

    def probe(self, index: int, rot: float, ls: float, side: int) -> float:
        """The MI of one probe at level ``index``, evaluated once: a search's last probe is where
        the next search, or the final MI, starts."""
        key = (index, rot, ls, side, *self.tilt)
        value = self._memo.get(key)
        if value is None:
            value = self._memo[key] = float(self.levels[index].mutual_information(rot, ls, side, self.a,
                                                                                  self.tilt)[0])
            self.evaluations += 1
        return value

    @staticmethod
    def step(level: _Level) -> float:
        """The grid step at a level: one pixel at the disc edge, as a log-scale step (radians of
        rotation; :func:`math.degrees` of it in degrees)."""
        return 1.0 / level.radius_px

    @staticmethod
    def tilt_step(level: _Level) -> float:
        """One pixel near the optical axis, as a tilt [rad]."""
        return 1.0 / level.focal_px

    def _grid(self, lo: float, hi: float, step: float) -> np.ndarray:
        return np.linspace(lo, hi, max(3, int(math.ceil((hi - lo) / step)) + 1))

    def _mi(self, level: _Level, rot, ls, side: int | None, tilt=None) -> np.ndarray:
        values = level.mutual_information(rot, ls, side, self.a, self.tilt if tilt is None else tilt)
        self.evaluations += values.size
        return values

    def bracket(self, rot: float, ls: float, joint: bool) -> tuple[float, float]:
        """The best grid point at the coarsest level: a 2-D grid (``joint``), or 1-D grids of
        rotation, scale and rotation again in turn; with the tilt, then a 2-D grid of tilts at
        that rotation and scale, and the rotation and scale grid again at the best tilt."""
        rot, ls = self._bracket(rot, ls, joint)
        if self.do_tilt:
            level = self.levels[-1]
            g = self._grid(*self.tilt_range, self.tilt_step(level))
            tx, ty = (x.ravel() for x in np.meshgrid(g, g, indexing="ij"))
            best = int(np.argmax(self._mi(level, rot, ls, None, (tx, ty))))
            self.tilt = [float(tx[best]), float(ty[best])]
            rot, ls = self._bracket(rot, ls, joint)
        return rot, ls

    def _bracket(self, rot: float, ls: float, joint: bool) -> tuple[float, float]:
        level = self.levels[-1]
        step = self.step(level)
        two_d = joint and self.do_rot and self.do_scale
        spans = ((self.rot_range[1] - self.rot_range[0]) / math.degrees(step) if self.do_rot else 1.0) * (
            (self.ls_range[1] - self.ls_range[0]) / step if self.do_scale else 1.0)
        samples = (spans if two_d else 3.0 * spans ** (1.0 if not (self.do_rot and self.do_scale) else 0.5)) \
            * len(level.pixels[0][0])
        if samples > MAX_GRID_SAMPLES:  # work bound: a coarser grid, and wider refinement brackets
            self.grid_factor = (samples / MAX_GRID_SAMPLES) ** (0.5 if two_d else 1.0)
            step *= self.grid_factor
        g_rot = self._grid(*self.rot_range, math.degrees(step))
        g_ls = self._grid(*self.ls_range, step)
        if two_d:
            tt, gg = (x.ravel() for x in np.meshgrid(g_rot, g_ls, indexing="ij"))
            best = int(np.argmax(self._mi(level, tt, gg, None)))
            return float(tt[best]), float(gg[best])
        turns = ["rot", "ls", "rot"] if (self.do_rot and self.do_scale) else (["rot"] if self.do_rot else ["ls"])
        for which in turns:
            if which == "rot":
                rot = float(g_rot[np.argmax(self._mi(level, g_rot, ls, None))])
            else:
                ls = float(g_ls[np.argmax(self._mi(level, rot, g_ls, None))])
        return rot, ls

    def _maximise(self, index: int, which: str, centre: float, span: float, tol: float,
                  rot: float, ls: float) -> float:
        lo_lim, hi_lim = {"rot": self.rot_range, "ls": self.ls_range}.get(which, self.tilt_range)
        lo, hi = max(lo_lim, centre - span), min(hi_lim, centre + span)
        side = int(0.5 * (lo + hi) > 0.0) if which == "ls" else int(ls > 0.0)
        if which == "rot":
            def f(t):
                return self.probe(index, t, ls, side)
        elif which == "ls":
            def f(g):
                return self.probe(index, rot, g, side)
        else:
            axis = 0 if which == "tx" else 1
            level = self.levels[index]

            def f(v):
                tilt = list(self.tilt)
                tilt[axis] = v
                self.evaluations += 1
                return level.mutual_information(rot, ls, side, self.a, tilt)[0]
        result = maximise(f, lo, hi, tol, self.method)
        self.iterations += result.iterations
        return result.x

    def refine(self, index: int, rot: float, ls: float, tol_rot: float, tol_ls: float,
               tol_tilt: float = 0.0) -> tuple[float, float]:
        """One rotation and one scale search (and one per tilt axis) at level ``index``, each in
        a bracket of +-BRACKET_STEPS grid steps of the coarser level (of this level on the
        coarsest), to a quarter of this level's step, or to the tolerances at full resolution.
        There, when both parameters are estimated, the searches repeat in brackets of +-4
        tolerances (at most FINAL_CYCLES rounds in all) until none moves by more than twice its
        tolerance: the rotation found at the coarser level's scale is re-optimised at the new
        scale (they are nearly independent: rotation moves pixels along circles, scale along
        radii)."""
        level = self.levels[index]
        coarser = self.levels[min(index + 1, len(self.levels) - 1)]
        span_ls = (FINE_BRACKET_STEPS if index == 0 else BRACKET_STEPS) * self.step(coarser)
        if index == len(self.levels) - 1:
            span_ls *= self.grid_factor
        span_rot = math.degrees(span_ls)
        finest = index == 0
        t_ls = tol_ls if finest else 0.25 * self.step(level)
        t_rot = tol_rot if finest else math.degrees(t_ls)
        if self.do_tilt:
            span_tilt = (FINE_BRACKET_STEPS if finest else BRACKET_STEPS) * self.tilt_step(coarser)
            t_tilt = tol_tilt if finest else 0.25 * self.tilt_step(level)
        for cycle in range(FINAL_CYCLES if finest and (self.do_rot and self.do_scale or self.do_tilt) else 1):
            old = (rot, ls, *self.tilt)
            if self.do_tilt:
                for axis, name in enumerate(("tx", "ty")):
                    self.tilt[axis] = self._maximise(index, name, self.tilt[axis], span_tilt, t_tilt, rot, ls)
            if self.do_rot:
                rot = self._maximise(index, "rot", rot, span_rot, t_rot, rot, ls)
                if cycle > 0 and not self.do_tilt and abs(rot - old[0]) <= 2.0 * t_rot:
                    break  # converged: the last scale search ran at (within tolerance) this rotation
            if self.do_scale:
                ls = self._maximise(index, "ls", ls, span_ls, t_ls, rot, ls)
            moved = abs(rot - old[0]) > 2.0 * t_rot or abs(ls - old[1]) > 2.0 * t_ls
            if self.do_tilt:
                moved = moved or max(abs(self.tilt[0] - old[2]), abs(self.tilt[1] - old[3])) > 2.0 * t_tilt
                span_tilt = 4.0 * t_tilt
            if not moved:
                break
            span_rot, span_ls = 4.0 * t_rot, 4.0 * t_ls
        return rot, ls


def estimate_motion(reference: np.ndarray, moving: np.ndarray, *, estimate: str = "both",
                    strategy: str = "joint", search: str = "fibonacci",
                    rotation_range_deg: tuple[float, float] = (-90.0, 90.0),
                    scale_range: tuple[float, float] | None = None,
                    rotation_tolerance_deg: float = 0.005, scale_tolerance: float = 0.0005,
                    initial_rotation_deg: float = 0.0, initial_scale: float = 1.0,
                    bins: int = DEFAULT_BINS, cutoff: float | None = DEFAULT_CUTOFF, order: int = DEFAULT_ORDER,
                    kernel_a: float = THESIS_A, radius_px: float | None = None,
                    coarse_size_px: int = 16, max_pixels: int = MAX_PIXELS, fov_deg: float | None = None,
                    tilt_range_deg: float = TILT_RANGE_DEG,
                    tilt_tolerance_deg: float = TILT_TOLERANCE_DEG) -> MotionEstimate:
    """Rotation about the optical axis and scale of ``moving`` relative to ``reference`` (module
    doc: model, sign conventions, strategy), by maximum mutual information.

    Frames: grey (H, W) or colour (H, W, 3|4) arrays of the same shape, 16 to 2048 pixels a side.
    ``estimate``: "both", "rotation" (scale held at ``initial_scale``) or "scale" (rotation held
    at ``initial_rotation_deg``). ``search``: "fibonacci" or "golden". Tolerances: the final
    bracket widths (rotation in degrees; scale relative, as a width in log scale). ``bins``:
    grey-level bins per frame at full resolution. ``cutoff`` / ``order``: the Butterworth
    pre-filter (``cutoff=None``: none). ``kernel_a``: -1 the thesis' Eq 3.9, -0.5 Keys'.
    ``radius_px``: radius of the compared disc (default min(H, W) / 2 - 2). ``coarse_size_px``:
    the smallest pyramid level's side. ``max_pixels``: pixels compared per level at most (a
    regular lattice of the disc beyond; default 2^17, a 408 px disc; module doc).
    ``fov_deg``: the field of view of the equidistant fisheye whose image circle is inscribed in
    the frame (:class:`vision.camera.FisheyeCamera`); given, the moving camera's tilt (its
    optical axis seen from the reference camera) is estimated too, within +-``tilt_range_deg``
    per axis, to ``tilt_tolerance_deg`` (module doc, "Tilt"); None: the thesis' similarity model.
    """
    if estimate not in ESTIMATES:
        raise VisionInputError(f"must be one of {', '.join(ESTIMATES)}, got {estimate!r}", "estimate")
    if strategy not in STRATEGIES:
        raise VisionInputError(f"must be one of {', '.join(STRATEGIES)}, got {strategy!r}", "strategy")
    if search not in SEARCHES:
        raise VisionInputError(f"must be one of {', '.join(SEARCHES)}, got {search!r}", "search")
    rot_lo, rot_hi = _range(rotation_range_deg, "rotation_range_deg", -180.0, 180.0)
    if scale_range is None:
        scale_range = SCALE_RANGE_BOTH if estimate == "both" else SCALE_RANGE_ALONE
    s_lo, s_hi = _range(scale_range, "scale_range", 0.05, 20.0)
    tol_rot = _positive(rotation_tolerance_deg, "rotation_tolerance_deg")
    tol_ls = _positive(scale_tolerance, "scale_tolerance")
    for value, name in ((tol_rot, "rotation_tolerance_deg"), (tol_ls, "scale_tolerance")):
        if not 1e-7 <= value <= 1.0:
            raise VisionInputError(f"must be in [1e-7, 1], got {value!r}", name)
    rot0 = float(initial_rotation_deg)
    ls0 = math.log(_positive(initial_scale, "initial_scale"))
    if not math.isfinite(rot0):
        raise VisionInputError("must be finite", "initial_rotation_deg")
    bins = check_bins(bins)
    a = check_kernel_a(kernel_a)
    tilt_range = 0.0
    if fov_deg is not None:
        fov = _positive(fov_deg, "fov_deg")
        if not 10.0 <= fov <= 220.0:
            raise VisionInputError(f"must be in [10, 220] degrees, got {fov_deg!r}", "fov_deg")
        tilt_range = math.radians(_positive(tilt_range_deg, "tilt_range_deg"))
        if tilt_range > math.radians(45.0):
            raise VisionInputError(f"must be in (0, 45] degrees, got {tilt_range_deg!r}", "tilt_range_deg")
        tol_tilt = math.radians(_positive(tilt_tolerance_deg, "tilt_tolerance_deg"))
        if not 1e-7 <= tol_tilt <= tilt_range:
            raise VisionInputError(f"must be in [1e-7 rad, tilt_range_deg], got {tilt_tolerance_deg!r}",
                                   "tilt_tolerance_deg")
    ref, mov = to_grey(reference, "reference"), to_grey(moving, "moving")
    if ref.shape != mov.shape:
        raise VisionInputError(f"frames differ in size: reference {ref.shape[1]} x {ref.shape[0]}, "
                               f"moving {mov.shape[1]} x {mov.shape[0]}", "moving")
    if not (MIN_SIZE_PX <= min(ref.shape) and max(ref.shape) <= MAX_SIZE_PX):
        raise VisionInputError(f"frames must be {MIN_SIZE_PX} to {MAX_SIZE_PX} pixels a side, got "
                               f"{ref.shape[1]} x {ref.shape[0]}", "reference")
    max_radius = min(ref.shape) / 2.0 - 2.0
    radius = max_radius if radius_px is None else _positive(radius_px, "radius_px")
    if radius > max_radius or radius < 6.0:
        raise VisionInputError(f"must be in [6, {max_radius:g}] for these frames, got {radius_px!r}", "radius_px")
    center = frame_center(ref.shape)
    rr, cc = np.ogrid[:ref.shape[0], :ref.shape[1]]
    disc = (rr - center[0]) ** 2 + (cc - center[1]) ** 2 <= radius**2
    for frame, name in ((ref, "reference"), (mov, "moving")):
        inside = frame[disc]
        if inside.max() == inside.min():  # MI is 0 at every probe: no estimate exists
            raise VisionInputError(f"is constant ({inside[0]:g}) inside the compared disc of radius {radius:g} "
                                   "px: there is nothing to register", name)
    if cutoff is not None:
        # the two frames on the pool's two threads (scipy's FFTs release the GIL)
        filtered = [pool().submit(butterworth_lowpass, frame, cutoff, order) for frame in (ref, mov)]
        ref, mov = (f.result() for f in filtered)
    coarse = int(coarse_size_px)
    if not 16 <= coarse <= MAX_SIZE_PX:
        raise VisionInputError(f"must be in [16, {MAX_SIZE_PX}], got {coarse_size_px!r}", "coarse_size_px")

    # the bracketing level must show the zoomed-OUT frame's content over >= CONTENT_RADIUS_PX
    # pixels at the extreme scales of the range (a scale 0.2 squeezes a 16 px frame into 3 px)
    min_radius = min(MAX_BRACKET_RADIUS_PX, max(MIN_RADIUS_PX, CONTENT_RADIUS_PX / min(s_lo, 1.0 / s_hi)))
    if isinstance(max_pixels, bool) or not isinstance(max_pixels, (int, np.integer)) or max_pixels < 1024:
        raise VisionInputError(f"must be an integer >= 1024, got {max_pixels!r}", "max_pixels")
    focal = None if fov_deg is None else (min(ref.shape) / 2.0) / math.radians(fov / 2.0)
    levels = _pyramid(ref, mov, radius, bins, coarse, min_radius, int(max_pixels), focal)
    search_ = _Search(levels, a, search, estimate, (rot_lo, rot_hi), (math.log(s_lo), math.log(s_hi)), tilt_range)
    rot = min(max(rot0, rot_lo), rot_hi) if search_.do_rot else rot0
    ls = min(max(ls0, search_.ls_range[0]), search_.ls_range[1]) if search_.do_scale else ls0
    rot, ls = search_.bracket(rot, ls, joint=strategy == "joint")
    for index in range(len(levels) - 1, -1, -1):
        rot, ls = search_.refine(index, rot, ls, tol_rot, tol_ls, tol_tilt if tilt_range else 0.0)

    mi = search_.probe(0, rot, ls, int(ls > 0.0))
    settings = {"estimate": estimate, "strategy": strategy, "search": search, "bins": bins, "cutoff": cutoff,
                "order": order, "kernel_a": a, "radius_px": radius, "max_pixels": int(max_pixels),
                "fov_deg": fov_deg}
    return MotionEstimate(rotation_deg=float(rot), scale=float(math.exp(ls)), mutual_information=mi,
                          iterations=search_.iterations, evaluations=search_.evaluations, levels=len(levels),
                          settings=settings, tilt_deg=(math.degrees(search_.tilt[0]), math.degrees(search_.tilt[1])))


def estimate_rotation(reference: np.ndarray, moving: np.ndarray, **kwargs) -> MotionEstimate:
    """:func:`estimate_motion` with ``estimate="rotation"`` (the thesis' Table 3.2 case)."""
    return estimate_motion(reference, moving, estimate="rotation", **kwargs)


def estimate_scale(reference: np.ndarray, moving: np.ndarray, **kwargs) -> MotionEstimate:
    """:func:`estimate_motion` with ``estimate="scale"`` (the thesis' Table 3.1 case)."""
    return estimate_motion(reference, moving, estimate="scale", **kwargs)
