"""Models of sensor-layout design, POST /v1/design/coverage and /v1/design/layout (docs/design.md).

The requests mirror the library's specs (:mod:`design.coverage`, :mod:`design.layout`), which check
every value again with the phantom at hand (sites, centrelines, candidates, constraints): a 422
from either names the field.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from service.limits import MAX_INTERACTIONS, MAX_RAYS, capped
from service.schemas import Int, PhantomId, Strict, Vec3, int_range

COVERAGE_EXAMPLE: dict[str, Any] = {
    "phantom": "torso", "positions": {"along_tract": {"ds_m": 0.1}},
    "candidates": {"spacing_m": 0.04, "region": {"min_m": [-1, -1, -0.1], "max_m": [1, 1, 0.36]}},
    "frequency_hz": 402e6, "channel": {"rays": 20000, "max_interactions": 4, "dynamic_range_db": 40},
}
LAYOUT_EXAMPLE: dict[str, Any] = {
    "coverage": "cv-0123456789abcdef", "sensors": 8, "criterion": "p90",
    "constraints": {"belts": [{"height_m": 0.05, "tolerance_m": 0.02}, {"height_m": 0.125, "tolerance_m": 0.02}],
                    "min_spacing_m": 0.03},
    "evaluate": {"trials": 10},
}


class AlongTract(Strict):
    ds_m: float = Field(0.02, ge=1e-3, le=10.0, description="Capsule positions every ds_m along it [m].")
    start_m: float = Field(0.0, ge=0.0, description="First arc length [m].")
    stop_m: float | None = Field(None, ge=0.0, description="Last arc length [m] (null: the end).")
    centreline: str = Field("gi_tract", min_length=1, max_length=64, description="The phantom's centreline.")


class Positions(Strict):
    """Exactly one of `along_tract`, `sites` (null: every capsule site), `positions_m`."""

    model_config = ConfigDict(json_schema_extra={"oneOf": [{"required": ["along_tract"]}, {"required": ["sites"]},
                                                           {"required": ["positions_m"]}]})
    along_tract: AlongTract | None = None
    sites: list[str] | None = Field(None, min_length=1, max_length=2000)
    positions_m: list[Vec3] | None = Field(None, min_length=1, max_length=2000)

    @model_validator(mode="after")
    def _one(self) -> "Positions":
        given = [k for k in ("along_tract", "sites", "positions_m") if k in self.model_fields_set]
        if len(given) != 1:
            raise ValueError("give exactly one of along_tract, sites or positions_m")
        return self


class Region(Strict):
    min_m: Vec3 = Field(description="Lower corner of the box [m].")
    max_m: Vec3 = Field(description="Upper corner of the box [m].")


class CandidateOptions(Strict):
    spacing_m: float | None = Field(0.015, ge=0.002, le=0.5, description="Spacing of the candidates on the outer "
                                    "surface [m]; null: its mesh vertices.")
    depth_m: float = Field(0.001, ge=1e-5, le=0.05, description="Depth of a contact candidate below the surface [m].")
    region: Region | None = Field(None, description="Keep only candidates inside this box.")
    include_sites: bool = Field(True, description="Add the phantom's sensor sites (the baseline of a layout).")


class CoverageChannel(Strict):
    rays: Int = Field(30_000, ge=1, le=MAX_RAYS, description="Rays launched per capsule position.",
                      json_schema_extra=capped("max_rays"))
    max_interactions: Int = Field(4, ge=1, le=MAX_INTERACTIONS, json_schema_extra=capped("max_interactions"))
    dynamic_range_db: float = Field(40.0, gt=0.0, le=300.0)
    near_field: bool = True
    capsule_polarization: Vec3 = Field([0.0, 0.0, 1.0], description="The capsule antenna's axis.")


class Link(Strict):
    transmit_power_dbm: float = Field(-16.0206, ge=-100.0, le=60.0, description="Transmit power [dBm] (MICS EIRP).")
    noise_figure_db: float = Field(0.0, ge=0.0, le=60.0)
    temperature_k: float = Field(290.0, ge=1.0, le=1e4)
    bandwidth_hz: float | None = Field(None, ge=1.0, description="Noise bandwidth [Hz]; null: the waveform's fs / 2.")


class CoverageWaveform(Strict):
    duration_s: float = Field(25e-9, gt=0.0, le=1e-3, description="Tone burst duration T0 [s].")
    sample_rate_hz: float = Field(20e9, gt=0.0, le=1e12, description="Sample rate [Hz]; the SNR is per sample.")


class CoverageRequest(Strict):
    """Coverage over the skin (docs/design.md, "Coverage"): per capsule position and sensor candidate,
    the received power, SNR, first-arrival delay, whether a direct path exists, and the eikonal model."""

    model_config = ConfigDict(json_schema_extra={"examples": [COVERAGE_EXAMPLE]})
    phantom: PhantomId = "torso"
    positions: Positions = Field(default_factory=lambda: Positions(along_tract=AlongTract()))
    candidates: CandidateOptions = Field(default_factory=CandidateOptions)
    frequency_hz: float = Field(402e6, ge=1e6, le=20e9, description="Carrier [Hz].")
    channel: CoverageChannel = Field(default_factory=CoverageChannel)
    link: Link = Field(default_factory=Link)
    waveform: CoverageWaveform = Field(default_factory=CoverageWaveform)
    cell_size_m: float = Field(0.004, ge=0.001, le=0.02, description="Travel-time grid cell [m].")


class JobState(BaseModel):
    id: str
    state: Literal["queued", "running", "done", "failed", "cancelled"]
    elapsed_s: float = Field(description="Wall time spent running [s].")
    eta_s: float | None = Field(None, description="Estimated time left [s].")
    error: str | None = None
    created_at: float | None = None
    started_at: float | None = None
    finished_at: float | None = None
    cancel_requested: bool = False
    deleted: bool | None = Field(None, description="DELETE only: the finished job was removed.")


class CoverageStatus(JobState):
    phantom: str
    done: int = Field(description="Capsule positions traced.")
    total: int = Field(description="Capsule positions of the job.")
    positions: int
    candidates: int
    links: int = Field(description="positions x candidates.")
    receivers_per_trace: int
    failures: list[dict[str, Any]] = Field(default_factory=list)


class CoverageList(BaseModel):
    jobs: list[CoverageStatus]


class Belt(Strict):
    height_m: float = Field(description="Height of the belt along `axis` [m].")
    tolerance_m: float = Field(0.01, gt=0.0, description="Candidates within this of the height are on it [m].")
    count: int_range(0, 64) | None = Field(None, description="Sensors on this belt (all belts or none).")


class KeepOutBox(Strict):
    """A box where no sensor may go."""

    min_m: Vec3 = Field(description="Lower corner [m].")
    max_m: Vec3 = Field(description="Upper corner [m] (each coordinate above min_m's).")


class KeepOutBall(Strict):
    """A ball where no sensor may go."""

    centre_m: Vec3 = Field(description="Centre [m].")
    radius_m: float = Field(gt=0.0, le=10.0, description="Radius [m].")


KeepOut = KeepOutBox | KeepOutBall


class Constraints(Strict):
    axis: Vec3 = Field([0.0, 0.0, 1.0], description="The direction heights are measured along.")
    belts: list[Belt] = Field(default_factory=list, max_length=16)
    keep_out: list[KeepOut] = Field(default_factory=list, max_length=64)
    min_spacing_m: float = Field(0.0, ge=0.0, description="Least distance between two sensors [m].")


class Search(Strict):
    restarts: int_range(0, 32) = Field(4, description="Random starts after the greedy one.")
    seed: int_range(0, 2**31 - 1) = 0
    exact_limit: int_range(0, 10**6) = Field(20_000, description="Enumerate every set when at most this many.")
    max_passes: int_range(1, 200) = Field(50, description="Swap passes per start, at most.")


class Evaluate(Strict):
    trials: int_range(1, 1000) = Field(20, description="Monte Carlo trials per capsule position.")
    seed: int_range(0, 2**31 - 1) = 0
    rays: int_range(1, MAX_RAYS) = Field(100_000, json_schema_extra=capped("max_rays"))
    max_interactions: int_range(1, MAX_INTERACTIONS) = Field(6, json_schema_extra=capped("max_interactions"))


class LayoutRequest(Strict):
    """Optimise N contact sensors on a finished coverage (docs/design.md, "Layout")."""

    model_config = ConfigDict(json_schema_extra={"examples": [LAYOUT_EXAMPLE]})
    coverage: str = Field(pattern=r"^cv-[0-9a-f]{16}$", description="A done coverage job's id.")
    sensors: Int = Field(ge=1, le=64, description="How many sensors to place.")
    criterion: Literal["p90", "mean"] = Field("p90", description="Statistic of the position bound along the tract.")
    model_error: Literal["none", "bias"] = Field("none", description="`none`: the position CRLB; `bias`: plus the "
                                                 "delay model's own error (grid, linearised bias of each link's "
                                                 "noiseless-ranging minus eikonal mismatch).")
    ranging: Literal["toa", "rss"] = Field("toa", description="Whose position bound: `toa` (GCC, the travel-time "
                                           "model) or `rss` (the CM2 path-loss model's, distance-based).")
    rss_model: Literal["cm2_deep_tissue", "cm2_near_surface"] = Field("cm2_deep_tissue", description="The path-loss "
                                                                      "model of ranging rss.")
    max_model_error_s: float | None = Field(None, ge=0.0, le=1e-6, description="A link whose noiseless ranging delay "
                                            "departs from the travel-time model by more is not usable [s]; null: "
                                            "the travel-time grid's stated error n_max h / c.")
    snr_db: float | None = Field(None, ge=-50.0, le=200.0, description="Every link's SNR [dB]; null: the coverage's "
                                 "link budget per link.")
    min_snr_db: float | None = Field(None, ge=-300.0, le=200.0, description="Links below are not detected [dB].")
    require_direct_path: bool = True
    min_sensors: Int = Field(4, ge=1, le=64, description="Usable links a position needs to be covered.")
    constraints: Constraints = Field(default_factory=Constraints)
    search: Search = Field(default_factory=Search)
    evaluate: Evaluate | None = Field(default_factory=Evaluate, description="End-to-end model-based fixes of the "
                                      "optimised and built-in layouts; null: bounds only.")


class LayoutSensor(BaseModel):
    position_m: list[float]
    candidate_index: int
    belt: int | None = None
    site: str | None = None


class LayoutResult(BaseModel):
    sensors: list[LayoutSensor]
    criterion: str
    criterion_m: float | None = Field(description="The optimised layout's criterion [m] (null: uncovered positions "
                                      "make it infinite).")
    baseline_criterion_m: float | None = Field(description="The best same-size subset of the phantom's sensor sites, "
                                               "found the same way [m].")
    uncovered_positions: int
    ranging: str = "toa"
    model_tolerance_s: float | None = Field(None, description="The model-mismatch tolerance applied [s] (TOA).")
    baseline_uncovered_positions: int | None = None
    baseline_sensors: list[LayoutSensor] | None = None
    search: dict[str, Any]
    positions: dict[str, Any]
    per_organ: dict[str, Any]
    evaluation: dict[str, Any] | None = None
    baseline_evaluation: dict[str, Any] | None = None


class LayoutStatus(JobState):
    coverage: str
    stage: str | None = Field(None, description="What the running job is doing.")
    result: LayoutResult | None = Field(None, description="When done.")


class LayoutList(BaseModel):
    jobs: list[LayoutStatus]


__all__ = ["CoverageList", "CoverageRequest", "CoverageStatus", "LayoutList", "LayoutRequest", "LayoutResult",
           "LayoutStatus"]
