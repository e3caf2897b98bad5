"""Models of the sweep jobs (POST/GET/DELETE /v1/sweeps, docs/sweeps.md) and the JSON Schema of a
sweep spec (the spec itself is validated as a whole by :mod:`sweeps.spec`; the work:
:mod:`service.operations.sweeps` and :mod:`service.sweep_jobs`)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from service.limits import LIMIT_KEY
from service.schemas import FREQUENCY_MAX_HZ, FREQUENCY_MIN_HZ
from sweeps.spec import LIMITS


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
#: The sweep spec's shape, from sweeps.spec's own limits (the server lowers the receivers, rays,
#: interactions and trials marked with service.limits.LIMIT_KEY in its served document). Rules
#: that depend on the phantom (sites, organs,
#: centrelines) or relate fields (bands to carriers, localizers to ranging methods) are the
#: validator's, sweeps.spec, whose 422 names the field.
SPEC_SCHEMA = {
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
            "default": "sensors", LIMIT_KEY: "max_receivers"},
        "frequencies_hz": {"type": "array",
                           "items": {"type": "number", "minimum": FREQUENCY_MIN_HZ, "maximum": FREQUENCY_MAX_HZ},
                           "minItems": 1, "maxItems": LIMITS.max_frequencies, "uniqueItems": True,
                           "default": [402e6]},
        "channel": {
            "type": "object", "additionalProperties": False,
            "description": "The ChannelSpec knobs of every trace (defaults: POST /v1/channel's), a band around each "
                           "carrier ({span_hz, points}) or absolute, and the capsule antenna.",
            "properties": {
                "max_interactions": {"type": "integer", "minimum": 1, "maximum": LIMITS.max_interactions,
                                     LIMIT_KEY: "max_interactions"},
                "rays": {"type": "integer", "minimum": 1, "maximum": LIMITS.max_rays, LIMIT_KEY: "max_rays"},
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
        "trials": {"type": "integer", "minimum": 1, "maximum": LIMITS.max_trials, "default": 100,
                   LIMIT_KEY: "max_trials"},
        "seed": {"type": "integer", "minimum": 0, "maximum": 2**53 - 1, "default": 0},
        "chunk_positions": {"type": "integer", "minimum": 1, "maximum": LIMITS.max_chunk_positions, "default": 4},
    },
    "example": {"name": "belt along the tract", "phantom": "torso",
                "capsule_positions": {"along_tract": {"ds_m": 0.05}}, "receivers": "sensors",
                "frequencies_hz": [402e6], "channel": {"rays": 2000, "max_interactions": 3},
                "ranging": {"toa": {"methods": ["gcc"], "snr_db": 30}}, "trials": 20, "seed": 1},
}
