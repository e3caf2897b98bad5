"""POST /v1/vision/render and /v1/vision/motion: the capsule camera and the MI motion estimator
(docs/vision.md) over HTTP. Thin: the models and limits here, the work in :mod:`vision`.

* ``render``: a pose in a phantom's GI lumen (an arc length on its GI-tract centreline, or a
  position and a view direction) -> the capsule camera's frame, ``image/png`` with the ground-truth
  pose in ``X-Pose-*`` headers, or (``Accept: application/json``) the same as JSON with the PNG
  in base64.
* ``motion``: two PNG frames as multipart parts ``reference`` and ``moving`` (optional JSON parts
  ``options``, the estimator's knobs, and ``geometry``, the render request of the reference
  frame) -> rotation, scale, and the advance when the geometry is given.

Work is bounded before it starts (camera <= 1024 px, frames <= 1024 px a side and 4 MiB each,
the PNG size read from its header before anything is inflated) and runs in a worker thread
through the compute gate. Every :class:`vision.errors.VisionInputError` becomes a 422 whose
``loc`` names the field (``["body", "pose", "position_m"]``, ``["body", "moving"]``).
"""

from __future__ import annotations

import base64
import math
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ConfigDict, Field, ValidationError, model_validator

from raytrace import Budget
from service import costs
from service.admission import admit, declare
from service.deps import state
from service.errors import ServiceError, Unprocessable, error_responses, field_to_loc
from service.schemas import ID_PATTERN, ErrorResponse, Int, Name, Out, Strict, Vec3, alternatives
from service.uploads import MULTIPART_OVERHEAD_BYTES, read_parts
from vision.advance import advance_for_scale
from vision.camera import DEFAULT_FOV_DEG, DEFAULT_SIZE_PX, FisheyeCamera, Pose
from vision.errors import VisionInputError
from vision.motion import MotionEstimate, estimate_motion
from vision.mucosa import texture_for
from vision.png import decode_png, encode_png
from vision.render import Frame, lumen_organ, render_frame
from vision.sensor import SensorModel
from vision.sequence import GI_TRACT, centreline_pose

router = APIRouter(prefix="/v1/vision", tags=["vision"])

#: Largest rendered frame [px a side] (the camera's own ceiling; ~1 s of CPU).
MAX_RENDER_SIZE_PX = 1024
#: Smallest and largest frame accepted by the motion estimator here [px a side], and its PNG's size [bytes].
MIN_FRAME_SIDE_PX = 16
MAX_FRAME_SIDE_PX = 1024
MAX_FRAME_BYTES = 4 * 1024 * 1024
#: Largest JSON part (options, geometry) [bytes].
MAX_JSON_PART_BYTES = 16 * 1024


def _range(lo: float, hi: float) -> Any:
    """A float in [lo, hi], for optional fields (the bounds before the union: plain JSON Schema)."""
    return Annotated[float, Field(ge=lo, le=hi)]


class VisionUnprocessable(Unprocessable):
    """A :class:`VisionInputError` as an HTTP 422."""

    type = "vision_input"


