"""The bench's full-wave cases (bench/fullwave) without running gprMax: the layered case's grid
puts every interface on cell faces at both cell sizes, antennas the grid snaps onto an interface
are moved off it for the tracer on the requested side, the grid's own view of each receiver's
cells, re-use of a finished run, and the report's tables."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from bench.fullwave import CASES, layered_on_grid, layered_phantom
from bench.fullwave.__main__ import main as bench_main
from fullwave.compare import OFF_SURFACE_CELLS, tracer_spec
from fullwave.model import build_model
from fullwave.run import markdown, previous_output


def _box_faces_y(model) -> dict[str, tuple[float, float]]:
    """World y extent of each material's boxes, read back from the gprMax text."""
    out: dict[str, list[float]] = {}
    for line in model.input_text.splitlines():
        if line.startswith("#box:"):
            f = line.split()
            y0, y1, mid = float(f[2]), float(f[5]), f[7]
            lo, hi = out.get(mid, [np.inf, -np.inf])
            out[mid] = [min(lo, y0 + model.origin_m[1]), max(hi, y1 + model.origin_m[1])]
    return {k.split("_", 1)[1]: tuple(v) for k, v in out.items()}


def test_layered_case_interfaces_lie_on_cell_faces():
    """2 mm: skin [0, 2], fat [2, 22] mm exactly as the phantom; 3 and 1.5 mm: the nearest faces,
    skin [0, 3] / fat [3, 21] and skin [0, 1.5] / fat [1.5, 22.5] mm (the docstring's statement).
    Tolerance 1 nm: the bounds are shrunk by 1 nm so that voxelize's ceil does not add a cell."""
    spec, ph, opts = CASES["layered"][0]()
    for h, skin, fat in ((0.002, (0.0, 0.002), (0.002, 0.022)), (0.003, (0.0, 0.003), (0.003, 0.021)),
                         (0.0015, (0.0, 0.0015), (0.0015, 0.0225))):
        model = build_model(spec, ph, dataclasses.replace(opts, cell_m=h))
        faces = _box_faces_y(model)
        assert np.allclose(faces["skin_dry"], skin, atol=1e-9), (h, faces)
        assert np.allclose(faces["fat_average_infiltrated"], fat, atol=1e-9), (h, faces)
        assert abs(faces["muscle"][0] - fat[1]) < 1e-9
        # the tracer's phantom for this grid (compare's grid_phantom) has its layers on those faces
        seen = layered_on_grid(h)
        fronts = {o.name: float(np.asarray(o.mesh.vertices)[:, 1].min()) for o in seen.organs}
        assert np.allclose([fronts["skin"], fronts["fat"], fronts["muscle"]], [0.0, skin[1], fat[1]], atol=1e-12)


def test_snapped_contact_sensors_leave_the_surface_on_the_requested_side():
    """The contact sensors (requested 0.5 mm inside the skin) snap onto the skin surface y = 0 (the
    Ez nodes lie on cell faces); the tracer gets them 0.1 cell straight into the skin (+y), where
    the phantom itself (an independent ray-cast) says they are. The grid's cells
    around those nodes are air and skin; mid-fat and air receivers sit among their own medium."""
    spec, ph, opts = CASES["layered"][0]()
    model = build_model(spec, ph, opts)
    ts = tracer_spec(model, spec, ph)
    names = [r.name for r in spec.receivers]
    media = ph.medium_index(np.array([r.position_m for r in ts.receivers]))
    organ = [o.name for o in ph.organs]
    for i, name in enumerate(names):
        if name.startswith("contact"):
            assert abs(model.rx_m[i][1]) < 1e-9  # on the surface in the grid
            step = ts.receivers[i].position_m - model.rx_m[i]
            assert np.allclose(step, [0, OFF_SURFACE_CELLS * 0.002, 0], atol=1e-12) and organ[media[i]] == "skin"
            assert model.rx_cell_media[i] == ("air", "skin")
        else:
            assert np.array_equal(ts.receivers[i].position_m, model.rx_m[i])
    assert model.rx_cell_media[names.index("fat_mid")] == ("fat",)
    assert model.rx_cell_media[names.index("air_30mm")] == ("air",)


def test_previous_output_only_for_the_identical_finished_input(tmp_path):
    spec, ph, opts = CASES["layered"][0]()
    model = build_model(spec, ph, opts)
    (tmp_path / "m.in").write_text(model.input_text)
    (tmp_path / "m.h5").write_bytes(b"")
    assert previous_output(model, tmp_path, "m") is None  # no wall time: the run did not finish
    (tmp_path / "m.wall_s").write_text("12.5\n")
    assert previous_output(model, tmp_path, "m") == (tmp_path / "m.h5", 12.5)
    (tmp_path / "m.in").write_text(model.input_text + "#rx: 0 0 0\n")
    assert previous_output(model, tmp_path, "m") is None


