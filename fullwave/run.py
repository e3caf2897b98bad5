"""Export, run gprMax (when installed) at two cell sizes, trace, and write the comparison report.

The FDTD's own discretisation error is estimated from a second run with cells ``coarse_factor``
times larger: each run is compared with the tracer at its own snapped antenna positions, and
the change of (FDTD - tracer) between the two runs is reported per receiver (the positions
themselves move with the grid, so raw FDTD values of the two runs are not comparable).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

import numpy as np

from raytrace.body.phantom import Phantom
from raytrace.errors import BudgetExceededError
from raytrace.solver.budget import Budget
from raytrace.solver.tracer import trace_channel
from raytrace.spec import ChannelSpec

from .compare import Metrics, fdtd_gains, media_indices, tracer_gains, tracer_spec
from .model import FdtdModel, FdtdOptions, build_model


def gprmax_available() -> bool:
    try:
        import gprMax  # noqa: F401
        import h5py  # noqa: F401
    except ImportError:
        return False
    return True


def input_stem(cell_m: float) -> str:
    """The file stem of the model at ``cell_m`` in a comparison's directory (``model_20``: 2.0 mm)."""
    return f"model_{round(cell_m * 1e4)}"


def export(model: FdtdModel, directory: Path, stem: str) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{stem}.in"
    path.write_text(model.input_text)
    return path


def previous_output(model: FdtdModel, directory: Path, stem: str) -> tuple[Path, float] | None:
    """The HDF5 output and wall time of an earlier run of exactly this input in ``directory``
    (same input text, finished), or None: lets a report be rebuilt after a change to the
    comparison without re-running gprMax."""
    path, out, wall = (directory / f"{stem}{ext}" for ext in (".in", ".h5", ".wall_s"))
    if path.exists() and out.exists() and wall.exists() and path.read_text() == model.input_text:
        return out, float(wall.read_text())
    return None


#: How often a running gprMax is checked for cancellation, its deadline and its progress [s].
POLL_S = 0.2
#: gprMax's progress bar (tqdm on its stdout): ``|--->:  45%|####  | 1157/2571 [00:10<00:12, ...]``.
_PROGRESS = re.compile(rb"(\d+)/(\d+) \[")


def _progress(log_path: Path) -> tuple[int, int] | None:
    """The last (iteration, iterations) gprMax's progress bar wrote to ``log_path`` (its tail only)."""
    try:
        with open(log_path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - 512))
            tail = fh.read()
    except OSError:
        return None
    found = _PROGRESS.findall(tail)
    return (int(found[-1][0]), int(found[-1][1])) if found else None