# ----------------------------------------------------------------- render
class PoseIn(Strict):
    """Where the capsule is: ``s_m`` along the phantom's GI-tract centreline (looking along the
    direction of travel), or ``position_m`` with a view ``direction`` (exactly one of the two)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra=alternatives([
        {"required": ["s_m"], "properties": {"s_m": {"type": "number"}},
         "not": {"anyOf": [{"required": ["position_m"]}, {"required": ["direction"]}, {"required": ["organ"]}]}},
        {"required": ["position_m", "direction"], "properties": {"position_m": {"type": "array"},
                                                                 "direction": {"type": "array"}},
         "not": {"required": ["s_m"]}}]))

    s_m: _range(0.0, 100.0) | None = Field(
        None, description="Arc length along the phantom's GI-tract centreline [m] (GET /v1/phantoms/{id}: "
        "`centrelines`); the camera sits on the line and looks along the direction of travel.")
    position_m: Vec3 | None = Field(None, description="Camera position [m] (phantom coordinates), inside a "
                                    "GI organ's lumen.")
    direction: Vec3 | None = Field(None, description="View direction [-] (normalised by the server; not zero).")
    organ: Name | None = Field(None, description="The organ whose lumen `position_m` must be in (default: any "
                               "organ of the phantom's GI-tract centreline, or any organ without one).")

    @model_validator(mode="after")
    def _one(self) -> "PoseIn":
        given = self.model_fields_set  # a key present with null counts, as the schema's oneOf says
        if self.s_m is not None and given & {"position_m", "direction", "organ"}:
            raise ValueError("give s_m, or position_m with direction, not both (organ goes with position_m)")
        if self.s_m is None and ("s_m" in given or self.position_m is None or self.direction is None):
            raise ValueError("give s_m, or position_m with direction (exactly one)")
        return self


class CameraIn(Strict):
    fov_deg: float = Field(DEFAULT_FOV_DEG, ge=10.0, le=220.0,
                           description="Full field of view of the equidistant fisheye [deg].")
    size_px: Int = Field(DEFAULT_SIZE_PX, ge=16, le=MAX_RENDER_SIZE_PX, description="Pixels a side (square) [-].")


class TextureIn(Strict):
    preset: Literal["auto", "default", "small_intestine", "colon", "stomach"] = Field(
        "auto", description="Mucosa preset; `auto`: the organ's (small bowel, colon, stomach, docs/vision.md).")
    fold_axis: Vec3 | None = Field(None, description="Axis the circular folds run across [-] (default: the "
                                   "organ's long axis); not zero.")
    seed: Int = Field(0, ge=0, le=2**31 - 1, description="Seed of the solid noise: the same seed, the same wall.")


class SensorIn(Strict):
    vignetting: float = Field(0.3, ge=0.0, le=1.0, description="Fall-off 1 - v (r/R)^2 at the rim [-].")
    full_well_electrons: _range(1.0, 1e7) | None = Field(None, description="Shot noise: electrons at full "
                                                         "scale [-] (none: no shot noise).")
    read_noise: float = Field(0.0, ge=0.0, le=1.0, description="Gaussian read noise, fraction of full scale [-].")
    salt_pepper: float = Field(0.0, ge=0.0, le=1.0, description="Fraction of pixels set black or white [-].")
    seed: Int = Field(0, ge=0, le=2**31 - 1, description="Noise seed [-].")


class RenderRequest(Strict):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra={"examples": [
        # 0.3 m along the default torso's 0.69 m GI-tract centreline (GET /v1/phantoms/torso: centrelines)
        {"phantom": "torso", "pose": {"s_m": 0.3}, "roll_deg": 0.0, "camera": {"fov_deg": 150.0, "size_px": 256}},
        {"phantom": "torso", "pose": {"position_m": [0.0, 0.0, 0.0], "direction": [0.0, 0.0, 1.0]}},
    ]})

    phantom: Annotated[str, Field(pattern=ID_PATTERN)] = Field(
        "torso", description="Phantom id (GET /v1/phantoms).")
    pose: PoseIn
    roll_deg: float = Field(0.0, ge=-360.0, le=360.0, description="Roll about the view direction [deg] (right-hand "
                            "rule; 0: the camera's up nearest the torso's head-ward +z).")
    camera: CameraIn = Field(default_factory=CameraIn, description="The fisheye.")
    texture: TextureIn = Field(default_factory=TextureIn, description="The procedural mucosa.")
    sensor: SensorIn = Field(default_factory=SensorIn, description="Sensor effects (gamma 2.2, 8 bit).")
    exposure: _range(1e-6, 1e9) | None = Field(None, description="Radiance to linear full scale [-]; none: "
                                               "automatic (98th luma percentile at 0.9).")


class PoseOut(Out):
    position_m: list[float] = Field(description="Camera position [m].")
    direction: list[float] = Field(description="Unit view direction [-].")
    up: list[float] = Field(description="Unit up vector of the image (rows grow against it) [-].")
    roll_deg: float = Field(description="Roll [deg].")
    s_m: float | None = Field(None, description="Arc length on the GI-tract centreline [m] (poses given by s_m).")
    organ: str = Field(description="Organ whose lumen holds the camera.")


class CameraOut(Out):
    fov_deg: float = Field(description="Field of view [deg].")
    size_px: int = Field(description="Pixels a side [-].")
    focal_px: float = Field(description="f of r = f theta [px per rad].")


class RenderResponse(Out):
    pose: PoseOut
    camera: CameraOut
    exposure: float = Field(description="Exposure used (the automatic one when none was given) [-].")
    wall_fraction: float = Field(description="Fraction of the image circle's pixels that see a wall [-].")
    median_depth_m: float | None = Field(None, description="Median distance to the wall over those pixels [m].")
    image_png_base64: str = Field(description="The frame, a PNG (8-bit RGB), base64.")


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


def _headers(info: dict[str, Any]) -> dict[str, str]:
    pose = info["pose"]
    out = {"X-Pose-Position-M": ",".join(repr(v) for v in pose["position_m"]),
           "X-Pose-Direction": ",".join(repr(v) for v in pose["direction"]),
           "X-Pose-Up": ",".join(repr(v) for v in pose["up"]),
           "X-Pose-Roll-Deg": repr(pose["roll_deg"]),
           "X-Pose-Organ": pose["organ"],
           "X-Camera-Focal-Px": repr(info["camera"]["focal_px"]),
           "X-Exposure": repr(info["exposure"])}
    if pose["s_m"] is not None:
        out["X-Pose-S-M"] = repr(pose["s_m"])
    return out


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


class NotAcceptable(ServiceError):
    status_code = 406
    type = "not_acceptable"


def wants_json(accept: str | None) -> bool:
    """Whether ``Accept`` prefers application/json to image/png (PNG when absent or tied)."""
    if not accept or not accept.strip():
        return False
    q = {"png": 0.0, "json": 0.0}
    for part in accept.split(","):
        media, *params = [p.strip().lower() for p in part.split(";")]
        weight = 1.0
        for p in params:
            if p.startswith("q="):
                try:
                    weight = float(p[2:])
                except ValueError:
                    weight = 0.0
        weight = weight if math.isfinite(weight) else 0.0
        for kind, names in (("png", ("image/png", "image/*", "*/*")), ("json", ("application/json",
                                                                              "application/*"))):
            if media in names:
                q[kind] = max(q[kind], weight)
    if q["png"] <= 0.0 and q["json"] <= 0.0:
        raise NotAcceptable(f"Accept {accept[:100]!r} allows neither image/png nor application/json",
                            loc=["header", "accept"])
    return q["json"] > q["png"]


_POSE_HEADERS = {name: {"description": text, "schema": {"type": "string"}, "required": name != "X-Pose-S-M"}
                 for name, text in (("X-Pose-Position-M", "Camera position x,y,z [m]."),
                                    ("X-Pose-Direction", "Unit view direction x,y,z."),
                                    ("X-Pose-Up", "Unit up vector of the image x,y,z."),
                                    ("X-Pose-Roll-Deg", "Roll [deg]."),
                                    ("X-Pose-S-M", "Arc length on the GI-tract centreline [m] (poses by s_m)."),
                                    ("X-Pose-Organ", "Organ whose lumen holds the camera."),
                                    ("X-Camera-Focal-Px", "f of r = f theta [px per rad]."),
                                    ("X-Exposure", "Exposure used [-]."))}

_RENDER_RESPONSES = {
    200: {"description": "The frame: a PNG with the ground-truth pose in `X-Pose-*` headers, or with "
          "`Accept: application/json` a RenderResponse (PNG in base64).", "headers": _POSE_HEADERS,
          "model": RenderResponse, "content": {"image/png": {"schema": {"type": "string", "format": "binary"}}}},
    406: {"model": ErrorResponse, "description": "The Accept header allows neither image/png nor JSON."},
    **error_responses(400, 404, 413, 422, 503, 504),
}


def render_cost(req: RenderRequest) -> costs.Cost:
    """A rendered frame: ``camera.size_px`` squared pixels (:func:`service.costs.pixels`)."""
    return costs.pixels(req.camera.size_px, 1, ("camera", "size_px"), "the frame")


@router.post("/render", operation_id="vision_render", summary="Render the capsule camera's frame at a pose",
             response_class=Response, responses=_RENDER_RESPONSES)
@declare(body="max_json_body_bytes", cost=render_cost)
async def vision_render(req: RenderRequest, request: Request) -> Response:
    """The capsule camera's view (equidistant fisheye, LEDs, procedural mucosa, sensor;
    docs/vision.md) at `pose` inside the phantom's GI lumen, with the exact pose echoed:
    `X-Pose-*` headers on the PNG, or the JSON body with `Accept: application/json`.
    422 naming the field for a pose outside the phantom, in air, outside the GI lumens or off
    the centreline; 404 for an unknown phantom."""
    as_json = wants_json(request.headers.get("accept"))
    st = state(request)

    def work(budget: Budget) -> tuple[bytes, dict[str, Any]]:
        admit(render_cost(req), st.settings)
        phantom = st.registry.get(req.phantom, ["body", "phantom"])
        frame, organ, s_m = _vision_errors(lambda: render_request(phantom, req))
        budget.charge(0)
        return encode_png(frame.to_uint8()), describe_frame(frame, organ, s_m)

    png, info = await st.gate.run(work, Budget(deadline_s=st.settings.request_deadline_s),
                                  disconnected=request.is_disconnected)
    headers = {**_headers(info), "Vary": "Accept"}
    if as_json:
        body = RenderResponse.model_validate({**info, "image_png_base64": base64.b64encode(png).decode("ascii")})
        return JSONResponse(body.model_dump(), headers=headers)
    return Response(png, media_type="image/png", headers=headers)


# ----------------------------------------------------------------- motion
class MotionOptions(Strict):
    """The estimator's knobs (vision.motion.estimate_motion; docs/vision.md, "The estimator")."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True,
                              json_schema_extra={"examples": [{"estimate": "both", "bins": 64}]})

    estimate: Literal["both", "rotation", "scale"] = Field("both", description="What to estimate.")
    strategy: Literal["joint", "in_turn"] = Field("joint", description="Bracketing: a joint grid, or in turn "
                                                  "(the thesis' order).")
    search: Literal["fibonacci", "golden"] = Field("fibonacci", description="1-D maximiser.")
    bins: Int = Field(64, ge=2, le=1024, description="Grey-level bins per frame [-].")
    cutoff: _range(0.01, 0.7071) | None = Field(0.15, description="Butterworth cut-off [cycles/px] (null: no "
                                                "pre-filter).")
    order: Int = Field(2, ge=1, le=16, description="Butterworth order [-].")
    kernel_a: float = Field(-1.0, ge=-3.0, le=0.0, description="Cubic-convolution a [-] (-1: thesis Eq 3.9, "
                            "-0.5: Keys).")
    rotation_range_deg: list[Annotated[float, Field(ge=-180.0, le=180.0)]] = Field(
        [-90.0, 90.0], min_length=2, max_length=2, description="Rotations searched, [low, high] [deg].")
    scale_range: list[Annotated[float, Field(ge=0.05, le=20.0)]] | None = Field(
        None, min_length=2, max_length=2, description="Scales searched, [low, high] [-] (default 0.5-2 for both, "
        "0.15-5 for scale alone).")
    rotation_tolerance_deg: float = Field(0.005, ge=1e-4, le=1.0, description="Final rotation bracket [deg].")
    scale_tolerance: float = Field(0.0005, ge=1e-5, le=1.0, description="Final bracket in log scale [-].")
    initial_rotation_deg: float = Field(0.0, ge=-180.0, le=180.0, description="Rotation held when estimating "
                                        "scale alone [deg].")
    initial_scale: float = Field(1.0, ge=0.05, le=20.0, description="Scale held when estimating rotation alone [-].")
    max_pixels: Int = Field(2**17, ge=1024, le=2**20, description="Pixels compared per pyramid level at most [-].")


