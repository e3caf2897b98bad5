"""The capsule camera's view: Embree primary rays from the fisheye into the phantom, shaded by the
capsule's own LEDs.

Per pixel inside the image circle (:class:`~vision.camera.FisheyeCamera`), one ray from the
camera centre along the pixel's direction (:class:`~vision.camera.Pose`); the tracer's Embree
scene (:func:`raytrace.engine.scene.scene_for`, float64 re-intersection) gives the first wall hit
and its distance, all rays in one batch. At the hit P the wall has reflectance rho and a bumped
normal n (:mod:`vision.mucosa`, or any object with the same ``shade_inputs``).

Illumination (:class:`Lighting`): ``led_count`` point LEDs on a ring of radius
``ring_radius_m`` around the lens, in the lens plane, together of radiant intensity I on the
axis, each with the emission pattern cos^m of its angle from the view direction (m = 1:
Lambertian LED). The irradiance from LED k at distance d_k, arriving at incidence cos i_k =
n . l_k, is E_k = (I / led_count) cos^m(e_k) cos(i_k) / d_k^2 (inverse-square law, Lambert's
cosine law); the radiance towards the camera is

    L = sum_k E_k (rho / pi + k_s (s + 8) / (8 pi) (n . h_k)^s)

(Lambertian diffuse plus a normalised Blinn-Phong specular lobe for the wet mucosa, h_k the
half-vector of the LED and camera directions). The linear pixel value is ``exposure`` * L, then
the sensor (:class:`~vision.sensor.SensorModel`). Not modelled: inter-reflections, the LEDs'
shadows (the LEDs sit beside the lens, so shadows are nearly hidden from it), the dome's
reflections, lens distortion beyond the equidistant model.

Units: with the default intensity, a white (rho = 1) Lambertian wall 15 mm ahead of the
camera, perpendicular to the axis, renders at 0.8 of full scale (linear) with exposure 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from raytrace import InputError, Phantom
from raytrace.engine.scene import scene_for

from .camera import FisheyeCamera, Pose
from .errors import VisionInputError
from .kernels import shade_points, wall_hits
from .mucosa import MucosaTexture
from .pool import THREADS, pool
from .sensor import SensorModel

#: Total on-axis radiant intensity giving 0.8 of full scale on a white wall 15 mm ahead (module doc).
DEFAULT_INTENSITY = 0.8 * math.pi * 0.015**2


@dataclass(frozen=True)
class Lighting:
    """The capsule's LEDs (module doc)."""

    led_count: int = 4
    ring_radius_m: float = 4e-3
    intensity: float = DEFAULT_INTENSITY
    emission_exponent: float = 1.0
    specular: float = 0.25
    shininess: float = 60.0

    def __post_init__(self) -> None:
        if isinstance(self.led_count, bool) or not isinstance(self.led_count, (int, np.integer)) \
                or not 1 <= self.led_count <= 16:
            raise VisionInputError(f"must be an integer in [1, 16], got {self.led_count!r}", "lighting.led_count")
        for name, lo, hi in (("ring_radius_m", 0.0, 0.02), ("intensity", 0.0, 1e3), ("emission_exponent", 0.0, 50.0),
                             ("specular", 0.0, 10.0), ("shininess", 1.0, 1e4)):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and lo <= v <= hi):
                raise VisionInputError(f"must be in [{lo}, {hi}], got {v!r}", f"lighting.{name}")

    def positions(self, pose: Pose) -> np.ndarray:
        """(led_count, 3) LED positions [m] on the ring around the lens."""
        right, up, _ = pose.basis
        angles = 2.0 * np.pi * (np.arange(self.led_count) + 0.5) / self.led_count
        return pose.position_m + self.ring_radius_m * (np.cos(angles)[:, None] * right + np.sin(angles)[:, None] * up)


