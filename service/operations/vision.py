"""The work of POST /v1/vision/render and /v1/vision/motion (docs/vision.md), shared by the routes
(service.routes.vision) and the CLI (``capsule-rt vision``): a thin layer over :mod:`vision`.

Work is bounded before it starts (camera <= 1024 px, frames <= 1024 px a side, the PNG size read
from its header before anything is inflated; :mod:`service.admission`). Every
:class:`vision.errors.VisionInputError` becomes a 422 whose ``loc`` names the field
(``["body", "pose", "position_m"]``, ``["body", "moving"]``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from raytrace import Budget
from service import costs
from service.admission import admit
from service.errors import Unprocessable, field_to_loc
from service.registry import Registry
from service.schemas.vision import MotionOptions, PoseIn, RenderRequest
from service.settings import Settings
from vision.advance import advance_for_scale
from vision.camera import FisheyeCamera, Pose
from vision.errors import VisionInputError
from vision.motion import MotionEstimate, estimate_motion
from vision.mucosa import texture_for
from vision.png import decode_png, encode_png
from vision.render import Frame, lumen_organ, render_frame
from vision.sensor import SensorModel
from vision.sequence import GI_TRACT, centreline_pose

#: Smallest and largest frame accepted by the motion estimator here [px a side], and its PNG's size [bytes].
MIN_FRAME_SIDE_PX = 16
MAX_FRAME_SIDE_PX = 1024


class VisionUnprocessable(Unprocessable):
    """A :class:`VisionInputError` as an HTTP 422."""

    type = "vision_input"


def resolve_pose(phantom, pose: PoseIn, roll_deg: float) -> tuple[Pose, str, float | None]:
    """(pose, organ, s_m) of a request's pose, checked inside a lumen of the phantom."""
    if pose.s_m is not None:
        out, organ = centreline_pose(phantom, pose.s_m, roll_deg)
        lumen_organ(phantom, out.position_m, organ)
        return out, organ, float(pose.s_m)
    out = Pose(pose.position_m, pose.direction, roll_deg)
    try:
        index = lumen_organ(phantom, out.position_m, pose.organ)
    except VisionInputError as exc:
        raise VisionInputError(exc.reason, "pose.organ" if exc.field == "organ" else exc.field) from None
    organ = phantom.organs[index].name
    line = getattr(phantom, "centrelines", {}).get(GI_TRACT)
    lumens = sorted({p.organ for p in line.pieces}) if line is not None else []
    if pose.organ is None and lumens and organ not in lumens:
        raise VisionInputError(f"is inside {organ!r}, not in a GI lumen ({', '.join(lumens)})", "pose.position_m")
    return out, organ, None


def render_request(phantom, req: RenderRequest) -> tuple[Frame, str, float | None]:
    """Render a request's frame (the CLI and the route share it)."""
    pose, organ, s_m = resolve_pose(phantom, req.pose, req.roll_deg)
    camera = FisheyeCamera(req.camera.fov_deg, req.camera.size_px)
    texture = texture_for(organ, req.texture.preset, req.texture.fold_axis, req.texture.seed, phantom=phantom)
    sensor = SensorModel(**req.sensor.model_dump())
    frame = render_frame(phantom, pose, camera, texture=texture, sensor=sensor, exposure=req.exposure, organ=organ)
    return frame, organ, s_m


def _vec(a) -> list[float]:
    return [float(v) for v in a]


def describe_frame(frame: Frame, organ: str, s_m: float | None) -> dict[str, Any]:
    pose, camera = frame.pose, frame.camera
    depth = frame.depth_m[frame.mask]
    return {
        "pose": {"position_m": _vec(pose.position_m), "direction": _vec(pose.direction), "up": _vec(pose.basis[1]),
                 "roll_deg": pose.roll_deg, "s_m": s_m, "organ": organ},
        "camera": {"fov_deg": camera.fov_deg, "size_px": camera.size_px, "focal_px": camera.focal_px},
        "exposure": float(frame.metadata["exposure"]),
        "wall_fraction": float(frame.mask.sum() / camera.mask.sum()),
        "median_depth_m": float(np.median(depth)) if depth.size else None,
    }


def _vision_errors(fn, prefix: tuple[str, ...] = (), renames: dict[str, str] | None = None):
    """Run ``fn()``, turning a VisionInputError into a 422 at ``body.<prefix>.<field>``."""
    try:
        return fn()
    except VisionInputError as exc:
        field = exc.field or ""
        head = field.split(".")[0].split("[")[0]
        if renames and head in renames:
            field = renames[head] + field[len(head):]
        raise VisionUnprocessable(exc.reason, loc=["body", *prefix, *field_to_loc(field)]) from exc


