"""Sensor-layout design: coverage over the skin and optimised layouts, as jobs on the one queue
(docs/design.md, "Over HTTP")."""

from __future__ import annotations

from typing import Literal

import anyio.to_thread
import numpy as np
from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.responses import JSONResponse

from service.admission import declare
from service.design_jobs import CoverageJobs, LayoutJobs
from service.errors import error_responses
from service.schemas.design import (
    CoverageList,
    CoverageRequest,
    CoverageStatus,
    LayoutList,
    LayoutRequest,
    LayoutStatus,
)
from service.security import writer

router = APIRouter(prefix="/v1/design", tags=["design"])

CoverageId = Path(..., pattern=r"^cv-[0-9a-f]{16}$", description="Coverage job id (`cv-` + 16 hex digits).",
                  examples=["cv-0123456789abcdef"])
LayoutId = Path(..., pattern=r"^ly-[0-9a-f]{16}$", description="Layout job id (`ly-` + 16 hex digits).",
                examples=["ly-0123456789abcdef"])


def _coverage(request: Request):
    return request.app.state.coverage


def _layout(request: Request):
    return request.app.state.layout


@router.post("/coverage", status_code=202, response_model=CoverageStatus, operation_id="submit_coverage",
             summary="Submit a coverage map", responses=error_responses(400, 401, 404, 413, 422, 503))
@declare(body="max_json_body_bytes", cost=CoverageJobs.estimate, keyed=True)
async def submit_coverage(req: CoverageRequest, request: Request) -> JSONResponse:
    """Plan the capsule positions and the sensor candidates on the phantom's outermost surface, bound the
    work (positions x candidates, each trace's rays and memory) and queue the job: one trace per capsule
    position serves every candidate. 202 with its status at once."""
    owner = writer(request, request.app.state.capsule.settings)
    body = req.model_dump(mode="json", exclude_unset=True)
    status = await anyio.to_thread.run_sync(_coverage(request).submit, body, owner)
    return JSONResponse(CoverageStatus.model_validate(status).model_dump(), status_code=202,
                        headers={"Location": f"/v1/design/coverage/{status['id']}"})


@router.get("/coverage", response_model=CoverageList, operation_id="list_coverage", summary="List coverage jobs")
async def list_coverage(request: Request) -> CoverageList:
    return CoverageList(jobs=await anyio.to_thread.run_sync(_coverage(request).list))


@router.get("/coverage/{job_id}", response_model=CoverageStatus, operation_id="get_coverage",
            summary="Coverage job progress", responses=error_responses(404, 422))
async def get_coverage(request: Request, job_id: str = CoverageId) -> CoverageStatus:
    """State, capsule positions traced of the total, elapsed and estimated remaining time."""
    return CoverageStatus.model_validate(await anyio.to_thread.run_sync(_coverage(request).status, job_id))


@router.get("/coverage/{job_id}/results", operation_id="get_coverage_results", summary="The coverage table",
            responses={200: {"description": "One row per (capsule position, candidate): Parquet, CSV or JSON "
                                            "(docs/design.md, \"Coverage\"); the rows stored so far while running.",
                             "content": {"application/vnd.apache.parquet": {}, "text/csv": {},
                                         "application/json": {}}},
                       **error_responses(404, 422)})
async def get_coverage_results(request: Request, job_id: str = CoverageId,
                               format: Literal["parquet", "csv", "json"] = Query("parquet")) -> Response:
    from sweeps.store import parquet_bytes
    from sweeps.table import to_csv_bytes, to_json_bytes

    def body():
        table = _coverage(request).table(job_id)
        if format == "csv":
            return to_csv_bytes(table), "text/csv"
        if format == "json":
            return to_json_bytes(table), "application/json"
        return parquet_bytes(table), "application/vnd.apache.parquet"

    data, media = await anyio.to_thread.run_sync(body)
    return Response(data, media_type=media,
                    headers={"Content-Disposition": f'attachment; filename="{job_id}.{format}"'})


def _map(request: Request, job_id: str, metric: str, position: int | None, reduce: str):
    from design.coverage import CoverageDir, Plan
    from design.maps import candidate_values

    jobs = _coverage(request)
    d = jobs.done_dir(job_id, ["path", "job_id"])
    store = CoverageDir(d)
    plan = Plan.from_dict(store.record()["plan"])
    values = candidate_values(store.table(), len(plan.positions), len(plan.candidates), metric, position, reduce)
    return plan, values


@router.get("/coverage/{job_id}/map", operation_id="get_coverage_map", summary="Per-candidate values of a coverage",
            responses=error_responses(404, 409, 422))
async def get_coverage_map(
    request: Request, job_id: str = CoverageId,
    metric: Literal["snr_db", "rx_power_dbm", "path_gain_db", "first_delay_s", "eikonal_delay_s", "direct_path",
                    "paths"] = Query("snr_db"),
    position: int | None = Query(None, ge=0, description="One capsule position's values; default: all, reduced."),
    reduce: Literal["median", "min", "max", "mean"] = Query("median"),
) -> JSONResponse:
    """What the viewer's coverage layer colours the skin with: every candidate's position and its value
    (null where none: no path), for one capsule position or reduced over all of them."""
    plan, values = await anyio.to_thread.run_sync(_map, request, job_id, metric, position, reduce)
    return JSONResponse({"metric": metric, "position": position, "reduce": reduce,
                         "positions_m": plan.positions.positions_m.tolist(),
                         "candidates_m": plan.candidates.positions_m.tolist(),
                         "sites": list(plan.candidates.site),
                         "values": [float(v) if np.isfinite(v) else None for v in values]})


