"""Sweep jobs: submit, follow, fetch results, cancel (``docs/sweeps.md``, "HTTP")."""

from __future__ import annotations

import json
from typing import Any, Literal

import anyio.to_thread
from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field

from service.admission import declare
from service.errors import ServiceError, Unprocessable, UnsupportedMediaType, UploadTooLarge, error_responses
from service.security import writer
from service.sweep_jobs import SweepJobs
from sweeps.spec import LIMITS, parse_text

router = APIRouter(prefix="/v1/sweeps", tags=["sweeps"])

SweepIdPath = Path(..., pattern=r"^sw-[0-9a-f]{16}$", description="Sweep id (`sw-` + 16 hex digits).",
                   examples=["sw-0123456789abcdef"])


class SweepFailure(BaseModel):
    model_config = ConfigDict(extra="allow")
    reason: str = Field(description="Why this trace or task failed.")
    type: str = Field(description="The error's type.")


class SweepStatus(BaseModel):
    """A sweep job's progress. `done`/`total` count traces (capsule positions x frequencies)."""

    id: str
    name: str
    phantom: str
    state: Literal["queued", "running", "done", "failed", "cancelled"]
    done: int = Field(description="Traces stored (positions x frequencies, each with all its receivers).")
    total: int
    tasks_done: int
    tasks_total: int
    elapsed_s: float = Field(description="Wall time spent running, over every run of the job [s].")
    eta_s: float | None = Field(description="Estimated time left [s] (null until a task has finished).")
    failures: list[SweepFailure] = Field(description="Failed traces or tasks with their reasons (first 100).")
    failure_count: int
    engine: str | None = Field(description="Where it runs: `local:<workers>` or `dask:<address>`.")
    error: str | None
    created_at: float | None
    started_at: float | None
    finished_at: float | None
    cancel_requested: bool
    deleted: bool | None = Field(None, description="DELETE only: the finished job and its results were removed.")


class SweepSummary(BaseModel):
    id: str
    name: str
    phantom: str
    state: str
    done: int
    total: int
    created_at: float | None


class SweepList(BaseModel):
    sweeps: list[SweepSummary]


