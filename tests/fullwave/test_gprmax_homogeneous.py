"""The tracer against gprMax (full-wave FDTD, an independent solver) in homogeneous muscle.

A z-directed Hertzian dipole deep in the half-space phantom's muscle (0.5 m from any surface:
an unbounded lossy, dispersive medium to both solvers), dipole receivers 5 and 10 cm away
broadside (k r ~ 3 and 6), 2 mm cells. Acceptance (issue 23): with the near-field term the
tracer agrees within 0.2 dB / 3 deg at both receivers; without it the far-field-only direct
path is off by about -0.5 dB / +18 deg at 5 cm (measured -0.50 dB / +17.7 deg), which the test
also requires (> 0.3 dB or > 10 deg) so that it can tell the two apart. Measured with the term:
0.001 dB / 0.03 deg and 0.003 dB / 0.6 deg; the 10 cm phase residual is the grid's numerical
dispersion (it grows with distance and shrinks with the cell). Runs one gprMax model (about
two minutes on 2 idle cores).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fullwave.compare import Metrics, fdtd_gains, media_indices, tracer_gains, tracer_spec
from fullwave.model import FdtdOptions, build_model
from fullwave.run import export, run_gprmax
from raytrace.body.library import get_phantom
from raytrace.solver.tracer import trace_channel
from raytrace.spec import Antenna, ChannelSpec

F0 = 402e6


@pytest.mark.slow
@pytest.mark.timeout(7200)  # a hang guard: the machine is shared, gprMax gets what the other jobs leave it
def test_tracer_with_near_field_matches_gprmax_in_homogeneous_muscle(tmp_path):
    phantom = get_phantom("half-space")
    tx = np.array([0.0, 0.5, 0.0])
    spec = ChannelSpec(Antenna(position_m=tx, polarization=[0, 0, 1], pattern="dipole"),
                       (Antenna(position_m=tx + [0.05, 0, 0], name="r5", pattern="dipole"),
                        Antenna(position_m=tx + [0.10, 0, 0], name="r10", pattern="dipole")),
                       phantom="half-space", frequency_hz=F0)
    model = build_model(spec, phantom, FdtdOptions(cell_m=0.002, margin_m=0.02, pml_cells=10))
    assert model.materials and all(f.max_relative_error < 5e-3 for f in model.materials.values())
    out, _wall = run_gprmax(export(model, tmp_path, "muscle"))
    ts = tracer_spec(model, spec)
    n_tx, n_rx = media_indices(phantom, ts)
    a_fdtd, diag = fdtd_gains(model, out, n_tx, n_rx)
    # the window holds the response: < 0.1 % of a receiver's energy in its last 10 % (measured 1e-7 and
    # 8e-5 with this 20 mm margin / 10-cell PML; a 16 mm / 8-cell domain left 1.3e-3 and a 0.29 dB error at 10 cm)
    assert max(diag["tail_energy_fraction"]) < 1e-3
    for near, tol_db, tol_deg in ((True, 0.2, 3.0), (False, None, None)):
        a_tr = tracer_gains(trace_channel(dataclasses.replace(ts, near_field=near), phantom))
        for r in range(2):
            fd, tr = Metrics.of(a_fdtd[r], F0), Metrics.of(a_tr[r], F0)
            d_db = tr.gain_db - fd.gain_db
            d_deg = (tr.phase_deg - fd.phase_deg + 180) % 360 - 180
            if near:
                assert abs(d_db) < tol_db and abs(d_deg) < tol_deg, (r, d_db, d_deg)
                # group delay: the grid's dispersion slows the FDTD by ~15 ps at 10 cm (0.6 %)
                assert abs(tr.group_delay_s - fd.group_delay_s) < 0.02 * fd.group_delay_s
            elif r == 0:
                assert abs(d_db) > 0.3 or abs(d_deg) > 10.0, (d_db, d_deg)