@dataclass(frozen=True)
class Frame:
    """One rendered frame and its exact geometry (pixels outside the image circle or without a
    hit: 0 in ``image``, NaN in ``depth_m`` / ``points_m``, -1 in ``organ``)."""

    image: np.ndarray  # (S, S, 3) float in [0, 1], after the sensor
    linear: np.ndarray  # (S, S, 3) exposure * radiance, before the sensor
    depth_m: np.ndarray  # (S, S) distance from the camera centre to the wall along the pixel's ray
    points_m: np.ndarray  # (S, S, 3) wall points, phantom frame
    organ: np.ndarray  # (S, S) int: organ index of the wall hit
    mask: np.ndarray  # (S, S) bool: pixels with a wall hit inside the image circle
    pose: Pose
    camera: FisheyeCamera
    metadata: dict = field(default_factory=dict)

    def grey(self) -> np.ndarray:
        """BT.601 luma of the image (what the motion estimator uses)."""
        return self.image @ np.array([0.299, 0.587, 0.114])

    def to_uint8(self) -> np.ndarray:
        """The image as (S, S, 3) uint8 (for PNG)."""
        return np.round(np.clip(self.image, 0.0, 1.0) * 255.0).astype(np.uint8)


#: Automatic exposure: this percentile of the luma of the wall pixels lands at AUTO_LEVEL.
AUTO_PERCENTILE, AUTO_LEVEL = 98.0, 0.9


def auto_exposure(radiance: np.ndarray) -> float:
    """The exposure putting the AUTO_PERCENTILE-th percentile of the frame's luma (linear, BT.601
    weights) at AUTO_LEVEL of full scale: bright enough for far walls, a few highlights clipped."""
    if len(radiance) == 0:
        return 1.0
    luma = radiance @ np.array([0.299, 0.587, 0.114])
    level = float(np.percentile(luma, AUTO_PERCENTILE))
    return AUTO_LEVEL / level if level > 0.0 else 1.0


def lumen_organ(phantom: Phantom, position_m: np.ndarray, organ: str | None) -> int:
    """The organ index the camera is in, checked: not air, and ``organ`` if named."""
    try:
        index = int(phantom.medium_index(np.asarray(position_m, float)[None, :], field="pose.position_m")[0])
    except InputError as exc:
        raise VisionInputError(exc.reason, exc.field or "pose.position_m") from None
    if index < 0:
        raise VisionInputError("is outside every organ of the phantom (in air)", "pose.position_m")
    if organ is not None:
        try:
            want = phantom.organ_index(organ)
        except InputError:
            names = ", ".join(o.name for o in phantom.organs)
            raise VisionInputError(f"no organ {organ!r} in phantom {phantom.name!r} (organs: {names})",
                                   "organ") from None
        if index != want:
            raise VisionInputError(f"is in {phantom.organs[index].name!r}, not inside organ {organ!r}",
                                   "pose.position_m")
    return index


def shade(points: np.ndarray, normals: np.ndarray, albedo: np.ndarray, view_dirs: np.ndarray, pose: Pose,
          lighting: Lighting) -> np.ndarray:
    """Radiance (N, 3) towards the camera of wall points lit by the LEDs (module doc);
    ``normals`` unit and facing the lumen, ``view_dirs`` the unit rays from the camera."""
    out = np.empty((len(points), 3))
    args = (lighting.positions(pose), np.ascontiguousarray(pose.basis[2]), lighting.intensity / lighting.led_count,
            float(lighting.emission_exponent), lighting.specular * (lighting.shininess + 8.0) / (8.0 * np.pi),
            float(lighting.shininess))
    arrays = [np.ascontiguousarray(a, dtype=np.float64) for a in (points, normals, albedo, view_dirs)]
    _in_parts(lambda a, b: shade_points(*(x[a:b] for x in arrays), *args, out[a:b]), len(points))
    return out


