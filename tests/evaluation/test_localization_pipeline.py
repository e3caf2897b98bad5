"""The end-to-end localization pipeline (trace -> ranges -> position): a homogeneous
phantom where every method must find the capsule, determinism, and typed input errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from estimators.errors import EstimatorInputError
from evaluation.localization import evaluate_localization
from raytrace.body.phantom import Material, Organ, Phantom

C = 299_792_458.0
EPS_R = 27.9
SIGMA_S_PER_M = 0.8
#: The delays travel with the phase index Re sqrt(eps' - j sigma / (w eps0)) = 6.28 at 402 MHz
#: (the loss raises it from sqrt(27.9) = 5.28): the constant velocity must use it to be the true one.
N_PHASE = np.sqrt(EPS_R - 1j * SIGMA_S_PER_M / (2 * np.pi * 402e6 * 8.8541878128e-12)).real
CELL = 0.008
SENSORS = [[0.1, 0.0, 0.03], [-0.1, 0.01, 0.02], [0.0, 0.1, -0.02], [0.01, -0.1, 0.0], [0.06, 0.06, 0.09],
           [-0.06, -0.05, 0.1], [0.05, -0.06, -0.09], [-0.05, 0.06, -0.1]]
CAPSULE = [0.012, -0.021, 0.017]


@pytest.fixture(scope="module")
def box():
    # lossy enough (0.8 S/m) that the walls' echoes (>= 0.36 m more path) are > 50 dB down
    mesh = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    body = Material(relative_permittivity=EPS_R, conductivity_s_per_m=SIGMA_S_PER_M)
    return Phantom.build("box", [Organ("body", body, mesh)])


@pytest.fixture(scope="module")
def homogeneous_run(box):
    # far field: the dipole's near-field phase (kr ~ 4.5 here) biases carrier-phase TOA by ~4 mm, a
    # physical effect of its own (tests/raytrace); this test is about the estimators on exact ranges
    return evaluate_localization(box, CAPSULE, SENSORS, trials=4, seed=3, cell_size_m=CELL, rays=20_000,
                                 relative_permittivity=N_PHASE**2, near_field=False)


def test_every_method_finds_the_capsule_in_a_homogeneous_phantom(homogeneous_run):
    r = homogeneous_run
    cv, jv, mb = (r.methods[m] for m in ("nonlinear", "joint_velocity", "model_based"))
    # the constant velocity is the true one here: errors are noise (30 dB: ~0.03 mm per range)
    assert cv.rmse_m < 0.5e-3 and r.methods["linear"].rmse_m < 0.5e-3
    assert jv.rmse_m < 0.5e-3
    # the model-based fix agrees with the constant-velocity one within PDOP x the range
    # equivalent of the grid's stated error (n h / c * c / n = h)
    assert np.linalg.norm(mb.bias_m - cv.bias_m) <= mb.pdop * CELL
    assert mb.rmse_m <= mb.pdop * 0.4 * CELL  # the homogeneous march's own error (fields test)
    assert mb.crlb_m == pytest.approx(cv.crlb_m, rel=0.2)
    assert jv.extra["relative_permittivity"] == pytest.approx(N_PHASE**2, rel=1e-3)
    assert all(s.converged_fraction == 1.0 and s.failures == 0 for s in r.methods.values())
    assert r.delay_kind == "phase"  # GCC measures the carrier-phase delay: phase-index fields
    assert cv.cep50_m <= cv.cep90_m <= cv.rmse_m * 3


def test_same_seed_same_answer(box, homogeneous_run):
    again = evaluate_localization(box, CAPSULE, SENSORS, trials=4, seed=3, cell_size_m=CELL, rays=20_000,
                                  methods=("nonlinear",), relative_permittivity=N_PHASE**2, near_field=False)
    np.testing.assert_array_equal(again.methods["nonlinear"].estimates_m,
                                  homogeneous_run.methods["nonlinear"].estimates_m)


def test_rss_and_pdoa_ranging_run(box):
    rss = evaluate_localization(box, CAPSULE, SENSORS, ranging="rss", trials=3, rays=20_000)
    assert set(rss.methods) == {"rss"} and np.isfinite(rss.methods["rss"].rmse_m)
    # the CM2 bound: ln(10) 7.85 / (10 4.26) d ~ 0.42 d per range
    assert rss.methods["rss"].crlb_m > 0.01
    pdoa = evaluate_localization(box, CAPSULE, SENSORS, ranging="pdoa", methods=("nonlinear",), trials=3,
                                 rays=20_000, relative_permittivity=N_PHASE**2)
    # 21-tone regression over 20 MHz at 30 dB in-band SNR: centimetres (phase-difference bound,
    # ~9 mm per range); 3 trials of a 3-D error scatter around the bound, 3x is a generous ceiling
    stats = pdoa.methods["nonlinear"]
    assert math.isfinite(stats.crlb_m) and stats.rmse_m < 3 * stats.crlb_m


@pytest.mark.parametrize("kwargs, field", [
    ({"ranging": "radar"}, "ranging"),
    ({"ranging": "rss", "methods": ["model_based"]}, "methods[0]"),
    ({"methods": ["rss"]}, "methods[0]"),
    ({"methods": ["nonlinear", "triangulate"]}, "methods[1]"),
    ({"capsule": "nowhere"}, "capsule"),
    ({"capsule": [0.0, float("nan"), 0.0]}, "capsule"),
    ({"sensors": SENSORS[:3]}, "sensors"),
    ({"sensors": SENSORS[:7] + ["no_such_site"]}, "sensors[7]"),
    ({"trials": 0}, "trials"),
    ({"seed": -1}, "seed"),
    ({"delay_kind": "carrier"}, "delay_kind"),
    ({"ranging": "rss", "delay_kind": "group"}, "delay_kind"),
])
def test_bad_requests_name_the_field(box, kwargs, field):
    args = {"capsule": CAPSULE, "sensors": SENSORS}
    args.update(kwargs)
    capsule, sensors = args.pop("capsule"), args.pop("sensors")
    with pytest.raises(EstimatorInputError) as exc:
        evaluate_localization(box, capsule, sensors, rays=2000, **args)
    assert exc.value.field == field
