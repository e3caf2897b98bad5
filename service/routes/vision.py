"""POST /v1/vision/render and /v1/vision/motion: the capsule camera and the MI motion estimator
(docs/vision.md) over HTTP. Thin handlers: the models are in :mod:`service.schemas.vision`, the work in
:mod:`service.operations.vision` (over :mod:`vision`); the HTTP matters (Accept, headers, multipart) here.

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
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ValidationError

from raytrace import Budget
from service.admission import declare
from service.deps import state
from service.errors import ServiceError, error_responses
from service.operations.vision import motion, motion_cost, render, render_cost
from service.schemas import ErrorResponse
from service.schemas.vision import MotionOptions, MotionResponse, RenderRequest, RenderResponse
from service.uploads import MULTIPART_OVERHEAD_BYTES, read_parts

router = APIRouter(prefix="/v1/vision", tags=["vision"])
MAX_FRAME_BYTES = 4 * 1024 * 1024
#: Largest JSON part (options, geometry) [bytes].
MAX_JSON_PART_BYTES = 16 * 1024


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

    png, info = await st.gate.run(lambda b: render(req, st.registry, st.settings, b),
                                  Budget(deadline_s=st.settings.request_deadline_s),
                                  disconnected=request.is_disconnected)
    headers = {**_headers(info), "Vary": "Accept"}
    if as_json:
        body = RenderResponse.model_validate({**info, "image_png_base64": base64.b64encode(png).decode("ascii")})
        return JSONResponse(body.model_dump(), headers=headers)
    return Response(png, media_type="image/png", headers=headers)


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


def _json_part(model, data: bytes | None, name: str):
    if data is None:
        return None
    try:
        return model.model_validate_json(bytes(data))
    except ValidationError as exc:
        raise RequestValidationError([{"type": e["type"], "loc": ("body", name, *e["loc"]), "msg": e["msg"],
                                       "input": None} for e in exc.errors(include_url=False, include_input=False)]
                                     ) from None


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
        return motion(raw["reference"], raw["moving"], options, geometry, st.registry, st.settings, budget)

    out = await st.gate.run(work, Budget(deadline_s=st.settings.request_deadline_s),
                            disconnected=request.is_disconnected)
    return MotionResponse.model_validate(out)
