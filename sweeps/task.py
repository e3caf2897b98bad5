"""One task of a sweep, run in a worker: a chunk of capsule positions, every frequency and receiver.

:func:`run_task` is what the engines ship to worker processes (a local pool or a Dask
cluster). Its input (:class:`TaskInput`) is plain data: the normalised spec, the plan's
rows for the chunk, where the phantom comes from and the per-trace budget. The worker
builds the phantom once per process (:func:`phantom_for`, cached; the tracer caches its
scene per phantom), then for each position and frequency traces one
:class:`~raytrace.ChannelSpec` to every receiver and ranges every link.

Determinism: BLAS runs on one thread in a task (:func:`run_task`), and the noise of every
Monte Carlo estimate is drawn from
``SeedSequence(spec.seed, spawn_key=(position, frequency, receiver, family))`` with the
sweep's global indices (family 0 TOA, 1 PDOA, 2 RSS; the TOA methods share their noise,
as ``estimate_toa(method="all")`` does), so a row's numbers do not depend on which task or
worker computed it.

A trace that fails (e.g. its budget ran out) is reported in the task's ``failures`` with
its reason; the task's other rows stand. An estimator that cannot range a link (no path,
paths that cancel) leaves that method's columns null and says why in ``note``.
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimators import PathProfile, estimate_pdoa, estimate_rss, estimate_toa
from estimators.errors import EstimatorInputError
from raytrace.body.library import get_phantom
from raytrace.body.phantom import Phantom
from raytrace.errors import CapsuleRTError
from raytrace.solver.budget import Budget
from raytrace.solver.config import TracerConfig
from raytrace.solver.tracer import trace_channel
from raytrace.spec import Antenna
from sweeps import localization as loc
from sweeps.heap import task_heap
from sweeps.spec import SweepSpec, rss_model
from sweeps.table import HAS_GROUP_DELAY

__all__ = ["PhantomFiles", "PhantomSource", "TaskInput", "TaskOutput", "phantom_for", "run_task"]

_FAMILY = {"toa": 0, "pdoa": 1, "rss": 2}


@dataclass(frozen=True)
class PhantomSource:
    """Where a worker gets the phantom: a built-in id, or an uploaded phantom's stored files
    (``glb_path`` + ``manifest_path``). A local pool's workers read the files; a cluster's
    workers need not see them: the engine ships their bytes (:class:`PhantomFiles`) once per
    worker and each worker keeps the phantom built from them (:func:`phantom_for`)."""

    id: str
    glb_path: str | None = None
    manifest_path: str | None = None


@dataclass(frozen=True)
class PhantomFiles:
    """An uploaded phantom's stored files as bytes, and their sha256 (the workers' cache key):
    what a Dask engine broadcasts to workers that do not share this machine's filesystem."""

    sha256: str
    glb: bytes
    manifest: bytes

    @classmethod
    def read(cls, source: PhantomSource) -> "PhantomFiles":
        with open(source.glb_path, "rb") as fh:
            glb = fh.read()
        with open(source.manifest_path, "rb") as fh:
            manifest = fh.read()
        digest = hashlib.sha256(len(glb).to_bytes(8, "little") + glb + manifest).hexdigest()
        return cls(digest, glb, manifest)


@dataclass(frozen=True)
class TaskInput:
    task: int
    spec: dict
    plan: dict  # Plan.to_dict() restricted to this task's positions, plus "position_indices"
    phantom: PhantomSource
    budget: dict = field(default_factory=dict)  # Budget(**budget) per trace: deadline_s, max_ray_segments
    #: Tracer threads per trace (TracerConfig.threads); None: every CPU of the worker. A pool or a
    #: cluster runs one task per worker process, so 1: the workers are the parallelism (the same
    #: paths on any number of threads: docs/tracer.md, "Determinism").
    tracer_threads: int | None = None


