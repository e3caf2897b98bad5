"""Coverage over the skin: per capsule position and sensor candidate, the received power, SNR,
first-arrival delay, whether a direct path exists, and the heterogeneity-aware delay model
(docs/design.md, "Coverage").

One trace per capsule position serves every candidate: the candidates are the receivers of that
position's :class:`raytrace.ChannelSpec` (cut into as few traces as the tracer's memory model
allows, :func:`receivers_per_trace`). A receiver's paths do not depend on the other receivers of
its trace (one launch serves all; each receiver's candidates, seeds and refinement are its own),
so a coverage row is exactly what ``POST /v1/channel`` answers for that capsule and that one
receiver with the same knobs (``tests/design/test_coverage.py``).

The spec (JSON, every field optional but ``phantom``'s default is ``torso``)::

    {"phantom": "torso",
     "positions": {"along_tract": {"ds_m": 0.02}},           # or {"sites": [...]}, {"positions_m": [...]}
     "candidates": {"spacing_m": 0.015, "depth_m": 0.001, "region": null, "include_sites": true},
     "frequency_hz": 402e6,
     "channel": {"rays": 30000, "max_interactions": 4, "dynamic_range_db": 40, "near_field": true,
                 "capsule_polarization": [0, 0, 1]},
     "link": {"transmit_power_dbm": -16.02, "noise_figure_db": 0, "temperature_k": 290, "bandwidth_hz": null},
     "waveform": {"duration_s": 25e-9, "sample_rate_hz": 20e9},
     "cell_size_m": 0.004}

SNR per link: the link budget (docs/science.md (S24)) with the path gain of the link and the noise
bandwidth of the TOA waveform's per-sample SNR (fs / 2) unless ``link.bandwidth_hz`` is given.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from design.candidates import Candidates, CandidateSpec, skin_candidates
from design.checks import boolean, integer, mapping, number, vector
from design.errors import DesignInputError
from design.model import link_model
from design.positions import Positions, check_positions_spec, resolve_positions
from estimators.constants import DEFAULT_RELATIVE_PERMITTIVITY, velocity_m_per_s
from estimators.errors import EstimatorInputError
from estimators.link import LinkBudget, make_link
from estimators.profile import PathProfile
from estimators.toa import estimate_toa
from estimators.waveforms import ToneBurst
from raytrace import Antenna, Budget, ChannelSpec, TracerConfig, trace_channel
from raytrace.body.phantom import Phantom
from raytrace.errors import CapsuleRTError
from raytrace.solver.footprint import estimate
from sweeps.store import atomic_write, parquet_bytes
from sweeps.task import PhantomSource, phantom_for

DEFAULTS_CHANNEL = {"rays": 30_000, "max_interactions": 4, "dynamic_range_db": 40.0, "near_field": True,
                    "capsule_polarization": [0.0, 0.0, 1.0]}
DEFAULT_CELL_SIZE_M = 0.004

SCHEMA = pa.schema([
    ("position_index", pa.int32()), ("capsule", pa.string()), ("capsule_organ", pa.string()), ("s_m", pa.float64()),
    ("capsule_x_m", pa.float64()), ("capsule_y_m", pa.float64()), ("capsule_z_m", pa.float64()),
    ("candidate_index", pa.int32()), ("site", pa.string()),
    ("candidate_x_m", pa.float64()), ("candidate_y_m", pa.float64()), ("candidate_z_m", pa.float64()),
    ("distance_m", pa.float64()), ("paths", pa.int32()), ("direct_path", pa.bool_()),
    ("path_gain_db", pa.float64()), ("rx_power_dbm", pa.float64()), ("snr_db", pa.float64()),
    ("first_delay_s", pa.float64()), ("first_group_delay_s", pa.float64()), ("ranging_delay_s", pa.float64()),
    ("eikonal_delay_s", pa.float64()),
    ("gradient_x_s_per_m", pa.float64()), ("gradient_y_s_per_m", pa.float64()), ("gradient_z_s_per_m", pa.float64()),
])


@dataclass(frozen=True)
class Limits:
    """Bounds of one coverage request, checked before any work (the service lowers them to its settings)."""

    max_links: int = 250_000  # capsule positions x candidates
    max_rays: int = 1_000_000
    max_interactions: int = 10
    max_ray_segments: int | None = None  # per trace (the channel endpoint's work rule)
    max_trace_bytes: int | None = None  # per trace (the channel endpoint's memory rule)


LIMITS = Limits()


def normalise_spec(data: Any, limits: Limits = LIMITS) -> dict:
    """The spec (module docstring) with every default filled in and every value checked that needs
    no phantom; :class:`DesignInputError` naming the field."""
    data = mapping(data if data is not None else {}, "",
                   {"phantom", "positions", "candidates", "frequency_hz", "channel", "link", "waveform", "cell_size_m"})
    phantom = data.get("phantom", "torso")
    if not isinstance(phantom, str) or not phantom:
        raise DesignInputError("must be a phantom id", "phantom")
    freq = number(data.get("frequency_hz", 402e6), "frequency_hz", lo=1e6, hi=20e9)
    ch = mapping(data.get("channel") or {}, "channel", set(DEFAULTS_CHANNEL))
    channel = {
        "rays": integer(ch.get("rays", min(DEFAULTS_CHANNEL["rays"], limits.max_rays)), "channel.rays", lo=1,
                        hi=limits.max_rays),  # a default over a server's cap is lowered to it, as POST /v1/channel
        "max_interactions": integer(ch.get("max_interactions",
                                           min(DEFAULTS_CHANNEL["max_interactions"], limits.max_interactions)),
                                    "channel.max_interactions", lo=1, hi=limits.max_interactions),
        "dynamic_range_db": number(ch.get("dynamic_range_db", DEFAULTS_CHANNEL["dynamic_range_db"]),
                                   "channel.dynamic_range_db", lo=0.0, hi=300.0, lo_open=True),
        "near_field": boolean(ch.get("near_field", True), "channel.near_field"),
        "capsule_polarization": vector(ch.get("capsule_polarization", [0.0, 0.0, 1.0]),
                                       "channel.capsule_polarization").tolist(),
    }
    if not any(channel["capsule_polarization"]):
        raise DesignInputError("must be a non-zero vector", "channel.capsule_polarization")
    try:
        link = make_link({k: v for k, v in (data.get("link") or {}).items()})
    except EstimatorInputError as exc:
        raise DesignInputError(exc.reason, exc.field if str(exc.field).startswith("link") else f"link.{exc.field}") \
            from None
    link = link or LinkBudget()
    wf = mapping(data.get("waveform") or {}, "waveform", {"duration_s", "sample_rate_hz"})
    waveform = {"duration_s": number(wf.get("duration_s", 25e-9), "waveform.duration_s", lo=0.0, lo_open=True),
                "sample_rate_hz": number(wf.get("sample_rate_hz", 20e9), "waveform.sample_rate_hz", lo=0.0,
                                         lo_open=True)}
    try:
        ToneBurst(carrier_hz=freq, **waveform)
    except EstimatorInputError as exc:
        raise DesignInputError(exc.reason, exc.field) from None
    return {
        "phantom": phantom,
        "positions": check_positions_spec(data.get("positions")),
        "candidates": CandidateSpec.from_dict(data.get("candidates")).to_dict(),
        "frequency_hz": freq,
        "channel": channel,
        "link": {"transmit_power_dbm": link.transmit_power_dbm, "noise_figure_db": link.noise_figure_db,
                 "temperature_k": link.temperature_k, "bandwidth_hz": link.bandwidth_hz},
        "waveform": waveform,
        "cell_size_m": number(data.get("cell_size_m", DEFAULT_CELL_SIZE_M), "cell_size_m", lo=0.001, hi=0.02),
    }


def waveform_of(spec: dict) -> ToneBurst:
    return ToneBurst(carrier_hz=spec["frequency_hz"], **spec["waveform"])


def noise_bandwidth_hz(spec: dict) -> float:
    return spec["link"]["bandwidth_hz"] or spec["waveform"]["sample_rate_hz"] / 2.0


def channel_spec(spec: dict, phantom_id: str, capsule_m, receivers_m) -> ChannelSpec:
    """The channel request of one capsule position to ``receivers_m`` (what a coverage row reproduces)."""
    ch = spec["channel"]
    return ChannelSpec(
        transmitter=Antenna(position_m=np.asarray(capsule_m, float), polarization=ch["capsule_polarization"]),
        receivers=tuple(Antenna(position_m=p, name=f"c{i}") for i, p in enumerate(np.asarray(receivers_m, float))),
        phantom=phantom_id, frequency_hz=spec["frequency_hz"], max_interactions=ch["max_interactions"],
        rays=ch["rays"], dynamic_range_db=ch["dynamic_range_db"], near_field=ch["near_field"])


def receivers_per_trace(spec: dict, candidates: int, limits: Limits, config: TracerConfig | None = None) -> int:
    """The most receivers one trace may hold under the per-trace work and memory rules of the
    channel endpoint (:func:`raytrace.solver.footprint.estimate`): every candidate when they fit, else
    the largest count that fits; :class:`DesignInputError` naming the field when none does."""
    def fp(k: int):
        return estimate(channel_spec(spec, spec["phantom"], [0.0, 0.0, 0.0], np.zeros((k, 3)) + 1.0), config)

    one = fp(1)
    if limits.max_ray_segments is not None and one.ray_segments > limits.max_ray_segments:
        raise DesignInputError(f"each trace's shooting is estimated at {one.ray_segments:.3g} ray segments, over the "
                               f"work budget of {limits.max_ray_segments:.3g} per trace: lower channel.rays, "
                               "channel.max_interactions or channel.dynamic_range_db", "channel.rays")
    if limits.max_trace_bytes is None or fp(candidates).peak_bytes <= limits.max_trace_bytes:
        return candidates
    if one.peak_bytes > limits.max_trace_bytes:
        raise DesignInputError(f"one trace is estimated to need {one.peak_bytes / 2**20:.0f} MiB even with one "
                               f"receiver, over the {limits.max_trace_bytes / 2**20:.0f} MiB a trace may hold: lower "
                               "channel.rays or channel.max_interactions", "channel.rays")
    lo, hi = 1, candidates
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if fp(mid).peak_bytes <= limits.max_trace_bytes:
            lo = mid
        else:
            hi = mid - 1
    return lo


@dataclass
class Plan:
    phantom_id: str
    positions: Positions
    candidates: Candidates
    receivers_per_trace: int

    @property
    def links(self) -> int:
        return len(self.positions) * len(self.candidates)

    def to_dict(self) -> dict:
        return {"phantom_id": self.phantom_id, "positions": self.positions.to_dict(),
                "candidates": self.candidates.to_dict(), "receivers_per_trace": self.receivers_per_trace}

    @classmethod
    def from_dict(cls, d: dict) -> "Plan":
        return cls(d["phantom_id"], Positions.from_dict(d["positions"]), Candidates.from_dict(d["candidates"]),
                   int(d["receivers_per_trace"]))


def make_plan(spec: dict, phantom: Phantom, limits: Limits = LIMITS, config: TracerConfig | None = None) -> Plan:
    """Resolve positions and candidates against ``phantom`` and bound the work before any of it:
    positions x candidates <= ``limits.max_links`` (422 naming the field that makes it large), each
    trace within the channel endpoint's work and memory rules."""
    positions = resolve_positions(phantom, spec["positions"])
    candidates = skin_candidates(phantom, CandidateSpec(
        spec["candidates"]["spacing_m"], spec["candidates"]["depth_m"],
        None if spec["candidates"]["region"] is None else tuple(spec["candidates"]["region"]["min_m"]),
        None if spec["candidates"]["region"] is None else tuple(spec["candidates"]["region"]["max_m"]),
        spec["candidates"]["include_sites"]))
    links = len(positions) * len(candidates)
    if links > limits.max_links:
        where = "positions" if len(positions) > len(candidates) else "candidates.spacing_m"
        raise DesignInputError(f"{len(positions)} capsule positions x {len(candidates)} candidates = {links} links, "
                               f"over this server's limit of {limits.max_links}: fewer positions (a larger ds_m) or a "
                               "larger candidate spacing", where)
    per_trace = receivers_per_trace(spec, len(candidates), limits, config)
    return Plan(spec["phantom"], positions, candidates, per_trace)