_VEC3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
#: The sweep spec's shape, from sweeps.spec's own limits (the server lowers rays, interactions and
#: trials in its served document, service.app). Rules that depend on the phantom (sites, organs,
#: centrelines) or relate fields (bands to carriers, localizers to ranging methods) are the
#: validator's, sweeps.spec, whose 422 names the field.
_SPEC_SCHEMA = {
    "type": "object",
    "description": "A sweep spec (docs/sweeps.md, 'The spec'); also accepted as YAML (Content-Type: "
                   "application/yaml). Validated as a whole; a 422's `loc` names the offending field.",
    "required": ["capsule_positions"],
    "additionalProperties": False,
    "properties": {
        "name": {"type": "string", "maxLength": 128},
        "description": {"type": "string", "maxLength": 4000},
        "phantom": {"type": "string", "default": "torso", "pattern": r"^[a-z0-9][a-z0-9_-]{0,63}$"},
        "capsule_positions": {
            "description": "A list of {site} | {position_m} | {s_m[, centreline]} (each with an optional name), or "
                           "{along_tract: {ds_m, start_m, stop_m, centreline}}.",
            "oneOf": [
                {"type": "array", "minItems": 1, "maxItems": LIMITS.max_positions, "items": {
                    "type": "object", "minProperties": 1, "additionalProperties": False, "properties": {
                        "name": {"type": "string", "maxLength": 64}, "site": {"type": "string", "maxLength": 64},
                        "position_m": _VEC3, "s_m": {"type": "number", "minimum": 0},
                        "centreline": {"type": "string", "maxLength": 64}}}},
                {"type": "object", "required": ["along_tract"], "additionalProperties": False, "properties": {
                    "along_tract": {"type": "object", "required": ["ds_m"], "additionalProperties": False,
                                    "properties": {"ds_m": {"type": "number", "exclusiveMinimum": 0},
                                                   "start_m": {"type": "number", "minimum": 0},
                                                   "stop_m": {"type": "number", "minimum": 0},
                                                   "centreline": {"type": "string", "maxLength": 64}}}}},
            ]},
        "receivers": {
            "description": "A list of antennas as in POST /v1/channel, or \"sensors\" (every sensor site of the "
                           "phantom).",
            "oneOf": [{"const": "sensors"},
                      {"type": "array", "minItems": 1, "maxItems": LIMITS.max_receivers, "items": {"type": "object"}}],
            "default": "sensors"},
        "frequencies_hz": {"type": "array", "items": {"type": "number", "minimum": 10.0, "maximum": 20e9},
                           "minItems": 1, "maxItems": LIMITS.max_frequencies, "uniqueItems": True,
                           "default": [402e6]},
        "channel": {
            "type": "object", "additionalProperties": False,
            "description": "The ChannelSpec knobs of every trace (defaults: POST /v1/channel's), a band around each "
                           "carrier ({span_hz, points}) or absolute, and the capsule antenna.",
            "properties": {
                "max_interactions": {"type": "integer", "minimum": 1, "maximum": LIMITS.max_interactions},
                "rays": {"type": "integer", "minimum": 1, "maximum": LIMITS.max_rays},
                "dynamic_range_db": {"type": "number", "exclusiveMinimum": 0, "maximum": 300},
                "band": {"type": ["object", "null"]},
                "homogeneous": {"type": ["object", "null"]},
                "near_field": {"type": "boolean"},
                "capsule_polarization": {"oneOf": [_VEC3, {"const": "tangent"}]},
                "capsule_pattern": {"enum": ["isotropic", "dipole"]}}},
        "ranging": {"type": "object", "description": "relative_permittivity; toa {methods, snr_db, waveform}; pdoa "
                                                     "{methods, snr_db, span_hz, points, duration_s}; rss {model, "
                                                     "shadowing}."},
        "localization": {"type": ["object", "null"], "description": "{methods: [{name, ranges_from, ...}]}: "
                                                                    "registered localizers only."},
        "trials": {"type": "integer", "minimum": 1, "maximum": LIMITS.max_trials, "default": 100},
        "seed": {"type": "integer", "minimum": 0, "maximum": 2**53 - 1, "default": 0},
        "chunk_positions": {"type": "integer", "minimum": 1, "maximum": LIMITS.max_chunk_positions, "default": 4},
    },
    "example": {"name": "belt along the tract", "phantom": "torso",
                "capsule_positions": {"along_tract": {"ds_m": 0.05}}, "receivers": "sensors",
                "frequencies_hz": [402e6], "channel": {"rays": 2000, "max_interactions": 3},
                "ranging": {"toa": {"methods": ["gcc"], "snr_db": 30}}, "trials": 20, "seed": 1},
}
_SUBMIT = {"requestBody": {"required": True, "content": {
    "application/json": {"schema": _SPEC_SCHEMA},
    "application/yaml": {"schema": _SPEC_SCHEMA}}}}  # the same spec, as YAML

_MEDIA = {"parquet": "application/vnd.apache.parquet", "csv": "text/csv; charset=utf-8",
          "json": "application/json"}


def _jobs(request: Request):
    return request.app.state.sweeps


#: The media types a spec may come as: JSON, or YAML. Anything else (above all the types a web page's form
#: or a no-preflight fetch sends: text/plain, application/x-www-form-urlencoded, multipart/form-data) is 415.
YAML_TYPES = ("application/yaml", "application/x-yaml", "text/yaml")


def spec_media_type(header: str | None) -> str:
    kind = (header or "").split(";")[0].strip().lower()
    if kind == "application/json" or (kind.startswith("application/") and kind.endswith("+json")) or kind in YAML_TYPES:
        return kind
    raise UnsupportedMediaType(f"a sweep spec is sent as application/json or application/yaml, not "
                               f"{kind[:100] or 'a body without Content-Type'}", loc=["header", "content-type"])


def decode_spec(body: bytes, kind: str) -> dict:
    """A sweep spec's body (JSON, or YAML for ``application/yaml``) as an object: 400 naming the
    body when it is not UTF-8, not JSON/YAML, or nests too deeply to parse; 422 when it is not an
    object. Call it off the event loop: a 1 MiB YAML spec takes seconds to parse."""
    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError:
        raise ServiceError("the spec is not UTF-8 text", loc=["body"]) from None
    try:
        if kind in YAML_TYPES:
            from raytrace.errors import InputError

            try:
                data: Any = parse_text(text, ".yaml")
            except InputError as exc:
                raise ServiceError(exc.reason, loc=["body"]) from None
        else:
            try:
                data = json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
            except ValueError as exc:  # malformed, NaN/Infinity, an integer of too many digits
                raise ServiceError(f"malformed JSON: {exc}", loc=["body"]) from None
    except RecursionError:
        raise ServiceError("the spec nests too deeply to be parsed", loc=["body"]) from None
    if not isinstance(data, dict):
        raise Unprocessable("a sweep spec is a JSON object", loc=["body"])
    return data