class MotionResponse(Out):
    rotation_deg: float = Field(description="Rotation of the moving frame's content, counter-clockwise as "
                                "displayed = the capsule's roll increment [deg].")
    scale: float = Field(description="Magnification about the optical axis [-] (> 1: advancing).")
    advance_m: float | None = Field(None, description="Advance along the view direction that gives this scale "
                                    "in the reference frame's rendered geometry [m] (with `geometry` only).")
    advance_note: str | None = Field(None, description="Why advance_m is null although geometry was given.")
    mutual_information: float = Field(description="MI reached, Eq 3.2 at full resolution [nats].")
    iterations: int = Field(description="Bracket reductions of the 1-D searches [-].")
    evaluations: int = Field(description="MI evaluations over all pyramid levels [-].")
    levels: int = Field(description="Pyramid levels [-].")
    width_px: int = Field(description="Frame width [px].")
    height_px: int = Field(description="Frame height [px].")
    options: MotionOptions = Field(description="The options used (defaults filled in).")


_MOTION_PARTS = {"reference": MAX_FRAME_BYTES, "moving": MAX_FRAME_BYTES,
                 "options": MAX_JSON_PART_BYTES, "geometry": MAX_JSON_PART_BYTES}
_MOTION_BODY = {"requestBody": {"required": True, "content": {"multipart/form-data": {
    "schema": {"type": "object", "required": ["reference", "moving"], "additionalProperties": False, "properties": {
        "reference": {"type": "string", "format": "binary", "description": "The earlier frame: a PNG (any colour "
                      "type and bit depth; colour is reduced to BT.601 luma), 16-1024 px a side, <= 4 MiB."},
        "moving": {"type": "string", "format": "binary", "description": "The later frame, PNG, same size."},
        "options": {"type": "string", "contentMediaType": "application/json", "description": "JSON text of "
                    "the estimator's options (schema `#/components/schemas/MotionOptions`), <= 16 KiB."},
        "geometry": {"type": "string", "contentMediaType": "application/json", "description": "JSON text of "
                     "the POST /v1/vision/render body that rendered `reference` (schema "
                     "`#/components/schemas/RenderRequest`): its geometry converts the scale to advance_m."}}},
    "encoding": {"reference": {"contentType": "image/png"}, "moving": {"contentType": "image/png"},
                 "options": {"contentType": "application/json"}, "geometry": {"contentType": "application/json"}},
}}}}
_OPTION_NAMES = {name: f"options.{name}" for name in MotionOptions.model_fields}