def ranging_delay_s(paths, frequency_hz: float, waveform: ToneBurst, velocity_m_per_s_: float) -> float:
    """The delay TOA (GCC) measures on a link without noise: the estimate of
    :func:`estimators.toa.estimate_toa` on the link's traced paths, back to seconds. A phase delay
    (docs/localization.md, "Delay kinds") that carries the ranging's multipath bias, which the
    first traced arrival does not (docs/design.md, "Coverage")."""
    est = estimate_toa(PathProfile.from_traced(paths, frequency_hz), method="gcc", waveform=waveform, snr_db=None,
                       trials=1, seed=0, return_estimates=True)[0]
    if est.estimates_m is None:  # asked for: return_estimates
        raise AssertionError("estimate_toa returned no estimates")
    return float(est.estimates_m[0]) / velocity_m_per_s_


# ------------------------------------------------------------------------------ one position
@dataclass(frozen=True)
class PositionTask:
    index: int
    spec: dict
    plan: dict  # Plan.to_dict()
    source: PhantomSource
    budget: dict = field(default_factory=dict)
    config: TracerConfig | None = None


def position_columns(task: PositionTask, phantom: Phantom | None = None) -> dict[str, list]:
    """Every row of one capsule position (module docstring); runs in a worker process."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _position_columns(task, phantom)


def _position_columns(task: PositionTask, phantom: Phantom | None) -> dict[str, list]:
    spec, plan = task.spec, Plan.from_dict(task.plan)
    phantom = phantom if phantom is not None else phantom_for(task.source)
    p = task.index
    x = plan.positions.positions_m[p]
    cands = plan.candidates.positions_m
    C = len(cands)
    link = LinkBudget(**spec["link"])
    noise_dbm = link.noise_power_dbm(noise_bandwidth_hz(spec))
    paths = np.zeros(C, np.int64)
    direct = np.zeros(C, bool)
    gain = np.full(C, np.nan)
    first = np.full(C, np.nan)
    group = np.full(C, np.nan)
    ranging = np.full(C, np.nan)
    waveform = waveform_of(spec)
    v = velocity_m_per_s(DEFAULT_RELATIVE_PERMITTIVITY)
    k = plan.receivers_per_trace
    for lo in range(0, C, k):
        chunk = cands[lo:lo + k]
        budget = dict(task.budget)
        if budget.get("deadline_s") is not None:  # a channel request's deadline per 64 receivers
            budget["deadline_s"] = budget["deadline_s"] * max(1.0, len(chunk) / 64.0)
        result = trace_channel(channel_spec(spec, plan.phantom_id, x, chunk), phantom, budget=Budget(**budget),
                               config=task.config)
        for j, prof in enumerate(result.profiles):
            c = lo + j
            paths[c] = len(prof.paths)
            if prof.paths:
                direct[c] = any(all(i.kind == "refraction" for i in q.interactions) for q in prof.paths)
                gain[c] = prof.path_gain_db
                first[c] = prof.paths[0].delay_s
                group[c] = prof.paths[0].group_delay_s
                ranging[c] = ranging_delay_s(prof.paths, spec["frequency_hz"], waveform, v)
    model = link_model(phantom, x[None, :], cands, spec["frequency_hz"], spec["cell_size_m"])
    rx = link.transmit_power_dbm + gain
    snr = rx - noise_dbm
    grad = model["gradient_s_per_m"][0]

    def opt(a):
        return [None if not np.isfinite(v) else float(v) for v in a]

    s_m = plan.positions.s_m[p]
    return {
        "position_index": [p] * C, "capsule": [plan.positions.labels[p]] * C,
        "capsule_organ": [plan.positions.organ[p]] * C, "s_m": [s_m] * C,
        "capsule_x_m": [float(x[0])] * C, "capsule_y_m": [float(x[1])] * C, "capsule_z_m": [float(x[2])] * C,
        "candidate_index": list(range(C)), "site": [s or None for s in plan.candidates.site],
        "candidate_x_m": cands[:, 0].tolist(), "candidate_y_m": cands[:, 1].tolist(),
        "candidate_z_m": cands[:, 2].tolist(), "distance_m": np.linalg.norm(cands - x, axis=1).tolist(),
        "paths": paths.tolist(), "direct_path": direct.tolist(), "path_gain_db": opt(gain),
        "rx_power_dbm": opt(rx), "snr_db": opt(snr), "first_delay_s": opt(first), "first_group_delay_s": opt(group),
        "ranging_delay_s": opt(ranging), "eikonal_delay_s": model["eikonal_delay_s"][0].tolist(),
        "gradient_x_s_per_m": grad[:, 0].tolist(), "gradient_y_s_per_m": grad[:, 1].tolist(),
        "gradient_z_s_per_m": grad[:, 2].tolist(),
    }


# ------------------------------------------------------------------------------ the directory
RECORD = "coverage.json"
STATE = "state.json"
PARTS = "parts"
TABLE = "coverage.parquet"


class CoverageDir:
    """A coverage's directory: ``coverage.json`` (spec, plan, phantom source), ``state.json``,
    ``parts/position-NNNNNN.parquet`` (one per finished position, written atomically: what a resumed
    run skips) and ``coverage.parquet`` (every part in order, when it is done)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def exists(self) -> bool:
        return (self.root / RECORD).is_file()

    def record(self) -> dict:
        return json.loads((self.root / RECORD).read_text())

    def create(self, record: dict) -> None:
        (self.root / PARTS).mkdir(parents=True, exist_ok=True)
        atomic_write(self.root / RECORD, json.dumps(record, sort_keys=True, allow_nan=False).encode())

    def read_state(self) -> dict:
        try:
            return json.loads((self.root / STATE).read_text())
        except FileNotFoundError:
            return {}

    def write_state(self, state: dict) -> None:
        state = {**state, "updated_at": time.time()}
        atomic_write(self.root / STATE, json.dumps(state, sort_keys=True, allow_nan=False).encode())

    def part(self, p: int) -> Path:
        return self.root / PARTS / f"position-{p:06d}.parquet"

    def done(self) -> set[int]:
        d = self.root / PARTS
        if not d.is_dir():
            return set()
        return {int(f.stem.split("-")[1]) for f in d.glob("position-*.parquet")}

    def write_part(self, p: int, columns: dict[str, list]) -> None:
        atomic_write(self.part(p), parquet_bytes(pa.table(columns, schema=SCHEMA)))

    def table(self) -> pa.Table:
        """The final table if written, else the parts stored so far (in position order)."""
        if (self.root / TABLE).is_file():
            return pq.read_table(self.root / TABLE)
        parts = [pq.read_table(self.part(p)) for p in sorted(self.done())]
        return pa.concat_tables(parts) if parts else SCHEMA.empty_table()

    def finalize(self) -> None:
        parts = [pq.read_table(self.part(p)) for p in sorted(self.done())]
        atomic_write(self.root / TABLE, parquet_bytes(pa.concat_tables(parts) if parts else SCHEMA.empty_table()))


