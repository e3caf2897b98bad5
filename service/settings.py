"""Service configuration: one pydantic-settings class, read from ``CAPSULE_RT_*`` env vars.

Every limit the API enforces lives here so an operator can tighten it. The
request schema (``openapi.json``) carries the hard ceilings (service.limits, the defaults
below); a setting can lower a limit, never raise it above its schema ceiling
(requests beyond the setting get a 422 that names the field and the limit:
service.admission.lower_or_refuse).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from raytrace.solver.config import TracerConfig
from service.limits import MAX_BAND_POINTS, MAX_INTERACTIONS, MAX_RAYS, MAX_RECEIVERS, MAX_TRIALS  # the ceilings

#: Shortest accepted API key (characters): a key is a bearer secret, not a password.
MIN_API_KEY_CHARS = 16

CommaList = Annotated[list[str], NoDecode]


class Settings(BaseSettings):
    """CapsuleRT service settings (environment variables ``CAPSULE_RT_<NAME>``)."""

    model_config = SettingsConfigDict(env_prefix="CAPSULE_RT_", extra="ignore")

    host: str = Field("127.0.0.1", description="Interface `capsule-rt serve` binds to; with the port, the server's "
                      "own origin `http://HOST:PORT`, from whose pages writes are accepted (a loopback or wildcard "
                      "HOST: `localhost`, `127.0.0.1`, `[::1]`; any other public name goes in CORS_ORIGINS).")
    port: int = Field(8000, ge=1, le=65535, description="TCP port of `capsule-rt serve`.")
    workers: int = Field(1, ge=1, le=64, description="Uvicorn worker processes.")
    data_dir: Path = Field(
        Path("data"),
        description="Directory holding uploaded phantoms (`<data_dir>/phantoms/<id>/`); created on start.",
    )
    log_level: str = Field("info", description="Log level (debug, info, warning, error).")
    log_json: bool = Field(True, description="Structured JSON logs (one object per line) on stderr.")

    # Compute limits (each <= its schema ceiling).
    max_rays: int = Field(MAX_RAYS, ge=1, le=MAX_RAYS, description="Max `rays` per channel request.")
    max_interactions: int = Field(
        MAX_INTERACTIONS, ge=0, le=MAX_INTERACTIONS, description="Max `max_interactions` per channel request."
    )
    max_receivers: int = Field(
        MAX_RECEIVERS, ge=1, le=MAX_RECEIVERS, description="Max receivers per channel request."
    )
    max_band_points: int = Field(
        MAX_BAND_POINTS, ge=2, le=MAX_BAND_POINTS, description="Max `band.points` (channel and PDOA)."
    )
    max_trials: int = Field(
        MAX_TRIALS, ge=1, le=MAX_TRIALS, description="Max Monte Carlo `trials` per ranging request."
    )
    max_ranging_samples: int = Field(
        20_000_000,
        ge=1,
        description="Work bound of one TOA request, refused (422) before it starts beyond it: samples per "
        "trial x trials, and samples per trial x paths (synthesis) [-].",
    )
    max_json_body_bytes: int = Field(
        256 * 1024, ge=1024, description="Max JSON body of the other operations (channel, bounds, localization, "
        "jobs, renders...) and of any undeclared write [bytes]; beyond it: 413."
    )
    max_ranging_body_bytes: int = Field(
        16 * 1024 * 1024, ge=1024, description="Max JSON body of the operations that carry data (ranging profiles, "
        "plots, the track's observations) [bytes]; beyond it: 413."
    )
    max_ray_segments: int = Field(
        50_000_000,
        ge=1,
        description="Work budget of one channel request: ray segments traced before it stops with 503. A request "
        "whose estimated shooting alone exceeds it is refused before any work (422 naming `rays`).",
    )
    max_compute_memory_bytes: int = Field(
        8 * 1024**3,
        ge=64 * 1024**2,
        description="Memory ceiling of the heavy computations of one worker process together [bytes]; each of "
        "the `max_concurrency` running ones gets an equal share. A channel request whose estimated peak "
        "(docs/service.md, memory and work model) exceeds the share is refused before any work (422 naming "
        "the field to lower); the trace also counts its arrays as it allocates them and stops (503) past it.",
    )
    request_deadline_s: float = Field(
        60.0, gt=0, le=3600, description="Wall-time budget of one computation [s]; beyond it: 504."
    )

    # Concurrency.
    max_concurrency: int = Field(
        2, ge=1, le=256, description="Heavy computations (channel, ranging) running at once per worker process."
    )
    max_queue: int = Field(
        8,
        ge=0,
        le=1024,
        description="Heavy requests allowed to wait for a slot; beyond it the server answers 503 + Retry-After.",
    )
    retry_after_s: int = Field(2, ge=1, le=3600, description="Retry-After sent with 503 responses [s].")

    # The tracer's CPU and memory per computation (raytrace.solver.config.TracerConfig).
    tracer_threads: int | None = Field(
        None, ge=1, le=256,
        description="Threads of one channel computation; unset: the CPUs this process may use (its affinity).",
    )
    tracer_launch_batch: int = Field(
        TracerConfig.launch_batch, ge=1_000, le=1_000_000,
        description="Launch directions shot together per thread (each holds its bounce tree in memory).",
    )
    tracer_max_live_rays: int = Field(
        TracerConfig.max_live_rays, ge=10_000, le=100_000_000,
        description="Cap on the live rays of one launch batch (memory bound; must exceed the launch batch).",
    )

    # Uploads.
    max_upload_bytes: int = Field(
        20 * 1024 * 1024, ge=1024, description="Max size of an uploaded .glb [bytes]; beyond it: 413."
    )
    max_manifest_bytes: int = Field(256 * 1024, ge=256, description="Max size of an upload manifest [bytes].")
    max_triangles: int = Field(
        500_000, ge=4, description="Max triangles of an uploaded phantom (all organs together)."
    )
    max_uploads: int = Field(100, ge=0, description="Max stored uploaded phantoms; beyond it an upload gets 507.")
    load_builtins: bool = Field(
        True, description="Build the built-in phantoms (default torso, scenarios) at start."
    )

    # Sweeps (docs/sweeps.md).
    sweep_workers: int | None = Field(
        None, ge=1, le=256, description="Worker processes of a sweep job (default: the CPUs of the machine)."
    )
    sweep_cluster: str | None = Field(
        None, description="Address of an existing Dask scheduler (tcp://host:8786) that runs the sweep jobs instead."
    )
    sweep_max_queue: int = Field(4, ge=1, le=1024, description="Sweep jobs queued or running at once; beyond: 503.")
    sweep_max_traces: int = Field(
        20_000, ge=1, le=100_000, description="Max traces (capsule positions x frequencies) of one sweep."
    )

    # Full-wave cross-checks (docs/validation.md, "Over HTTP").
    fullwave_max_cell_updates: int = Field(
        10_000_000_000, ge=1,
        description="Work bound of one full-wave job: FDTD cells x time steps over all its gprMax runs, refused "
        "(422 naming `cell_m`) before it is queued beyond it [-]. The default admits the layered validation case "
        "at 2 and 1.5 mm cells (2.3e9); gprMax does about 2.6e7 per second on 2 idle cores (1e10: ~6.5 min).",
    )
    fullwave_max_wall_s: float = Field(
        7200.0, gt=0, le=7 * 86400,
        description="Wall time of one full-wave job over all its runs [s]; beyond it gprMax is killed and the job "
        "fails saying so.",
    )
    fullwave_max_queue: int = Field(
        4, ge=1, le=1024, description="Full-wave jobs queued or running at once; beyond: 503."
    )
    fullwave_threads: int | None = Field(
        None, ge=1, le=256, description="OpenMP threads of gprMax (default: the CPUs this process may use)."
    )

    # Sensor-layout design (docs/design.md, "Over HTTP").
    design_max_links: int = Field(
        250_000, ge=1, le=1_000_000,
        description="Max links (capsule positions x sensor candidates) of one coverage job, refused (422 naming "
        "the field) before it is queued beyond it.",
    )
    design_max_queue: int = Field(
        4, ge=1, le=1024, description="Design jobs (coverage and layout, each kind) queued or running at once; "
        "beyond: 503.",
    )

    # Access (docs/service.md, "Security").
    api_keys: CommaList = Field(
        default_factory=list,
        repr=False,
        description=f"Comma-separated API keys (each >= {MIN_API_KEY_CHARS} characters). Empty: uploads, jobs "
        "and deletes are open. Set: they need header `X-API-Key`, and only the key that submitted a phantom or a "
        "job deletes it.",
    )
    cors_origins: CommaList = Field(
        default_factory=list,
        description="Comma-separated origins (`https://host:port`) whose web pages may call the API "
        "(CORS). Empty: none; writes carrying an `Origin` that is neither one of these nor the server's own "
        "(HOST, PORT) are refused (403): scheme, host and port all count, the request's Host header never does.",
    )

    @property
    def compute_memory_share_bytes(self) -> int:
        """Bytes one running computation may hold (the ceiling shared by ``max_concurrency``)."""
        return self.max_compute_memory_bytes // self.max_concurrency

    @field_validator("api_keys", "cors_origins", mode="before")
    @classmethod
    def _split(cls, value):
        if isinstance(value, str):
            return [part.strip() for part in value.split(",") if part.strip()]
        return value

    @field_validator("api_keys")
    @classmethod
    def _long_keys(cls, keys: list[str]) -> list[str]:
        for key in keys:
            if len(key) < MIN_API_KEY_CHARS or not key.isprintable() or " " in key:
                raise ValueError(f"each API key needs >= {MIN_API_KEY_CHARS} printable characters and no spaces")
        return keys

    @field_validator("cors_origins")
    @classmethod
    def _origins(cls, origins: list[str]) -> list[str]:
        for origin in origins:
            if not origin.startswith(("http://", "https://")) or origin.count("/") != 2:
                raise ValueError(f"a CORS origin is scheme://host[:port] without a path, got {origin!r}")
        return [o.lower() for o in origins]

    @model_validator(mode="after")
    def _resolve(self) -> "Settings":
        self.data_dir = Path(self.data_dir).expanduser()
        self.tracer_config()  # refuse an inconsistent tracer setting at start, not at the first request
        return self

    def tracer_config(self) -> TracerConfig:
        """The :class:`~raytrace.solver.config.TracerConfig` of every trace this service runs."""
        threads = {} if self.tracer_threads is None else {"threads": self.tracer_threads}
        return TracerConfig(launch_batch=self.tracer_launch_batch, max_live_rays=self.tracer_max_live_rays, **threads)


def settings_table_markdown() -> str:
    """The settings as a Markdown table (for the README)."""
    lines = ["| Variable | Default | Meaning |", "|---|---|---|"]
    for name, f in Settings.model_fields.items():
        default = f.default if f.default_factory is None else (", ".join(f.default_factory()) or "(none)")
        lines.append(f"| `CAPSULE_RT_{name.upper()}` | `{default}` | {f.description} |")
    return "\n".join(lines)
