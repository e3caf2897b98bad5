"""The gprMax export without running it: Debye fits against the Cole-Cole model, the box cover
of the voxel grid, snapped antennas on their Yee nodes, the CLI's --export-only."""

from __future__ import annotations

import json

import numpy as np

from fullwave.debye import fit_debye
from fullwave.model import FdtdOptions, _boxes, build_model
from raytrace.physics import tissues
from raytrace.physics.materials import Material
from raytrace.spec import Antenna, ChannelSpec


def test_debye_fit_of_gabriel_tissues_over_the_band():
    """Two poles + conductivity over 201-804 MHz: the reported worst error is the real one
    (recomputed here from the Cole-Cole model at 400 fresh frequencies) and below 0.5 %."""
    f = np.linspace(201e6, 804e6, 400)
    for name in ("muscle", "fat_average_infiltrated", "skin_dry", "small_intestine"):
        fit = fit_debye(Material(name), (201e6, 804e6))
        eps = tissues.complex_relative_permittivity(name, f)
        err = np.max(np.abs(fit.permittivity(f) - eps) / np.abs(eps))
        assert err < 5e-3 and err <= fit.max_relative_error * 1.05 + 1e-6, (name, err, fit.max_relative_error)
        assert fit.eps_inf >= 1 and fit.sigma_s_per_m >= 0 and min(fit.delta_eps) >= 0


def test_boxes_cover_the_grid_exactly():
    rng = np.random.default_rng(3)
    grid = rng.integers(-1, 3, size=(7, 6, 5))
    grid[:, :3, :] = 1  # a slab that merges
    painted = np.full(grid.shape, -1)
    for i0, j0, k0, i1, j1, k1, m in _boxes(grid):
        assert (painted[i0:i1, j0:j1, k0:k1] == -1).all()  # no overlap
        painted[i0:i1, j0:j1, k0:k1] = m
    assert (painted == grid).all()


def test_export_of_the_layered_slab(tmp_path):
    from raytrace.body.library import get_phantom

    ph = get_phantom("layered-slab")
    spec = ChannelSpec(Antenna(site="tx", polarization=[0, 0, 1], pattern="dipole"),
                       (Antenna(site="rx_normal", pattern="dipole"), Antenna(site="rx_fat", pattern="dipole")),
                       phantom="layered-slab")
    model = build_model(spec, ph, FdtdOptions(cell_m=0.002))
    text = model.input_text
    assert text.count("#hertzian_dipole: z") == 1 and text.count("#rx:") == 2
    assert set(model.materials) == {m for m in model.materials}  # ids are unique
    assert len(model.materials) == 3  # skin, fat, muscle (air is gprMax's free_space)
    for pos, site in zip(model.rx_m, ("rx_normal", "rx_fat")):  # snapped within half a cell per axis
        assert np.all(np.abs(pos - ph.sites[site].position_m) <= 0.001 + 1e-12)
    # the z component's Yee node: integer cells in x, y, half a cell in z from the domain origin
    frac = (model.tx_m - model.origin_m) / 0.002
    assert np.allclose(frac[:2], np.round(frac[:2])) and np.isclose(frac[2] % 1, 0.5)


def test_cli_export_only(tmp_path):
    from service.cli import main

    req = tmp_path / "req.json"
    req.write_text(json.dumps({"phantom": "half-space", "transmitter": {"site": "tx"},
                               "receivers": [{"site": "rx_normal"}]}))
    out = tmp_path / "out"
    assert main(["fullwave", str(req), "--out", str(out), "--export-only"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert [r["ran"] for r in report["runs"]] == [False, False]
    assert (out / report["runs"][0]["input"]).read_text().startswith("#title:")
    assert main(["fullwave", str(tmp_path / "missing.json"), "--out", str(out)]) == 2


def test_model_size_is_the_built_models_grid_and_bounds_its_steps():
    """model_size (no voxelization, no fit) gives build_model's exact cell counts, and time steps at or
    just above it: the bound takes the slowest medium of the whole phantom 1 % up, the model the slowest
    in its box (here the same muscle / skin / fat: <= 1 % + 1 step more)."""
    from fullwave.model import model_size
    from raytrace.body.library import get_phantom

    ph = get_phantom("layered-slab")
    spec = ChannelSpec(Antenna(site="tx", polarization=[0, 0, 1], pattern="dipole"),
                       (Antenna(site="rx_normal", pattern="dipole"),), phantom="layered-slab")
    for opts in (FdtdOptions(cell_m=0.002), FdtdOptions(cell_m=0.003, margin_m=0.01, pml_cells=6)):
        size, model = model_size(spec, ph, opts), build_model(spec, ph, opts)
        assert size.cells == model.cells
        assert model.iterations <= size.iterations <= 1.01 * model.iterations + 1
        assert size.cell_updates == int(np.prod(model.cells)) * size.iterations