@router.get("/coverage/{job_id}/plot", operation_id="get_coverage_plot", summary="The coverage map as a figure",
            responses={200: {"description": "The skin unrolled (polar angle x height), candidates coloured by the "
                                            "metric.", "content": {"image/png": {}}}, **error_responses(404, 409, 422)})
async def get_coverage_plot(
    request: Request, job_id: str = CoverageId,
    metric: Literal["snr_db", "rx_power_dbm", "path_gain_db", "first_delay_s", "eikonal_delay_s", "direct_path",
                    "paths"] = Query("snr_db"),
    position: int | None = Query(None, ge=0),
    reduce: Literal["median", "min", "max", "mean"] = Query("median"),
) -> Response:
    from design.maps import UNITS
    from plots.coverage import skin_coverage
    from plots.figure import figure_bytes

    def draw():
        plan, values = _map(request, job_id, metric, position, reduce)
        scale = 1e9 if metric.endswith("delay_s") else 1.0
        site = np.array([bool(s) for s in plan.candidates.site])
        fig = skin_coverage(plan.candidates.positions_m[~site], values[~site] * scale, label=UNITS[metric],
                            sites_m=plan.candidates.positions_m[site], title=f"{job_id}: {metric} ({reduce})")
        return figure_bytes(fig, "png")

    return Response(await anyio.to_thread.run_sync(draw), media_type="image/png")


@router.delete("/coverage/{job_id}", response_model=CoverageStatus, operation_id="cancel_coverage",
               summary="Cancel or delete a coverage job", responses=error_responses(401, 404, 409, 422))
@declare(body=None, cost="none: writes a cancellation file, or removes a finished job", keyed=True)
async def cancel_coverage(request: Request, job_id: str = CoverageId) -> CoverageStatus:
    requester = writer(request, request.app.state.capsule.settings)
    return CoverageStatus.model_validate(await anyio.to_thread.run_sync(_coverage(request).cancel, job_id, requester))


@router.post("/layout", status_code=202, response_model=LayoutStatus, operation_id="submit_layout",
             summary="Submit a layout optimisation", responses=error_responses(400, 401, 404, 409, 413, 422, 503))
@declare(body="max_json_body_bytes", cost=LayoutJobs.estimate, keyed=True)
async def submit_layout(req: LayoutRequest, request: Request) -> JSONResponse:
    """Check the layout against its (done) coverage, bound the search and queue it: N sensors chosen from
    the coverage's candidates under the constraints, minimising the mean or 90th-percentile position
    bound along the tract, beside the best same-size subset of the phantom's sensor sites."""
    owner = writer(request, request.app.state.capsule.settings)
    body = req.model_dump(mode="json", exclude_unset=True)
    if "evaluate" in req.model_fields_set and req.evaluate is None:
        body["evaluate"] = None
    elif "evaluate" not in body:
        body["evaluate"] = {}
    status = await anyio.to_thread.run_sync(_layout(request).submit, body, owner)
    return JSONResponse(LayoutStatus.model_validate(status).model_dump(), status_code=202,
                        headers={"Location": f"/v1/design/layout/{status['id']}"})


@router.get("/layout", response_model=LayoutList, operation_id="list_layout", summary="List layout jobs")
async def list_layout(request: Request) -> LayoutList:
    return LayoutList(jobs=await anyio.to_thread.run_sync(_layout(request).list))


@router.get("/layout/{job_id}", response_model=LayoutStatus, operation_id="get_layout", summary="Layout job and result",
            responses=error_responses(404, 422))
async def get_layout(request: Request, job_id: str = LayoutId) -> LayoutStatus:
    """State and, once done, the result: `sensors` (each `position_m`), `criterion_m`, `baseline_criterion_m`,
    per-position and per-organ bounds, and the end-to-end model-based errors of both layouts."""
    return LayoutStatus.model_validate(await anyio.to_thread.run_sync(_layout(request).status, job_id))


@router.get("/layout/{job_id}/report", operation_id="get_layout_report", summary="Layout report",
            responses={200: {"description": "The result (JSON) or the comparison per organ (Markdown).",
                             "content": {"application/json": {}, "text/markdown": {}}},
                       **error_responses(404, 409, 422)})
async def get_layout_report(request: Request, job_id: str = LayoutId,
                            format: Literal["json", "md"] = Query("md")) -> Response:
    body = await anyio.to_thread.run_sync(_layout(request).report, job_id, format)
    return Response(body, media_type="application/json" if format == "json" else "text/markdown; charset=utf-8")


@router.delete("/layout/{job_id}", response_model=LayoutStatus, operation_id="cancel_layout",
               summary="Cancel or delete a layout job", responses=error_responses(401, 404, 409, 422))
@declare(body=None, cost="none: writes a cancellation file, or removes a finished job", keyed=True)
async def cancel_layout(request: Request, job_id: str = LayoutId) -> LayoutStatus:
    requester = writer(request, request.app.state.capsule.settings)
    return LayoutStatus.model_validate(await anyio.to_thread.run_sync(_layout(request).cancel, job_id, requester))
