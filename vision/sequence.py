"""A capsule moving along a path: poses with known advance and roll per frame, and their frames.

The path is a polyline of points (metres, phantom frame), e.g. a lumen's centreline (the torso's
GI centreline is to come; any polyline works). Frame k sits at arc length s_k = s_0 + the sum of
the advances before it, looks along the path's tangent there (the direction of the polyline's
segment), and has rolled by the sum of the roll increments. The camera's up vector is carried
along the path by parallel transport (at a polyline vertex it turns by the smallest rotation
taking one segment's direction to the next), so a bend of the path adds no roll of its own: the
roll of the ground truth is exactly the sum of the requested increments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from raytrace import InputError

from .camera import FisheyeCamera, Pose, rotate_about
from .errors import VisionInputError
from .render import Frame, Lighting, render_frame
from .sensor import SensorModel

#: Frames per sequence at most (work bound).
MAX_FRAMES = 1000


@dataclass(frozen=True)
class Path:
    """A polyline (K >= 2 points, consecutive points distinct) parametrised by arc length."""

    points_m: np.ndarray

    def __post_init__(self) -> None:
        p = np.asarray(self.points_m, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2 or not np.isfinite(p).all():
            raise VisionInputError(f"must be at least 2 points of 3 finite coordinates, got shape {p.shape}",
                                   "path.points_m")
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        if np.any(seg < 1e-9):
            raise VisionInputError("consecutive points must be distinct", "path.points_m")
        object.__setattr__(self, "points_m", p)

    @property
    def cumulative_m(self) -> np.ndarray:
        """(K,) arc length at every vertex."""
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.points_m, axis=0), axis=1))])

    @property
    def length_m(self) -> float:
        return float(self.cumulative_m[-1])

    def segment(self, s_m: float) -> int:
        """Index of the segment holding arc length ``s_m`` (the later one at a vertex)."""
        return int(np.clip(np.searchsorted(self.cumulative_m, s_m, side="right") - 1, 0, len(self.points_m) - 2))

    def at(self, s_m: float) -> tuple[np.ndarray, np.ndarray]:
        """(position, unit tangent) at arc length ``s_m`` in [0, length]."""
        if not (math.isfinite(s_m) and -1e-12 <= s_m <= self.length_m + 1e-12):
            raise VisionInputError(f"arc length {s_m!r} m is off the path (length {self.length_m:.6g} m)", "path")
        k = self.segment(s_m)
        a, b = self.points_m[k], self.points_m[k + 1]
        tangent = (b - a) / np.linalg.norm(b - a)
        return a + (s_m - self.cumulative_m[k]) * tangent, tangent


def _per_step(value, steps: int, field_name: str) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.ndim == 0:
        a = np.full(steps, float(a))
    if a.shape != (steps,) or not np.isfinite(a).all():
        raise VisionInputError(f"must be a number or {steps} numbers (one per step), got shape {a.shape}", field_name)
    return a


@dataclass(frozen=True)
class SequencePoses:
    """Ground truth of a sequence: the poses, their arc lengths and cumulative rolls."""

    poses: list[Pose]
    s_m: np.ndarray
    roll_deg: np.ndarray


def sequence_poses(path: Path, frames: int, advance_m, roll_deg, *, start_m: float = 0.0,
                   start_roll_deg: float = 0.0, up_hint=None) -> SequencePoses:
    """Poses of ``frames`` frames along ``path`` (module doc): ``advance_m`` and ``roll_deg`` are
    the increments from each frame to the next (a number, or ``frames - 1`` numbers)."""
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or not 1 <= frames <= MAX_FRAMES:
        raise VisionInputError(f"must be an integer in [1, {MAX_FRAMES}], got {frames!r}", "frames")
    adv = _per_step(advance_m, frames - 1, "advance_m")
    roll = _per_step(roll_deg, frames - 1, "roll_deg")
    s = float(start_m) + np.concatenate([[0.0], np.cumsum(adv)])
    rolls = float(start_roll_deg) + np.concatenate([[0.0], np.cumsum(roll)])
    if s.min() < -1e-12 or s.max() > path.length_m + 1e-12:
        raise VisionInputError(f"the sequence runs from {s.min():.6g} to {s.max():.6g} m along a path of "
                               f"{path.length_m:.6g} m", "advance_m")
    poses = []
    position, tangent = path.at(float(s[0]))
    up = Pose(position, tangent, 0.0, up_hint).basis[1]
    for k in range(frames):
        position, new_tangent = path.at(float(s[k]))
        axis = np.cross(tangent, new_tangent)
        sin_a = float(np.linalg.norm(axis))
        if sin_a > 1e-12:  # parallel transport of the up vector across a bend
            up = rotate_about(up, axis / sin_a, math.atan2(sin_a, float(np.dot(tangent, new_tangent))))
        tangent = new_tangent
        poses.append(Pose(position, tangent, float(rolls[k]), up))
    return SequencePoses(poses=poses, s_m=s, roll_deg=rolls)


@dataclass(frozen=True)
class Sequence:
    """Rendered frames and their ground truth."""

    frames: list[Frame]
    truth: SequencePoses
    metadata: dict = field(default_factory=dict)


def render_sequence(phantom, path: Path, frames: int, advance_m, roll_deg, camera: FisheyeCamera | None = None, *,
                    start_m: float = 0.0, start_roll_deg: float = 0.0, up_hint=None,
                    lighting: Lighting | None = None, texture=None, sensor: SensorModel | None = None,
                    exposure: float | None = None, organ: str | None = None) -> Sequence:
    """Render the frames of :func:`sequence_poses`. ``exposure`` None: the automatic exposure of
    the FIRST frame, then held for the whole sequence (so brightness changes are the scene's)."""
    truth = sequence_poses(path, frames, advance_m, roll_deg, start_m=start_m, start_roll_deg=start_roll_deg,
                           up_hint=up_hint)
    out = []
    for k, pose in enumerate(truth.poses):
        frame = render_frame(phantom, pose, camera, lighting=lighting, texture=texture, sensor=sensor,
                             exposure=exposure, organ=organ, frame_index=k)
        exposure = frame.metadata["exposure"]
        out.append(frame)
    return Sequence(frames=out, truth=truth, metadata={"exposure": exposure})


#: The phantoms' GI-tract centreline (raytrace.body.centreline.GI_TRACT).
GI_TRACT = "gi_tract"


def _centreline(phantom, name: str, field_name: str):
    line = getattr(phantom, "centrelines", {}).get(name)
    if line is None:
        raise VisionInputError(f"phantom {phantom.name!r} has no {name!r} centreline: give position_m and direction",
                               field_name)
    return line


def centreline_pose(phantom, s_m: float, roll_deg: float = 0.0, *, centreline: str = GI_TRACT) -> tuple[Pose, str]:
    """The pose at arc length ``s_m`` along the phantom's centreline (on the line, looking along
    the direction of travel, rolled by ``roll_deg`` from the default up, module doc of
    :mod:`vision.camera`) and the organ whose lumen holds it."""
    line = _centreline(phantom, centreline, "pose.s_m")
    try:
        position, tangent, organ = line.point_m(s_m), line.tangent(s_m), line.organ_at(s_m)
    except InputError as exc:
        raise VisionInputError(exc.reason, "pose.s_m") from None
    return Pose(position, tangent, roll_deg), str(organ)


def centreline_path(phantom, start_m: float, length_m: float, *,
                    centreline: str = GI_TRACT) -> tuple[Path, float, str]:
    """The polyline of the centreline piece (one organ's lumen) holding arc lengths ``start_m``
    to ``start_m + length_m``, the start's arc length along that polyline, and the organ. A run
    that would cross into the next organ (the centreline jumps there) is refused."""
    line = _centreline(phantom, centreline, "start_m")
    try:
        organ = str(line.organ_at(start_m))
    except InputError as exc:
        raise VisionInputError(exc.reason, "start_m") from None
    starts = np.concatenate([[0.0], line.junctions_s_m])
    k = int(np.searchsorted(starts, start_m, side="right") - 1)
    piece = line.pieces[k]
    path = Path(piece.points_m)
    offset = float(start_m - starts[k])
    if not 0.0 <= offset + length_m <= path.length_m + 1e-12:
        raise VisionInputError(f"the sequence leaves the {organ} piece of the centreline (arc lengths "
                               f"{starts[k]:.6g} to {starts[k] + path.length_m:.6g} m)", "advance_m")
    return path, offset, organ


def transported_ups(path: Path, up_hint=None) -> np.ndarray:
    """(K - 1, 3) the camera's up vector (roll 0) on each segment of ``path``: the up of the first
    segment from ``up_hint`` (:class:`~vision.camera.Pose`), carried to every later segment by
    parallel transport (the smallest rotation taking one segment's direction to the next, module
    doc). A function of the segment only, so a capsule going back and forth over the same arc
    lengths sees the same frames."""
    seg = np.diff(path.points_m, axis=0)
    tangents = seg / np.linalg.norm(seg, axis=1)[:, None]
    up = Pose(path.points_m[0], tangents[0], 0.0, up_hint).basis[1]
    ups = np.empty_like(tangents)
    ups[0] = up
    for k in range(1, len(tangents)):
        axis = np.cross(tangents[k - 1], tangents[k])
        sin_a = float(np.linalg.norm(axis))
        if sin_a > 1e-12:
            up = rotate_about(up, axis / sin_a, math.atan2(sin_a, float(np.dot(tangents[k - 1], tangents[k]))))
        ups[k] = up
    return ups


def path_pose(path: Path, ups: np.ndarray, s_m: float, roll_deg: float) -> Pose:
    """The pose at arc length ``s_m`` of ``path`` looking along it, rolled by ``roll_deg`` from the
    transported up ``ups`` (:func:`transported_ups`) of its segment."""
    position, tangent = path.at(float(s_m))
    return Pose(position, tangent, float(roll_deg), ups[path.segment(float(s_m))])