@router.post("", status_code=202, response_model=SweepStatus, operation_id="submit_sweep", summary="Submit a sweep",
             responses=error_responses(400, 401, 404, 413, 415, 422, 503), openapi_extra=_SUBMIT)
@declare(body="max_json_body_bytes", cost=SweepJobs.estimate, keyed=True)
async def submit_sweep(request: Request) -> JSONResponse:
    """Validate the spec (and plan it against the phantom: sites, positions, centreline), store the job
    and queue it. The body is JSON (`application/json`) or YAML (`application/yaml`); any other type is 415.
    Answers 202 with its status at once; the work runs in worker processes. At most `sweep_max_queue` jobs
    may be queued or running (503 + Retry-After beyond)."""
    jobs = _jobs(request)
    owner = writer(request, request.app.state.capsule.settings)
    kind = spec_media_type(request.headers.get("content-type"))
    cap = jobs.limits.max_spec_bytes
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > cap:
            raise UploadTooLarge(f"a sweep spec is at most {cap} bytes", loc=["body"])
    # parsing (up to max_spec_bytes of JSON or YAML), validation and planning all run in a worker thread
    status = await anyio.to_thread.run_sync(lambda: jobs.submit(decode_spec(bytes(body), kind), owner))
    return JSONResponse(SweepStatus.model_validate(status).model_dump(), status_code=202,
                        headers={"Location": f"/v1/sweeps/{status['id']}"})


@router.get("", response_model=SweepList, operation_id="list_sweeps", summary="List sweeps")
async def list_sweeps(request: Request) -> SweepList:
    """Every stored sweep job, oldest first."""
    return SweepList(sweeps=await anyio.to_thread.run_sync(_jobs(request).list))


@router.get("/{sweep_id}", response_model=SweepStatus, operation_id="get_sweep", summary="Sweep progress",
            responses=error_responses(404, 422))
async def get_sweep(request: Request, sweep_id: str = SweepIdPath) -> SweepStatus:
    """State (`queued`, `running`, `done`, `failed`, `cancelled`), traces done of total, elapsed and
    estimated remaining time, and the failures with their reasons."""
    return SweepStatus.model_validate(await anyio.to_thread.run_sync(_jobs(request).status, sweep_id))


@router.get("/{sweep_id}/results", operation_id="get_sweep_results", summary="Sweep results",
            responses={200: {"description": "The table: Parquet, CSV or JSON ({columns, rows}).",
                             "content": {_MEDIA["parquet"]: {}, "text/csv": {}, "application/json": {}}},
                       **error_responses(404, 422)})
async def get_sweep_results(
    request: Request,
    sweep_id: str = SweepIdPath,
    format: Literal["parquet", "csv", "json"] = Query("parquet", description="Table format."),
    table: Literal["results", "localization"] = Query(
        "results", description="`results`: one row per (position, frequency, receiver); `localization`: one per "
                               "(position, frequency, method)."),
) -> Response:
    """The rows stored so far (all of them once `state` is `done`); headers `X-Sweep-State` and
    `X-Sweep-Complete` say which."""
    body, status = await anyio.to_thread.run_sync(_jobs(request).results, sweep_id, format, table)
    complete = status["tasks_done"] == status["tasks_total"]
    name = f"{sweep_id}-{table}.{format}"
    return Response(body, media_type=_MEDIA[format], headers={
        "X-Sweep-State": status["state"], "X-Sweep-Complete": "true" if complete else "false",
        "Content-Disposition": f'attachment; filename="{name}"'})


@router.delete("/{sweep_id}", response_model=SweepStatus, operation_id="cancel_sweep", summary="Cancel a sweep",
               responses=error_responses(401, 403, 404, 409, 422))
@declare(body=None, cost="none: writes a cancellation file, or removes a finished job", keyed=True)
async def cancel_sweep(request: Request, sweep_id: str = SweepIdPath) -> SweepStatus:
    """A queued or running sweep is cancelled (its finished tasks' rows stay available); a finished
    (`done`, `failed`, `cancelled`) one is deleted with its results (`deleted: true`)."""
    requester = writer(request, request.app.state.capsule.settings)
    return SweepStatus.model_validate(await anyio.to_thread.run_sync(_jobs(request).cancel, sweep_id, requester))
