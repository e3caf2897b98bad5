"""Models of the full-wave cross-check jobs, POST /v1/fullwave (docs/validation.md, "Over HTTP"): the
request (a channel request plus the FDTD model's options) and a job's status."""

from __future__ import annotations

import copy
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, create_model

from service.schemas import Strict, int_range
from service.schemas.channel import ChannelRequest
from service.schemas.constants import FDTD_DEFAULTS

#: The channel request's fields a full-wave job takes (all but `outputs`: the report is per receiver).
CHANNEL_FIELDS = tuple(name for name in ChannelRequest.model_fields if name != "outputs")
_EXAMPLE = {"phantom": "half-space", "frequency_hz": 402e6,
            "transmitter": {"position_m": [0.0, 0.5, 0.0], "polarization": [0, 0, 1], "pattern": "dipole"},
            "receivers": [{"name": "r3cm", "position_m": [0.03, 0.5, 0.0], "pattern": "dipole"}],
            "rays": 2000, "cell_m": 0.004, "coarse_factor": 1.5, "margin_m": 0.012, "pml_cells": 6}


class _FullwaveBase(Strict):
    """A full-wave cross-check: a channel request (the fields of POST /v1/channel but `outputs`,
    `scenario` included) exported to a gprMax FDTD model at one or two cell sizes, run, and compared
    per receiver with the tracer (docs/validation.md)."""

    model_config = ConfigDict(json_schema_extra={
        "allOf": copy.deepcopy(ChannelRequest.model_config["json_schema_extra"]["allOf"]),
        "examples": [_EXAMPLE, {"scenario": "thesis-fig-5-6", "rays": 20000, "export_only": True}]})


FullwaveRequest = create_model(
    "FullwaveRequest",
    __base__=_FullwaveBase,
    __doc__=_FullwaveBase.__doc__,
    **{name: (ChannelRequest.model_fields[name].annotation, copy.copy(ChannelRequest.model_fields[name]))
       for name in CHANNEL_FIELDS},
    cell_m=(float, Field(FDTD_DEFAULTS["cell_m"], ge=1e-4, le=0.02,
                         description="FDTD cell edge [m] of the first run.")),
    coarse_factor=(float | None, Field(
        1.5, ge=0.0, le=4.0, description="The second run's cells are this many times the first's, for the FDTD's "
        "discretisation estimate (below 1: finer); 0 or null: one run [-].")),
    margin_m=(float, Field(FDTD_DEFAULTS["margin_m"], ge=0.0, le=0.5,
                           description="Margin around the antennas' box [m] (tissue it cuts runs into the PML).")),
    pml_cells=(int_range(4, 40), Field(FDTD_DEFAULTS["pml_cells"], description="Absorbing layer thickness [cells].")),
    export_only=(bool, Field(False, description="Write the gprMax inputs (and a report without FDTD numbers) "
                             "at once, run nothing: works on a server without gprMax.")),
)


class FullwaveRun(BaseModel):
    cell_m: float = Field(description="FDTD cell edge [m].")
    input: str = Field(description="The gprMax input file's name (GET .../files/{name}).")
    cells: list[int] = Field(description="Cells per axis, PML included.")
    iterations: int = Field(description="Time steps.")
    cell_updates: int = Field(description="cells x time steps.")


class FullwaveStatus(BaseModel):
    """A full-wave job's progress. `runs_done`/`runs_total` count gprMax runs (cell sizes);
    `progress` is the fraction of the job's FDTD cell updates done (gprMax's own step count)."""

    model_config = ConfigDict(json_schema_extra={"examples": [{
        "id": "fw-0123456789abcdef", "phantom": "half-space", "state": "running", "export_only": False,
        "runs": [{"cell_m": 0.004, "input": "model_40.in", "cells": [26, 19, 18], "iterations": 988,
                  "cell_updates": 8785296}],
        "runs_done": 0, "runs_total": 1, "run": 0, "stage": "gprmax", "iteration": 420, "iterations": 985,
        "progress": 0.43, "elapsed_s": 1.9, "eta_s": 2.5, "error": None, "files": ["model_40.in", "model_40.log"],
        "created_at": 1.7e9, "started_at": 1.7e9, "finished_at": None, "cancel_requested": False}]})

    id: str
    phantom: str
    state: Literal["queued", "running", "done", "failed", "cancelled"]
    export_only: bool
    runs: list[FullwaveRun] = Field(description="The gprMax models, in the order they run.")
    runs_done: int = Field(description="gprMax runs finished (and compared with the tracer).")
    runs_total: int
    run: int | None = Field(description="Index of the run in progress (null when none is).")
    stage: Literal["gprmax", "tracer"] | None = Field(description="What the run in progress is doing.")
    iteration: int = Field(description="Time steps gprMax has done in the run in progress.")
    iterations: int = Field(description="Time steps of the run in progress (gprMax's count).")
    progress: float = Field(description="Fraction of the job's cell updates done [-].")
    elapsed_s: float = Field(description="Wall time spent running, over every run of the job [s].")
    eta_s: float | None = Field(description="Estimated time left [s] (null until gprMax has made progress).")
    error: str | None = Field(description="Why the job failed.")
    files: list[str] = Field(description="Files downloadable now (GET /v1/fullwave/{id}/files/{name}): the gprMax "
                             "inputs, finished outputs and logs, the report.")
    created_at: float | None
    started_at: float | None
    finished_at: float | None
    cancel_requested: bool
    deleted: bool | None = Field(None, description="DELETE only: the finished job and its files were removed.")


class FullwaveSummary(BaseModel):
    id: str
    phantom: str
    state: str
    runs_done: int
    runs_total: int
    created_at: float | None


class FullwaveList(BaseModel):
    jobs: list[FullwaveSummary]


__all__ = ["CHANNEL_FIELDS", "FullwaveList", "FullwaveRequest", "FullwaveStatus", "FullwaveSummary"]