def prepare(spec: dict, root: str | Path, phantom: Phantom, source: PhantomSource, limits: Limits = LIMITS,
            config: TracerConfig | None = None) -> Plan:
    """Plan ``spec`` (every check before any work) and write its directory (``queued``)."""
    plan = make_plan(spec, phantom, limits, config)
    store = CoverageDir(root)
    if store.exists():
        raise DesignInputError(f"{root} already holds a coverage", "out")
    store.create({"spec": spec, "plan": plan.to_dict(), "source": source.__dict__, "created_at": time.time(),
                  "links": plan.links})
    store.write_state({"state": "queued", "done": 0, "total": len(plan.positions), "elapsed_s": 0.0})
    return plan


def execute(root: str | Path, *, engine=None, cancel=None, budget: dict | None = None,
            config: TracerConfig | None = None, on_progress: Callable[[dict], None] | None = None) -> dict:
    """Run (or resume) the coverage in ``root``: every position without a part, on ``engine``
    (:mod:`sweeps.engines`; default: this process). Returns the final state."""
    from sweeps.engines import SerialEngine

    store = CoverageDir(root)
    record = store.record()
    spec, plan = record["spec"], Plan.from_dict(record["plan"])
    source = PhantomSource(**record["source"])
    total = len(plan.positions)
    todo = [p for p in range(total) if p not in store.done()]
    previous = store.read_state()
    elapsed_before = float(previous.get("elapsed_s") or 0.0)
    started = time.monotonic()
    state = {"state": "running", "done": total - len(todo), "total": total, "elapsed_s": elapsed_before,
             "eta_s": None, "failures": [], "started_at": previous.get("started_at") or time.time(),
             "finished_at": None, "error": None}
    store.write_state(state)
    engine = engine or SerialEngine()
    tasks = [PositionTask(p, spec, record["plan"], source, budget or {}, config) for p in todo]
    finished_here = 0
    for i, out in engine.run(position_columns, tasks, cancel):
        p = tasks[i].index
        if isinstance(out, BaseException):
            reason = out.reason if isinstance(out, CapsuleRTError) else f"{type(out).__name__}: {out}"
            state["failures"].append({"position_index": p, "capsule": plan.positions.labels[p], "reason": reason})
        else:
            store.write_part(p, out)
            state["done"] += 1
            finished_here += 1
        run_s = time.monotonic() - started
        state["elapsed_s"] = elapsed_before + run_s
        left = total - state["done"] - len(state["failures"])
        state["eta_s"] = run_s / finished_here * left if finished_here else None
        store.write_state(state)
        if on_progress is not None:
            on_progress(state)
    if cancel is not None and cancel.is_set():
        state["state"] = "cancelled"
    elif state["failures"]:
        state.update(state="failed", error=f"{len(state['failures'])} of {total} positions failed; the first: "
                     f"{state['failures'][0]['reason']}")
    else:
        store.finalize()
        state.update(state="done", eta_s=0.0)
    state["finished_at"] = time.time()
    store.write_state(state)
    return state