def _stop(proc: subprocess.Popen) -> None:
    """Kill gprMax and everything it started (its own process group), and reap it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


def run_gprmax(input_path: Path, threads: int = 2, *, cancel: threading.Event | None = None,
               deadline: float | None = None, on_progress: Callable[[int, int], None] | None = None,
               on_start: Callable[[int], None] | None = None) -> tuple[Path, float]:
    """Run gprMax on ``input_path`` in a child process (OpenMP ``threads``); its HDF5 output and
    the wall time [s]. Raises ``RuntimeError`` with gprMax's last log lines on failure.

    The child runs in its own process group with its output in ``<stem>.log``. Every
    :data:`POLL_S`: when ``cancel`` is set, or ``time.monotonic()`` passes ``deadline``, the group
    is killed (and reaped) and :class:`~raytrace.errors.BudgetExceededError` raised (kind
    ``cancelled`` / ``deadline``); ``on_progress(iteration, iterations)`` gets the time steps done,
    read from the tail of gprMax's progress bar in the log; ``on_start(pid)`` is told the child's pid
    (its process group's id too), e.g. to be recorded so that a process that outlived a crash of its
    parent can be found and stopped."""
    # OMP_WAIT_POLICY: gprMax's OpenMP threads spin at every barrier by default, so on a machine whose
    # cores are busy with other work a descheduled thread stalls the others: a 1.8e8 cell-update model
    # took 492 s with spinning threads and 13 s with passive ones on 2 cores shared with one busy process
    env = dict(os.environ, OMP_NUM_THREADS=str(int(threads)), TQDM_MININTERVAL="1")
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    log_path = input_path.parent / f"{input_path.stem}.log"
    out = input_path.with_suffix(".h5")
    input_path.with_suffix(".wall_s").unlink(missing_ok=True)  # a finished run is marked only once it is
    t0 = time.monotonic()
    if deadline is not None and t0 > deadline:
        raise BudgetExceededError(f"no time left to run gprMax on {input_path.name}", kind="deadline")
    with open(log_path, "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "gprMax", str(input_path.name), "--show-progress-bars"],
                                cwd=input_path.parent, env=env, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            if on_start is not None:
                on_start(proc.pid)
            seen = None
            while True:
                try:
                    proc.wait(POLL_S)
                    break
                except subprocess.TimeoutExpired:
                    pass
                if cancel is not None and cancel.is_set():
                    _stop(proc)
                    raise BudgetExceededError(f"gprMax on {input_path.name} was cancelled", kind="cancelled")
                if deadline is not None and time.monotonic() > deadline:
                    _stop(proc)
                    raise BudgetExceededError(f"gprMax on {input_path.name} was stopped at its deadline after "
                                              f"{time.monotonic() - t0:.0f} s", kind="deadline")
                if on_progress is not None:
                    now = _progress(log_path)
                    if now is not None and now != seen:
                        seen = now
                        on_progress(*now)
        except BaseException:
            if proc.poll() is None:
                _stop(proc)
            raise
    wall = time.monotonic() - t0
    if proc.returncode != 0 or not out.exists():
        text = log_path.read_text(errors="replace")
        tail = "\n".join(line for line in re.split(r"[\r\n]+", text) if line.strip())
        tail = "\n".join(tail.splitlines()[-15:])
        raise RuntimeError(f"gprMax failed on {input_path} (exit {proc.returncode}):\n{tail}")
    input_path.with_suffix(".wall_s").write_text(f"{wall:.3f}\n")
    return out, wall


@contextmanager
def _trace_budget(cancel: threading.Event | None, deadline: float | None):
    """A tracer :class:`Budget` that stops at ``deadline`` (monotonic) and when ``cancel`` is set."""
    budget = Budget(deadline_s=None if deadline is None else max(0.0, deadline - time.monotonic()))
    if cancel is None:
        yield budget
        return
    done = threading.Event()

    def link() -> None:
        while not done.wait(POLL_S):
            if cancel.is_set():
                budget.cancel()
                return

    watcher = threading.Thread(target=link, name="fullwave-trace-cancel", daemon=True)
    watcher.start()
    try:
        yield budget
    finally:
        done.set()
        watcher.join()


def _row(name: str, fd: Metrics, tr: Metrics, validity: tuple[str, ...], medium: str, cells: tuple[str, ...]) -> dict:
    return {
        "receiver": name,
        "validity": list(validity),
        "tracer_medium": medium,
        "fdtd_cell_media": list(cells),
        "fdtd": dataclasses.asdict(fd),
        "tracer": dataclasses.asdict(tr),
        "gain_error_db": tr.gain_db - fd.gain_db,
        "phase_error_deg": float((tr.phase_deg - fd.phase_deg + 180.0) % 360.0 - 180.0),
        "group_delay_error_s": tr.group_delay_s - fd.group_delay_s,
        "envelope_error_s": tr.envelope_s - fd.envelope_s,
    }


def compare(spec: ChannelSpec, phantom: Phantom, options: FdtdOptions, directory: Path, *,
            coarse_factor: float | None = 1.5, run: bool = True, threads: int = 2, reuse: bool = False,
            grid_phantom: Callable[[float], Phantom] | None = None, cancel: threading.Event | None = None,
            deadline: float | None = None, on_progress: Callable[[dict], None] | None = None,
            on_start: Callable[[int], None] | None = None) -> dict:
    """The report (a JSON-able dict): per cell size the model's facts, gprMax's wall time and
    per receiver the FDTD and tracer metrics and their differences; then per receiver the
    discretisation estimate. With ``run`` false (or gprMax missing) only the inputs are written;
    with ``reuse``, a cell size whose identical input already ran in ``directory`` is not re-run
    (:func:`previous_output`).

    ``grid_phantom(cell_m)``, when given, is the phantom as a grid of that cell sees it (e.g. planar
    layers moved to the nearest cell faces): the tracer answers on it, so that the change of
    (tracer - FDTD) between the cell sizes is the FDTD's discretisation alone, not the change of
    geometry the coarser voxels make (which the tracer would not see on ``phantom``).

    ``cancel`` (an event) and ``deadline`` (a ``time.monotonic()`` instant) stop gprMax (its process
    is killed) and the trace with :class:`~raytrace.errors.BudgetExceededError`; no report is
    written then, and the runs finished so far are what ``reuse`` finds next time.
    ``on_progress(event)`` is told ``{"run", "runs", "cell_m", "stage", "iteration", "iterations"}``
    as the work goes (stage ``gprmax``: time steps done of gprMax's own count; ``reused``: an earlier
    identical run is taken instead; ``tracer``; ``done``); ``on_start`` is :func:`run_gprmax`'s."""
    sizes = [options.cell_m] + ([options.cell_m * coarse_factor] if coarse_factor else [])
    report: dict = {"request": spec.to_dict(), "runs": [], "discretisation": []}
    for k, h in enumerate(sizes):
        opts = dataclasses.replace(options, cell_m=h)
        model = build_model(spec, phantom, opts)
        stem = input_stem(h)
        previous = previous_output(model, directory, stem) if reuse else None
        path = export(model, directory, stem)
        entry = {
            "cell_m": h, "input": path.name, "cells": list(model.cells), "iterations": model.iterations,
            "boxes": model.boxes, "margin_m": opts.margin_m, "pml_cells": opts.pml_cells,
            "transmitter_m": model.tx_m.tolist(), "receivers_m": model.rx_m.tolist(),
            "debye_fits": {mid: {"eps_inf": f.eps_inf, "sigma_s_per_m": f.sigma_s_per_m,
                                 "delta_eps": list(f.delta_eps), "tau_s": list(f.tau_s),
                                 "band_hz": list(f.band_hz), "max_relative_error": f.max_relative_error}
                           for mid, f in model.materials.items()},
        }
        report["runs"].append(entry)
        if not (run and gprmax_available()):
            entry["ran"] = False
            continue

        def tell(stage: str, iteration: int = 0, iterations: int = 0, k: int = k, h: float = h) -> None:
            if on_progress is not None:
                on_progress({"run": k, "runs": len(sizes), "cell_m": h, "stage": stage, "iteration": iteration,
                             "iterations": iterations})

        tell("reused" if previous is not None else "gprmax", 0, model.iterations)
        out, wall = previous or run_gprmax(path, threads, cancel=cancel, deadline=deadline,
                                           on_progress=lambda i, n: tell("gprmax", i, n), on_start=on_start)
        entry["reused"] = previous is not None
        tell("tracer")
        seen = grid_phantom(h) if grid_phantom else phantom
        entry["tracer_phantom"] = seen.description.split("\n")[0] if grid_phantom else spec.phantom
        ts = tracer_spec(model, spec, seen)
        n_tx, n_rx = media_indices(seen, ts)
        a_fd, diag = fdtd_gains(model, out, n_tx, n_rx)
        with _trace_budget(cancel, deadline) as budget:
            result = trace_channel(ts, seen, budget=budget)
        a_tr = tracer_gains(result)
        entry.update(ran=True, wall_s=wall, **diag)
        entry["tracer_receivers_m"] = [r.position_m.tolist() for r in ts.receivers]
        entry["receivers"] = [_row(name, Metrics.of(a_fd[r], spec.frequency_hz), Metrics.of(a_tr[r], spec.frequency_hz),
                                   result.profiles[r].validity, result.profiles[r].medium, model.rx_cell_media[r])
                              for r, name in enumerate(model.rx_names)]
        entry["paths"] = [len(p.paths) for p in result.profiles]
        tell("done")
    runs = [r for r in report["runs"] if r.get("ran")]
    if len(runs) == 2:
        for fine, coarse in zip(runs[0]["receivers"], runs[1]["receivers"]):
            report["discretisation"].append({
                "receiver": fine["receiver"],
                "gain_db": abs(fine["gain_error_db"] - coarse["gain_error_db"]),
                "phase_deg": abs((fine["phase_error_deg"] - coarse["phase_error_deg"] + 180.0) % 360.0 - 180.0),
                "group_delay_s": abs(fine["group_delay_error_s"] - coarse["group_delay_error_s"]),
                "cells_m": [runs[0]["cell_m"], runs[1]["cell_m"]],
                "gain_error_db": [fine["gain_error_db"], coarse["gain_error_db"]],
                "phase_error_deg": [fine["phase_error_deg"], coarse["phase_error_deg"]],
                "group_delay_error_s": [fine["group_delay_error_s"], coarse["group_delay_error_s"]],
            })
    (directory / "report.json").write_text(json.dumps(report, indent=2))
    (directory / "report.md").write_text(markdown(report))
    return report


def markdown(report: dict) -> str:
    """The report as a Markdown table per run (what docs/validation.md quotes)."""
    lines = []
    for run in report["runs"]:
        fits = ", ".join(f"{k} {v['max_relative_error'] * 100:.2f} %" for k, v in run["debye_fits"].items())
        lines.append(f"### {run['cell_m'] * 1e3:g} mm cells: {run['cells'][0]} x {run['cells'][1]} x "
                     f"{run['cells'][2]} cells ({run['pml_cells']} PML), {run['iterations']} steps, "
                     f"air margin {run['margin_m'] * 1e3:g} mm")
        lines.append(f"Debye fit worst error: {fits}.")
        if not run.get("ran"):
            lines.append("(not run)\n")
            continue
        lines.append(f"gprMax wall time {run['wall_s']:.0f} s. Tracer on: {run.get('tracer_phantom', '?')}.\n")
        lines.append("| receiver | FDTD dB | tracer dB | d dB | FDTD deg | d deg | FDTD group delay ns | d ps | "
                     "envelope d ps | validity | medium: tracer / FDTD cells |")
        lines.append("|---|---|---|---|---|---|---|---|---|---|---|")
        for r in run["receivers"]:
            lines.append(f"| {r['receiver']} | {r['fdtd']['gain_db']:.2f} | {r['tracer']['gain_db']:.2f} | "
                         f"{r['gain_error_db']:+.2f} | {r['fdtd']['phase_deg']:.1f} | {r['phase_error_deg']:+.1f} | "
                         f"{r['fdtd']['group_delay_s'] * 1e9:.3f} | {r['group_delay_error_s'] * 1e12:+.1f} | "
                         f"{r['envelope_error_s'] * 1e12:+.1f} | {', '.join(r.get('validity', ())) or '-'} | "
                         f"{r.get('tracer_medium', '?')} / {', '.join(r.get('fdtd_cell_media', ())) or '?'} |")
        lines.append("")
    if report["discretisation"]:
        h1, h2 = (h * 1e3 for h in report["discretisation"][0]["cells_m"])
        lines.append(f"FDTD discretisation: tracer - FDTD at {h1:g} and {h2:g} mm cells, and its change:\n")
        lines.append(f"| receiver | d dB ({h1:g} / {h2:g} mm) | change dB | d deg ({h1:g} / {h2:g} mm) | change deg | "
                     "change of d group delay ps |")
        lines.append("|---|---|---|---|---|---|")
        for d in report["discretisation"]:
            g, p = d["gain_error_db"], d["phase_error_deg"]
            lines.append(f"| {d['receiver']} | {g[0]:+.2f} / {g[1]:+.2f} | {d['gain_db']:.2f} | "
                         f"{p[0]:+.1f} / {p[1]:+.1f} | {d['phase_deg']:.1f} | {d['group_delay_s'] * 1e12:.1f} |")
    return "\n".join(lines) + "\n"


def main_positions(report: dict) -> np.ndarray:  # pragma: no cover - convenience for notebooks
    return np.array(report["runs"][0]["receivers_m"])
