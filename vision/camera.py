"""The capsule camera: an equidistant fisheye and its pose in the phantom.

Projection (the equidistant, "f-theta" fisheye model of wide-angle capsule optics): a ray at
angle theta from the optical axis lands at image radius r = f theta from the principal point,
the frame centre ((H - 1) / 2, (W - 1) / 2). The image circle of the field of view ``fov_deg``
is inscribed in the square frame: r = ``size_px`` / 2 at theta = fov / 2, so
f = (size_px / 2) / (fov / 2) pixels per radian. Pixels outside the circle see nothing (black).

Camera frame: x right, y up (as displayed: rows grow downwards, so y = -(row offset)), z the
view direction. A pixel at offset (x, y) = (col - c_x, c_y - row) looks along
(sin theta cos phi, sin theta sin phi, cos theta) with phi = atan2(y, x).

Pose (:class:`Pose`): a position (metres, phantom frame), a view direction, and a roll about it.
Roll 0 puts the camera's up as close as possible to a reference up (``up_hint``, default +z,
the torso's head-ward axis; -y, anterior, when looking along z). A roll of psi degrees turns the
camera by psi about the view direction by the right-hand rule, i.e. clockwise as seen from
behind the camera, so the scene turns COUNTER-clockwise in the frame by psi: the rotation the
motion estimator reports (``vision.motion``) between a frame and the next is the roll increment.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .errors import VisionInputError

#: Defaults like a small-bowel capsule (a PillCam SB 3 has a 156 deg field of view).
DEFAULT_FOV_DEG = 150.0
DEFAULT_SIZE_PX = 256
MIN_SIZE_PX, MAX_SIZE_PX = 16, 1024


@dataclass(frozen=True)
class FisheyeCamera:
    """An equidistant fisheye of ``fov_deg`` (full angle, 10-220 deg) on a square frame of
    ``size_px`` pixels a side (module doc)."""

    fov_deg: float = DEFAULT_FOV_DEG
    size_px: int = DEFAULT_SIZE_PX

    def __post_init__(self) -> None:
        fov = float(self.fov_deg)
        if not (math.isfinite(fov) and 10.0 <= fov <= 220.0):
            raise VisionInputError(f"must be in [10, 220] degrees, got {self.fov_deg!r}", "camera.fov_deg")
        size = self.size_px
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not MIN_SIZE_PX <= size <= MAX_SIZE_PX:
            raise VisionInputError(f"must be an integer in [{MIN_SIZE_PX}, {MAX_SIZE_PX}], got {size!r}",
                                   "camera.size_px")
        object.__setattr__(self, "fov_deg", fov)
        object.__setattr__(self, "size_px", int(size))

    @property
    def focal_px(self) -> float:
        """f of r = f theta [pixels per radian]."""
        return (self.size_px / 2.0) / math.radians(self.fov_deg / 2.0)

    @property
    def center_px(self) -> float:
        """The principal point's row and column, (size - 1) / 2."""
        return (self.size_px - 1) / 2.0

    @property
    def _rays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return _camera_rays(self.fov_deg, self.size_px)

    @property
    def mask(self) -> np.ndarray:
        """(S, S) bool: the pixels inside the image circle."""
        return self._rays[0]

    @property
    def theta(self) -> np.ndarray:
        """(S, S) angle of each pixel's ray from the optical axis [rad]."""
        return self._rays[1]

    @property
    def directions(self) -> np.ndarray:
        """(S, S, 3) unit ray of each pixel in the camera frame (x right, y up, z forward)."""
        return self._rays[2]

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """(..., 2) pixel (row, col) of camera-frame points (..., 3) (any distance; the angle
        from the axis may exceed the field of view)."""
        p = np.asarray(points_cam, dtype=float)
        theta = np.arctan2(np.hypot(p[..., 0], p[..., 1]), p[..., 2])
        phi = np.arctan2(p[..., 1], p[..., 0])
        r = self.focal_px * theta
        c = self.center_px
        return np.stack([c - r * np.sin(phi), c + r * np.cos(phi)], axis=-1)


@functools.lru_cache(maxsize=8)
def _camera_rays(fov_deg: float, size_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mask, theta, directions) of every pixel of a camera, computed once per (fov, size)."""
    c = (size_px - 1) / 2.0
    focal = (size_px / 2.0) / math.radians(fov_deg / 2.0)
    rows, cols = np.indices((size_px, size_px), dtype=float)
    x, y = cols - c, c - rows
    theta = np.hypot(x, y) / focal
    phi = np.arctan2(y, x)
    mask = theta <= math.radians(fov_deg / 2.0)
    dirs = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)
    for a in (mask, theta, dirs):
        a.setflags(write=False)
    return mask, theta, dirs


def _unit(v, field: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.isfinite(a).all():
        raise VisionInputError(f"must be 3 finite numbers, got {v!r}", field)
    n = float(np.linalg.norm(a))
    if n < 1e-12:
        raise VisionInputError("must not be the zero vector", field)
    return a / n


def rotate_about(v: np.ndarray, axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """v rotated by ``angle_rad`` about the unit ``axis`` (right-hand rule; Rodrigues)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return v * c + np.cross(axis, v) * s + axis * float(np.dot(axis, v)) * (1.0 - c)


@dataclass(frozen=True)
class Pose:
    """Where the capsule camera is and where it looks (module doc): ``position_m`` (3,),
    ``direction`` (3,, normalised), ``roll_deg`` about it, ``up_hint`` the roll-0 reference up."""

    position_m: np.ndarray
    direction: np.ndarray
    roll_deg: float = 0.0
    up_hint: np.ndarray | None = None

    def __post_init__(self) -> None:
        p = np.asarray(self.position_m, dtype=float).reshape(-1)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise VisionInputError(f"must be 3 finite numbers, got {self.position_m!r}", "pose.position_m")
        d = _unit(self.direction, "pose.direction")
        roll = float(self.roll_deg)
        if not math.isfinite(roll):
            raise VisionInputError(f"must be finite, got {self.roll_deg!r}", "pose.roll_deg")
        object.__setattr__(self, "position_m", p)
        object.__setattr__(self, "direction", d)
        object.__setattr__(self, "roll_deg", roll)
        if self.up_hint is not None:
            object.__setattr__(self, "up_hint", _unit(self.up_hint, "pose.up_hint"))

    @cached_property
    def basis(self) -> np.ndarray:
        """(3, 3) rows: the camera's right, up and forward unit vectors in the phantom frame."""
        forward = self.direction
        hint = self.up_hint
        if hint is None:
            hint = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.99 else np.array([0.0, -1.0, 0.0])
        up = hint - forward * float(np.dot(hint, forward))
        norm = float(np.linalg.norm(up))
        if norm < 1e-6:
            raise VisionInputError("is parallel to the view direction", "pose.up_hint")
        up = rotate_about(up / norm, forward, math.radians(self.roll_deg))
        right = np.cross(forward, up)
        return np.stack([right, up, forward])

    def world_directions(self, camera: FisheyeCamera) -> np.ndarray:
        """(S, S, 3) unit ray directions of every pixel in the phantom frame."""
        return camera.directions @ self.basis

    def to_camera(self, points_m: np.ndarray) -> np.ndarray:
        """Phantom-frame points (..., 3) in the camera frame (x right, y up, z forward) [m]."""
        return (np.asarray(points_m, dtype=float) - self.position_m) @ self.basis.T