def run_coverage(data: Any, out: str | Path, *, phantom: Phantom | None = None, source: PhantomSource | None = None,
                 workers: int | None = 0, limits: Limits = LIMITS, resume: bool = False,
                 on_progress: Callable[[dict], None] | None = None) -> dict:
    """The whole coverage from Python or the CLI: normalise, plan, run (``workers`` processes; 0: this
    one), resumable with ``resume``. Returns the final state."""
    from sweeps.engines import make_engine

    store = CoverageDir(out)
    if not (resume and store.exists()):
        spec = normalise_spec(data, limits)
        if phantom is None:
            from raytrace.body.library import get_phantom

            phantom = get_phantom(spec["phantom"])
        prepare(spec, out, phantom, source or PhantomSource(spec["phantom"]), limits)
    engine = make_engine(workers)
    try:
        return execute(out, engine=engine, on_progress=on_progress)
    finally:
        engine.close()


def load(root: str | Path) -> tuple[dict, Plan, pa.Table]:
    """(record, plan, table) of a finished coverage directory."""
    store = CoverageDir(root)
    if not store.exists():
        raise DesignInputError(f"no coverage at {root}", "coverage")
    record = store.record()
    if not (store.root / TABLE).is_file():
        state = store.read_state().get("state", "queued")
        raise DesignInputError(f"the coverage is {state}, not done: its table is written when every position is",
                               "coverage")
    return record, Plan.from_dict(record["plan"]), pq.read_table(store.root / TABLE)


def link_arrays(table: pa.Table, positions: int, candidates: int) -> dict[str, np.ndarray]:
    """The table's link columns as (P, C) arrays (rows are position-major, candidate-minor)."""
    def col(name, fill=np.nan):
        a = table.column(name).to_numpy(zero_copy_only=False)
        a = np.array([fill if v is None else v for v in a], float) if a.dtype == object else a.astype(float)
        return a.reshape(positions, candidates)

    grad = np.stack([col(f"gradient_{k}_s_per_m") for k in "xyz"], axis=2)
    return {"paths": col("paths", 0.0), "direct_path": col("direct_path", 0.0).astype(bool),
            "snr_db": col("snr_db"), "rx_power_dbm": col("rx_power_dbm"), "path_gain_db": col("path_gain_db"),
            "first_delay_s": col("first_delay_s"),
            # coverages before the column: the first arrival (no ranging bias)
            "ranging_delay_s": col("ranging_delay_s") if "ranging_delay_s" in table.column_names
            else col("first_delay_s"),
            "eikonal_delay_s": col("eikonal_delay_s"), "gradient_s_per_m": grad}