def render_cost(req: RenderRequest) -> costs.Cost:
    """A rendered frame: ``camera.size_px`` squared pixels (:func:`service.costs.pixels`)."""
    return costs.pixels(req.camera.size_px, 1, ("camera", "size_px"), "the frame")


def frame_from_png(data: bytes, field: str) -> np.ndarray:
    """The grey levels of a PNG part: colour by BT.601 luma, grey + alpha by its grey channel; its size
    within this server's frames (:data:`MIN_FRAME_SIDE_PX` to :data:`MAX_FRAME_SIDE_PX` a side, said so:
    the estimator's own range is wider)."""
    pixels = decode_png(data, field=field, max_side_px=MAX_FRAME_SIDE_PX,
                        max_pixels=MAX_FRAME_SIDE_PX * MAX_FRAME_SIDE_PX)
    if min(pixels.shape[:2]) < MIN_FRAME_SIDE_PX:
        raise VisionInputError(f"is {pixels.shape[1]} x {pixels.shape[0]} pixels: frames are {MIN_FRAME_SIDE_PX} to "
                               f"{MAX_FRAME_SIDE_PX} pixels a side", field)
    return pixels[..., 0] if pixels.ndim == 3 and pixels.shape[2] == 2 else pixels


def motion_response(est: MotionEstimate, shape, options: MotionOptions, advance_m=None, note=None) -> dict:
    return {"rotation_deg": est.rotation_deg, "scale": est.scale, "advance_m": advance_m, "advance_note": note,
            "mutual_information": est.mutual_information, "iterations": est.iterations,
            "evaluations": est.evaluations, "levels": est.levels, "width_px": int(shape[1]),
            "height_px": int(shape[0]), "options": options.model_dump()}


def estimate_pair(reference: np.ndarray, moving: np.ndarray, options: MotionOptions) -> MotionEstimate:
    """:func:`vision.motion.estimate_motion` with a request's options."""
    kw = options.model_dump()
    for key in ("rotation_range_deg", "scale_range"):
        kw[key] = None if kw[key] is None else tuple(kw[key])
    return estimate_motion(reference, moving, **kw)


def advance_of(frame: Frame, scale: float) -> tuple[float | None, str | None]:
    """(advance_m, None), or (None, why) when the rendered geometry cannot convert this scale."""
    try:
        return advance_for_scale(frame, scale), None
    except VisionInputError as exc:
        return None, exc.reason


def motion_cost(side_px: int) -> costs.Cost:
    """Two frames of ``side_px`` a side registered (:func:`service.costs.pixels`): what the body cap and
    the PNG headers (read before anything is inflated) allow."""
    return costs.pixels(side_px, 2, ("reference",), "the registration")


_OPTION_NAMES = {name: f"options.{name}" for name in MotionOptions.model_fields}


def render(req: RenderRequest, registry: Registry, settings: Settings, budget: Budget) -> tuple[bytes, dict[str, Any]]:
    """A POST /v1/vision/render body -> (the PNG, the frame's description: a RenderResponse less the image)."""
    admit(render_cost(req), settings)
    phantom = registry.get(req.phantom, ["body", "phantom"])
    frame, organ, s_m = _vision_errors(lambda: render_request(phantom, req))
    budget.charge(0)
    return encode_png(frame.to_uint8()), describe_frame(frame, organ, s_m)


def motion(reference_png: bytes, moving_png: bytes, options: MotionOptions, geometry: RenderRequest | None,
           registry: Registry, settings: Settings, budget: Budget) -> dict:
    """Two PNG frames (and the render request of the reference, optional) -> a MotionResponse dict."""
    ref = _vision_errors(lambda: frame_from_png(reference_png, "reference"))
    mov = _vision_errors(lambda: frame_from_png(moving_png, "moving"))
    admit(motion_cost(max(ref.shape[:2])), settings)
    if geometry is not None and ref.shape[:2] != (geometry.camera.size_px,) * 2:
        raise VisionUnprocessable(f"the frames are {ref.shape[1]} x {ref.shape[0]} px, the geometry's camera "
                                  f"{geometry.camera.size_px} px a side", loc=["body", "geometry", "camera",
                                                                                "size_px"])
    est = _vision_errors(lambda: estimate_pair(ref, mov, options), renames=_OPTION_NAMES)
    budget.charge(0)
    advance, note = None, None
    if geometry is not None:
        phantom = registry.get(geometry.phantom, ["body", "geometry", "phantom"])
        frame, _, _ = _vision_errors(lambda: render_request(phantom, geometry), ("geometry",))
        advance, note = advance_of(frame, est.scale)
    return motion_response(est, ref.shape, options, advance, note)
