"""Sweep jobs: submit, follow, fetch results, cancel (``docs/sweeps.md``, "HTTP")."""

from __future__ import annotations

from typing import Literal

import anyio.to_thread
from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.responses import JSONResponse

from service.admission import declare
from service.errors import UploadTooLarge, error_responses
from service.operations.sweeps import decode_spec, spec_media_type
from service.schemas.sweeps import SPEC_SCHEMA, SweepList, SweepStatus
from service.security import writer
from service.sweep_jobs import SweepJobs

router = APIRouter(prefix="/v1/sweeps", tags=["sweeps"])
SweepIdPath = Path(..., pattern=r"^sw-[0-9a-f]{16}$", description="Sweep id (`sw-` + 16 hex digits).",
                   examples=["sw-0123456789abcdef"])
_SUBMIT = {"requestBody": {"required": True, "content": {
    "application/json": {"schema": SPEC_SCHEMA},
    "application/yaml": {"schema": SPEC_SCHEMA}}}}  # the same spec, as YAML
_MEDIA = {"parquet": "application/vnd.apache.parquet", "csv": "text/csv; charset=utf-8",
          "json": "application/json"}


def _jobs(request: Request):
    return request.app.state.sweeps


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