@dataclass
class TaskOutput:
    task: int
    rows: dict[str, list]
    localization: dict[str, list]
    failures: list[dict]
    elapsed_s: float
    worker: str
    cpu_s: float = 0.0  # CPU time of the worker process while the task ran (every thread)


_PHANTOMS: dict[tuple, Phantom] = {}
_LOCK = threading.Lock()


def phantom_for(source: PhantomSource, files: PhantomFiles | None = None) -> Phantom:
    """The phantom of ``source``, built once per process (and per stored file version): from
    the shipped ``files`` when given (keyed by their sha256: a worker of a cluster), else from
    the stored files (keyed by path and modification time: a local worker)."""
    if source.glb_path is None:
        return get_phantom(source.id)
    key = (source.id, files.sha256) if files is not None else (
        source.id, source.glb_path, os.stat(source.glb_path).st_mtime_ns)
    with _LOCK:
        hit = _PHANTOMS.get(key)
    if hit is not None:
        return hit
    import json

    from raytrace.body.gltf import load_phantom

    if files is None:
        files = PhantomFiles.read(source)
    glb, manifest = files.glb, json.loads(files.manifest)
    phantom = load_phantom(glb, manifest, max_bytes=len(glb) + 1, max_triangles=10**8, check_crossings=False)
    with _LOCK:
        if len(_PHANTOMS) >= 4:
            _PHANTOMS.pop(next(iter(_PHANTOMS)))
        _PHANTOMS[key] = phantom
    return phantom


def _rng(seed: int, position: int, frequency: int, receiver: int, family: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(position, frequency, receiver,
                                                                          _FAMILY[family])))


def _profile(paths, frequency_hz: float, band_hz) -> PathProfile:
    """The estimators' profile of traced paths (gains carry exp(-j 2 pi f tau): ``docs/api.md``)."""
    return PathProfile.from_traced(paths, frequency_hz, band_hz)


def _result_columns(row: dict, name: str, result) -> None:
    row[f"{name}_distance_m"] = result.distance_m
    row[f"{name}_error_m"] = result.error_m
    row[f"{name}_std_m"] = result.std_m
    row[f"{name}_rmse_m"] = result.rmse_m
    row[f"{name}_crlb_m"] = result.crlb_m
    if name.startswith("pdoa_"):
        row[f"{name}_wrapped"] = bool(result.wrapped)


def range_link(row: dict, paths, frequency_hz: float, band_hz, truth_m: float, spec: SweepSpec,
               keys: tuple[int, int, int]) -> list[str]:
    """Every ranging method of ``spec`` on one link; fills ``row``, returns notes on what failed."""
    ranging, trials, seed = spec["ranging"], spec["trials"], spec["seed"]
    methods = spec.methods
    if not methods:
        return []
    if not paths:
        return ["no path: nothing to range on"]
    notes: list[str] = []
    profile = _profile(paths, frequency_hz, band_hz)
    eps = ranging["relative_permittivity"]
    if "toa" in ranging:
        toa = ranging["toa"]
        waveform = {**toa["waveform"], "carrier_hz": frequency_hz}
        for m in toa["methods"]:
            try:
                (res,) = estimate_toa(profile, method=m, waveform=waveform, snr_db=toa["snr_db"], trials=trials,
                                      seed=_rng(seed, *keys, "toa"), relative_permittivity=eps,
                                      true_distance_m=truth_m)
                _result_columns(row, f"toa_{m}", res)
            except EstimatorInputError as exc:
                notes.append(f"toa_{m}: {exc.reason}")
    if "pdoa" in ranging:
        pdoa = ranging["pdoa"]
        tones = np.linspace(frequency_hz - pdoa["span_hz"] / 2, frequency_hz + pdoa["span_hz"] / 2, pdoa["points"])
        for m in pdoa["methods"]:
            try:
                res = estimate_pdoa(profile, frequencies_hz=tones if m == "regression" else tones[[0, -1]],
                                    method=m, snr_db=pdoa["snr_db"], trials=trials, seed=_rng(seed, *keys, "pdoa"),
                                    relative_permittivity=eps, true_distance_m=truth_m,
                                    duration_s=pdoa["duration_s"])
                _result_columns(row, f"pdoa_{m}", res)
            except EstimatorInputError as exc:
                notes.append(f"pdoa_{m}: {exc.reason}")
    if "rss" in ranging:
        rss = ranging["rss"]
        try:
            res = estimate_rss(profile, model=rss_model(rss["model"]), trials=trials, seed=_rng(seed, *keys, "rss"),
                               true_distance_m=truth_m, shadowing=rss["shadowing"])
            _result_columns(row, "rss", res)
        except EstimatorInputError as exc:
            notes.append(f"rss: {exc.reason}")
    return notes