def test_bench_export_only_writes_both_cell_sizes(tmp_path):
    assert bench_main(["layered", "--export-only", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert [r["cell_m"] for r in report["runs"]] == [0.002, 0.0015] and not any(r["ran"] for r in report["runs"])
    assert bench_main(["torso", "--export-only", "--out", str(tmp_path / "t")]) == 0
    assert [r["cell_m"] for r in json.loads((tmp_path / "t" / "report.json").read_text())["runs"]] == [0.002, 0.0015]


def test_every_case_puts_its_layers_on_both_grids_and_the_table_lists_both_cell_sizes(tmp_path):
    """Every planar case (layered, lateral, wall, deep30, deep100) at 2 and 1.5 mm: the tracer's phantom
    for each grid (GRID_PHANTOMS) has its interfaces on that grid's cell faces (multiples of the cell from
    y = 0, where every case's box starts on a 6 mm boundary); the table command's Markdown has one row per
    case and receiver with both cell sizes' differences."""
    from bench.fullwave import GRID_PHANTOMS
    from bench.fullwave.__main__ import table

    for name, grid in GRID_PHANTOMS.items():
        spec, ph, opts = CASES[name][0]()
        for h in (0.002, 0.0015):
            model = build_model(spec, ph, dataclasses.replace(opts, cell_m=h))
            assert abs((model.origin_m[1] + opts.pml_cells * h) / 0.006 - round((model.origin_m[1] + opts.pml_cells * h)
                                                                                  / 0.006)) < 1e-6
            fronts = [float(np.asarray(o.mesh.vertices)[:, 1].min()) for o in grid(h).organs]
            assert all(abs(f / h - round(f / h)) < 1e-6 for f in fronts), (name, h, fronts)
    m = {"gain_db": -30.0, "phase_deg": 10.0, "group_delay_s": 1e-9, "envelope_s": 1e-9}
    row = {"receiver": "a", "validity": [], "fdtd": m, "tracer": m, "gain_error_db": 0.25, "phase_error_deg": -1.0,
           "group_delay_error_s": 12e-12, "envelope_error_s": -3e-12}
    runs = [{"cell_m": h, "ran": True, "receivers": [row]} for h in (0.002, 0.0015)]
    text = table({"wall": {"runs": runs}})
    assert "| wall (2 / 1.5 mm) | a | -30.00 | +0.25 / +0.25 | -1.0 / -1.0 | +12 / +12 | -3 / -3 | - |" in text


def test_layered_phantom_is_the_issue_stack():
    ph = layered_phantom()
    pts = np.array([[0, -0.001, 0], [0, 0.001, 0], [0, 0.021, 0], [0, 0.023, 0]], float)
    assert [ph.organs[m].name if m >= 0 else "air" for m in ph.medium_index(pts)] == ["air", "skin", "fat", "muscle"]


def test_markdown_shows_flags_media_and_both_cell_sizes():
    m = {"gain_db": -30.0, "phase_deg": 10.0, "group_delay_s": 1e-9, "envelope_s": 1e-9}
    row = {"receiver": "a", "validity": ["grazing_exit"], "tracer_medium": "air", "fdtd_cell_media": ["air"],
           "fdtd": m, "tracer": m, "gain_error_db": -20.5, "phase_error_deg": 3.0, "group_delay_error_s": 0.0,
           "envelope_error_s": 0.0}
    run = {"cell_m": 0.002, "cells": [1, 2, 3], "pml_cells": 10, "iterations": 5, "margin_m": 0.02,
           "debye_fits": {}, "ran": True, "wall_s": 1.0, "receivers": [row]}
    disc = {"receiver": "a", "gain_db": 0.25, "phase_deg": 2.0, "group_delay_s": 1e-12, "cells_m": [0.002, 0.003],
            "gain_error_db": [-20.5, -20.25], "phase_error_deg": [3.0, 1.0], "group_delay_error_s": [0.0, 1e-12]}
    text = markdown({"runs": [run], "discretisation": [disc]})
    assert "| a | -30.00 | -30.00 | -20.50 |" in text and "grazing_exit | air / air |" in text
    assert "| a | -20.50 / -20.25 | 0.25 | +3.0 / +1.0 | 2.0 | 1.0 |" in text