def _in_parts(work, n: int, min_size: int = 4096) -> None:
    """Run ``work(start, stop)`` over [0, n) in THREADS parts on the pool (one part if small)."""
    if THREADS < 2 or n < min_size:
        work(0, n)
        return
    cuts = np.linspace(0, n, THREADS + 1).astype(int)
    for f in [pool().submit(work, a, b) for a, b in zip(cuts[:-1], cuts[1:])]:
        f.result()


def render_frame(phantom: Phantom, pose: Pose, camera: FisheyeCamera | None = None, *,
                 lighting: Lighting | None = None, texture=None, sensor: SensorModel | None = None,
                 exposure: float | None = None, organ: str | None = None, frame_index: int = 0) -> Frame:
    """Render the capsule camera's frame at ``pose`` inside ``phantom`` (module doc).

    ``organ``: the organ whose lumen the camera must be in (checked; default: whichever organ
    contains the position, never air). ``texture``: a :class:`~vision.mucosa.MucosaTexture`
    (default) or any object with ``shade_inputs(points_m, normals) -> (albedo, normals)``.
    ``frame_index`` varies the sensor noise between frames of a sequence (same seed).
    ``exposure``: the factor from radiance to linear full scale; None: automatic, as a capsule's
    light control does (:func:`auto_exposure`).
    """
    camera = camera or FisheyeCamera()
    lighting = lighting or Lighting()
    sensor = sensor or SensorModel()
    texture = texture if texture is not None else MucosaTexture()
    if exposure is not None and not (math.isfinite(float(exposure)) and float(exposure) > 0.0):
        raise VisionInputError(f"must be a finite number > 0 or None (automatic), got {exposure!r}", "exposure")
    lumen_organ(phantom, pose.position_m, organ)
    scene = scene_for(phantom)
    tables = scene.kernel_tables
    mask = camera.mask
    dirs = pose.world_directions(camera)[mask]
    origin = np.asarray(pose.position_m, dtype=np.float64)
    query = (origin - scene.center).astype(np.float32)  # Embree's float32 frame (TracerScene.first_hit)
    n = len(dirs)
    face, t, points, normals = np.empty(n, np.int64), np.empty(n), np.empty((n, 3)), np.empty((n, 3))

    def trace(a: int, b: int) -> None:
        """Embree's first hits of rays a:b, then in one compiled pass the float64
        re-intersection, the wall points and the smooth normals facing the camera (GIL-free:
        2 threads pay)."""
        d = dirs[a:b]
        prim, tfar, _, _ = scene.embree.intersect(np.broadcast_to(query, d.shape), d)
        wall_hits(prim, tfar, origin, d, tables.face_map, tables.face_normals, tables.plane_d, tables.frame,
                  face[a:b], t[a:b], points[a:b], normals[a:b])

    _in_parts(trace, n)
    hit = face >= 0
    pts = points[hit]
    albedo, bent = texture.shade_inputs(pts, normals[hit])
    radiance = shade(pts, bent, np.asarray(albedo, float), dirs[hit], pose, lighting)

    size = camera.size_px
    full = np.zeros((size, size), bool)
    full[mask] = hit
    linear = np.zeros((size, size, 3))
    if exposure is None:
        exposure = auto_exposure(radiance)
    linear[full] = float(exposure) * radiance
    depth = np.full((size, size), np.nan)
    depth[mask] = np.where(hit, t, np.nan)
    points_map = np.full((size, size, 3), np.nan)
    points_map[mask] = points  # NaN where a ray missed
    organ_map = np.full((size, size), -1, np.int64)
    organ_map[mask] = np.where(hit, phantom.face_organ[face], -1)
    radius_fraction = camera.theta / math.radians(camera.fov_deg / 2.0)
    image = sensor.apply(linear, radius_fraction, full, frame_index)
    return Frame(image=image, linear=linear, depth_m=depth, points_m=points_map, organ=organ_map, mask=full,
                 pose=pose, camera=camera, metadata={"phantom": phantom.name, "frame_index": int(frame_index),
                                                     "exposure": float(exposure)})