def _append(columns: dict[str, list], row: dict, n_before: int) -> None:
    for key in row.keys() - columns.keys():
        columns[key] = [None] * n_before
    for key, values in columns.items():
        values.append(row.get(key))


def run_task(job: TaskInput, phantom_files: PhantomFiles | None = None) -> TaskOutput:
    """Run one task (module docstring), with one BLAS thread: a multi-threaded BLAS sums in an order
    that depends on its thread count (Dask's workers default to 1, a plain process to the CPUs),
    which moved the last bits of a GCC estimate; parallelism comes from the workers anyway. The C
    heap is glibc's default while it runs (:func:`sweeps.heap.task_heap`: a Dask worker's trim
    setting made every large temporary a fresh mmap, ~25 % of a task's time)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"), task_heap():
        return _run_task(job, phantom_files)


def _run_task(job: TaskInput, phantom_files: PhantomFiles | None) -> TaskOutput:
    started, cpu = time.monotonic(), time.process_time()
    spec = SweepSpec(job.spec)
    plan = job.plan
    phantom = phantom_for(job.phantom, phantom_files)
    config = TracerConfig() if job.tracer_threads is None else TracerConfig(threads=int(job.tracer_threads))
    receivers = tuple(Antenna.from_dict(r) for r in plan["receivers"])
    rx_m = np.asarray(plan["receivers_m"], float)
    pattern = spec["channel"]["capsule_pattern"]
    rows: dict[str, list] = {}
    loc_rows: dict[str, list] = {}
    n_rows = n_loc = 0
    failures: list[dict] = []
    line = phantom.centrelines.get(plan["centreline"]) if plan.get("centreline") else None
    for k, pi in enumerate(plan["position_indices"]):
        pos = np.asarray(plan["positions_m"][k], float)
        s_m = plan["s_m"][k]
        tx = Antenna(position_m=pos, polarization=plan["polarizations"][k], pattern=pattern)
        for fi, f in enumerate(plan["frequencies_hz"]):
            channel = spec.channel_spec(tx, receivers, f, plan["phantom_id"])
            try:
                result = trace_channel(channel, phantom, budget=Budget(**job.budget), config=config)
            except CapsuleRTError as exc:
                failures.append({"task": job.task, "position_index": pi, "capsule": plan["labels"][k],
                                 "frequency_hz": f, "reason": exc.reason, "type": type(exc).__name__})
                continue
            per_link = []
            for ri, prof in enumerate(result.profiles):
                paths = prof.paths
                truth = float(np.linalg.norm(rx_m[ri] - pos))
                row = {
                    "position_index": pi, "capsule": plan["labels"][k], "capsule_x_m": float(pos[0]),
                    "capsule_y_m": float(pos[1]), "capsule_z_m": float(pos[2]), "s_m": s_m,
                    "capsule_medium": plan["media"][k], "frequency_hz": f, "receiver_index": ri,
                    "receiver": prof.receiver, "receiver_medium": prof.medium, "distance_m": truth,
                    "paths": len(paths),
                    "first_delay_s": paths[0].delay_s if paths else None,
                    "first_path_length_m": paths[0].length_m if paths else None,
                    "direct_path": any(all(i.kind == "refraction" for i in p.interactions) for p in paths),
                    "path_gain_db": prof.path_gain_db if paths else None,
                    "rms_delay_spread_s": prof.rms_delay_spread_s if paths else None,
                }
                if HAS_GROUP_DELAY:
                    row["first_group_delay_s"] = getattr(paths[0], "group_delay_s", None) if paths else None
                notes = range_link(row, paths, f, result.band_frequencies_hz, truth, spec, (pi, fi, ri))
                row["note"] = "; ".join(notes) or None
                _append(rows, row, n_rows)
                n_rows += 1
                per_link.append(row)
            if spec["localization"]:
                traced = phantom if channel.homogeneous is None else _homogeneous(phantom, channel.homogeneous)
                for lrow in localize(spec, per_link, rx_m, pos, s_m, f, line, traced):
                    _append(loc_rows, {"position_index": pi, "capsule": plan["labels"][k], **lrow}, n_loc)
                    n_loc += 1
    return TaskOutput(job.task, rows, loc_rows, failures, time.monotonic() - started, f"pid {os.getpid()}",
                      time.process_time() - cpu)


def _homogeneous(phantom: Phantom, material) -> Phantom:
    """The phantom as the tracer saw it under a ``homogeneous`` override: every organ of ``material``
    (the model-based localizer builds its travel-time fields through it)."""
    import dataclasses

    key = (id(phantom), material)
    hit = _HOMOGENEOUS.get("last")
    if hit is None or hit[0] != key or hit[1] is not phantom:
        organs = tuple(dataclasses.replace(o, material=material) for o in phantom.organs)
        hit = (key, phantom, dataclasses.replace(phantom, organs=organs))
        _HOMOGENEOUS["last"] = hit
    return hit[2]


_HOMOGENEOUS: dict = {}


def localize(spec: SweepSpec, links: list[dict], receivers_m: np.ndarray, truth_m: np.ndarray, s_m,
             frequency_hz: float, line, phantom: Phantom | None = None) -> list[dict]:
    """One row per localization method of ``spec`` for one (position, frequency) (:mod:`sweeps.localization`)."""
    out = []
    for entry in spec["localization"]["methods"]:
        name = entry["name"]
        options = {k: v for k, v in entry.items() if k != "name"}
        source = options.get("ranges_from")
        ranges = np.array([np.nan if source is None or r.get(f"{source}_distance_m") is None
                           else r[f"{source}_distance_m"] for r in links], float)
        sigma = np.array([np.nan if source is None or r.get(f"{source}_std_m") is None
                          else r[f"{source}_std_m"] for r in links], float)
        pl = np.array([np.nan if r["path_gain_db"] is None else -r["path_gain_db"] for r in links], float)
        inputs = loc.LocalizationInputs(frequency_hz, receivers_m, ranges, sigma, pl,
                                        spec["ranging"]["relative_permittivity"], line, phantom=phantom)
        row: dict[str, Any] = {"frequency_hz": frequency_hz, "method": name, "true_x_m": float(truth_m[0]),
                               "true_y_m": float(truth_m[1]), "true_z_m": float(truth_m[2]), "s_m": s_m,
                               "receivers_used": int(np.isfinite(ranges).sum() if source else np.isfinite(pl).sum())}
        try:
            estimate = loc.get(name).fn(inputs, options)
        except (EstimatorInputError, CapsuleRTError, ValueError) as exc:
            row["note"] = f"{name}: {getattr(exc, 'reason', str(exc))}"
            estimate = None
        if estimate is not None:
            est = np.asarray(estimate, float).reshape(3)
            row.update(estimate_x_m=float(est[0]), estimate_y_m=float(est[1]), estimate_z_m=float(est[2]),
                       error_m=float(np.linalg.norm(est - truth_m)))
            if line is not None and s_m is not None:
                est_s = float(line.project(est))
                row.update(estimate_s_m=est_s, along_tract_error_m=est_s - s_m)
        elif "note" not in row:
            row["note"] = f"{name}: no estimate"
        out.append(row)
    return out