def _json_part(model, data: bytes | None, name: str):
    if data is None:
        return None
    try:
        return model.model_validate_json(bytes(data))
    except ValidationError as exc:
        raise RequestValidationError([{"type": e["type"], "loc": ("body", name, *e["loc"]), "msg": e["msg"],
                                       "input": None} for e in exc.errors(include_url=False, include_input=False)]
                                     ) from None


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


@router.post("/motion", operation_id="vision_motion", summary="Rotation, scale and advance between two frames",
             response_model=MotionResponse, openapi_extra=_MOTION_BODY,
             responses=error_responses(400, 404, 413, 422, 503, 504))
@declare(body=lambda s: sum(_MOTION_PARTS.values()) + MULTIPART_OVERHEAD_BYTES, cost=motion_cost)
async def vision_motion(request: Request) -> MotionResponse:
    """Maximum mutual information registration of `moving` against `reference` (thesis Ch. 3;
    docs/vision.md, "The estimator"): Butterworth pre-filter, MI of the joint histogram,
    Fibonacci search, cubic-convolution warp, coarse to fine. Multipart parts: `reference`
    and `moving` (PNG only: no JPEG decoder ships with CapsuleRT), optional `options` (JSON)
    and `geometry` (JSON: the render request of `reference`; the scale then becomes an advance
    in metres through the rendered depth, `advance_m`). 413 beyond 4 MiB per frame; 422 naming
    the part for a non-PNG, a frame beyond 1024 px or below 16 px a side, frames of different
    sizes, a frame constant inside the compared disc."""
    st = state(request)
    request.scope["capsule_rt.error_loc"] = "body"
    parts = await read_parts(request, _MOTION_PARTS, ("reference", "moving"),
                             "the body must be multipart/form-data with parts 'reference' and 'moving' (PNG "
                             "frames), optionally 'options' and 'geometry' (JSON)")
    raw = {name: bytes(part.data) for name, part in parts.items()}

    def work(budget: Budget) -> dict:
        options = _json_part(MotionOptions, raw.get("options"), "options") or MotionOptions()
        geometry = _json_part(RenderRequest, raw.get("geometry"), "geometry")
        ref = _vision_errors(lambda: frame_from_png(raw["reference"], "reference"))
        mov = _vision_errors(lambda: frame_from_png(raw["moving"], "moving"))
        admit(motion_cost(max(ref.shape[:2])), st.settings)
        if geometry is not None and ref.shape[:2] != (geometry.camera.size_px,) * 2:
            raise VisionUnprocessable(f"the frames are {ref.shape[1]} x {ref.shape[0]} px, the geometry's camera "
                                      f"{geometry.camera.size_px} px a side", loc=["body", "geometry", "camera",
                                                                                    "size_px"])
        est = _vision_errors(lambda: estimate_pair(ref, mov, options), renames=_OPTION_NAMES)
        budget.charge(0)
        advance, note = None, None
        if geometry is not None:
            phantom = st.registry.get(geometry.phantom, ["body", "geometry", "phantom"])
            frame, _, _ = _vision_errors(lambda: render_request(phantom, geometry), ("geometry",))
            advance, note = advance_of(frame, est.scale)
        return motion_response(est, ref.shape, options, advance, note)

    out = await st.gate.run(work, Budget(deadline_s=st.settings.request_deadline_s),
                            disconnected=request.is_disconnected)
    return MotionResponse.model_validate(out)

