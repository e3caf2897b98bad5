"""Full-wave cross-check jobs: submit, follow, fetch the report and the gprMax files, cancel
(docs/validation.md, "Over HTTP")."""

from __future__ import annotations

from typing import Literal

import anyio.to_thread
from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.responses import FileResponse, JSONResponse

from service.admission import declare
from service.errors import error_responses
from service.fullwave_jobs import FullwaveJobs
from service.schemas.fullwave import FullwaveList, FullwaveRequest, FullwaveStatus
from service.security import writer

router = APIRouter(prefix="/v1/fullwave", tags=["fullwave"])

JobIdPath = Path(..., pattern=r"^fw-[0-9a-f]{16}$", description="Job id (`fw-` + 16 hex digits).",
                 examples=["fw-0123456789abcdef"])
#: The only names a job's files can have: its gprMax inputs, outputs and logs, and its report.
FileNamePath = Path(..., pattern=r"^(model_[0-9]{1,6}\.(in|h5|log)|report\.(json|md))$",
                    description="`model_<cell in 0.1 mm>.in|.h5|.log`, `report.json` or `report.md`.",
                    examples=["model_40.in"])


def _jobs(request: Request):
    return request.app.state.fullwave


@router.post("", status_code=202, response_model=FullwaveStatus, operation_id="submit_fullwave",
             summary="Submit a full-wave cross-check", responses=error_responses(400, 401, 404, 413, 422, 501, 503))
@declare(body="max_json_body_bytes", cost=FullwaveJobs.estimate, keyed=True)
async def submit_fullwave(req: FullwaveRequest, request: Request) -> JSONResponse:  # type: ignore[valid-type]
    """Validate the channel request and the FDTD models (their size against the server's work bound,
    the antennas outside the absorbing layer), write the gprMax inputs and queue the job on the
    server's one job queue (shared with the sweeps: one heavy job at a time). Answers 202 with its
    status at once; `export_only` jobs are already `done`. At most `fullwave_max_queue` jobs may be
    queued or running (503 + Retry-After beyond); 501 when gprMax is not installed and the job would
    need it."""
    owner = writer(request, request.app.state.capsule.settings)
    status = await anyio.to_thread.run_sync(_jobs(request).submit, req, owner)
    return JSONResponse(FullwaveStatus.model_validate(status).model_dump(), status_code=202,
                        headers={"Location": f"/v1/fullwave/{status['id']}"})


@router.get("", response_model=FullwaveList, operation_id="list_fullwave", summary="List full-wave jobs")
async def list_fullwave(request: Request) -> FullwaveList:
    """Every stored full-wave job, oldest first."""
    return FullwaveList(jobs=await anyio.to_thread.run_sync(_jobs(request).list))


@router.get("/{job_id}", response_model=FullwaveStatus, operation_id="get_fullwave", summary="Full-wave job progress",
            responses=error_responses(404, 422))
async def get_fullwave(request: Request, job_id: str = JobIdPath) -> FullwaveStatus:
    """State (`queued`, `running`, `done`, `failed`, `cancelled`), gprMax runs done of total, the run
    in progress (its stage and gprMax's time steps), the fraction of the work done, elapsed and
    estimated remaining time, the files downloadable now, and the error of a failed job."""
    return FullwaveStatus.model_validate(await anyio.to_thread.run_sync(_jobs(request).status, job_id))


@router.get("/{job_id}/report", operation_id="get_fullwave_report", summary="Full-wave report",
            responses={200: {"description": "The report: JSON (per run and receiver, FDTD and tracer metrics and "
                                            "their differences; the discretisation estimate) or Markdown tables.",
                             "content": {"application/json": {}, "text/markdown": {}}},
                       **error_responses(404, 409, 422)})
async def get_fullwave_report(
    request: Request,
    job_id: str = JobIdPath,
    format: Literal["json", "md"] = Query("json", description="`json` (report.json) or `md` (report.md)."),
) -> Response:
    """The job's report (docs/validation.md, "The report, per receiver"), once it is `done` (409 before)."""
    body = await anyio.to_thread.run_sync(_jobs(request).report, job_id, format)
    media = "application/json" if format == "json" else "text/markdown; charset=utf-8"
    return Response(body, media_type=media,
                    headers={"Content-Disposition": f'attachment; filename="{job_id}-report.{format}"'})


@router.get("/{job_id}/files/{name}", operation_id="get_fullwave_file", summary="A full-wave job's file",
            responses={200: {"description": "The file: a gprMax input (text), output (HDF5, once its run has "
                                            "finished), log, or the report.",
                             "content": {"text/plain": {}, "application/x-hdf5": {}, "application/json": {},
                                         "text/markdown": {}}},
                       **error_responses(404, 422)})
async def get_fullwave_file(request: Request, job_id: str = JobIdPath, name: str = FileNamePath) -> Response:
    """One of the files the job's status lists: e.g. `model_20.in` to run the same model with gprMax
    on one's own cluster. Only the job's own files, by name (the pattern admits no path)."""
    content, media = await anyio.to_thread.run_sync(_jobs(request).file, job_id, name)
    if isinstance(content, bytes):  # a text file, the server's paths redacted
        return Response(content, media_type=media,
                        headers={"Content-Disposition": f'attachment; filename="{job_id}-{name}"'})
    return FileResponse(content, media_type=media, filename=f"{job_id}-{name}")


@router.delete("/{job_id}", response_model=FullwaveStatus, operation_id="cancel_fullwave",
               summary="Cancel or delete a full-wave job", responses=error_responses(401, 403, 404, 409, 422))
@declare(body=None, cost="none: writes a cancellation file, or removes a finished job", keyed=True)
async def cancel_fullwave(request: Request, job_id: str = JobIdPath) -> FullwaveStatus:
    """A queued or running job is cancelled (its gprMax process is killed; the files written so far
    stay); a finished (`done`, `failed`, `cancelled`) one is deleted with its files (`deleted: true`)."""
    requester = writer(request, request.app.state.capsule.settings)
    return FullwaveStatus.model_validate(await anyio.to_thread.run_sync(_jobs(request).cancel, job_id, requester))
