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
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

from raytrace.body.phantom import Phantom
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


def run_gprmax(input_path: Path, threads: int = 2) -> tuple[Path, float]:
    """Run gprMax on ``input_path`` in a child process (OpenMP ``threads``); its HDF5 output and
    the wall time [s]. Raises ``RuntimeError`` with gprMax's last log lines on failure."""
    env = dict(os.environ, OMP_NUM_THREADS=str(int(threads)))
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "gprMax", str(input_path.name), "--hide-progress-bars"],
                          cwd=input_path.parent, env=env, capture_output=True, text=True)
    wall = time.monotonic() - t0
    (input_path.parent / f"{input_path.stem}.log").write_text(proc.stdout + proc.stderr)
    out = input_path.with_suffix(".h5")
    if proc.returncode != 0 or not out.exists():
        tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-15:])
        raise RuntimeError(f"gprMax failed on {input_path} (exit {proc.returncode}):\n{tail}")
    input_path.with_suffix(".wall_s").write_text(f"{wall:.3f}\n")
    return out, wall


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
            grid_phantom: Callable[[float], Phantom] | None = None) -> dict:
    """The report (a JSON-able dict): per cell size the model's facts, gprMax's wall time and
    per receiver the FDTD and tracer metrics and their differences; then per receiver the
    discretisation estimate. With ``run`` false (or gprMax missing) only the inputs are written;
    with ``reuse``, a cell size whose identical input already ran in ``directory`` is not re-run
    (:func:`previous_output`).

    ``grid_phantom(cell_m)``, when given, is the phantom as a grid of that cell sees it (e.g. planar
    layers moved to the nearest cell faces): the tracer answers on it, so that the change of
    (tracer - FDTD) between the cell sizes is the FDTD's discretisation alone, not the change of
    geometry the coarser voxels make (which the tracer would not see on ``phantom``)."""
    sizes = [options.cell_m] + ([options.cell_m * coarse_factor] if coarse_factor else [])
    report: dict = {"request": spec.to_dict(), "runs": [], "discretisation": []}
    for k, h in enumerate(sizes):
        opts = dataclasses.replace(options, cell_m=h)
        model = build_model(spec, phantom, opts)
        stem = f"model_{round(h * 1e4)}"  # e.g. model_20: 2.0 mm
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
        out, wall = previous or run_gprmax(path, threads)
        entry["reused"] = previous is not None
        seen = grid_phantom(h) if grid_phantom else phantom
        entry["tracer_phantom"] = seen.description.split("\n")[0] if grid_phantom else spec.phantom
        ts = tracer_spec(model, spec, seen)
        n_tx, n_rx = media_indices(seen, ts)
        a_fd, diag = fdtd_gains(model, out, n_tx, n_rx)
        result = trace_channel(ts, seen)
        a_tr = tracer_gains(result)
        entry.update(ran=True, wall_s=wall, **diag)
        entry["tracer_receivers_m"] = [r.position_m.tolist() for r in ts.receivers]
        entry["receivers"] = [_row(name, Metrics.of(a_fd[r], spec.frequency_hz), Metrics.of(a_tr[r], spec.frequency_hz),
                                   result.profiles[r].validity, result.profiles[r].medium, model.rx_cell_media[r])
                              for r, name in enumerate(model.rx_names)]
        entry["paths"] = [len(p.paths) for p in result.profiles]
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
