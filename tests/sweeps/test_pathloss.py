"""The path-loss fit (sweeps.pathloss) against closed forms, and the fitted model in the RSS estimator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators import PathProfile, estimate_rss
from estimators.rss import PathLossModel
from raytrace.errors import InputError
from sweeps.pathloss import fit_path_loss, load_model, model_dict
from sweeps.spec import SweepSpec


def test_exact_data_give_the_exact_model():
    d = np.array([0.06, 0.08, 0.1, 0.15, 0.3])
    pl = 40.0 + 10 * 3.5 * np.log10(d / 0.05)  # PL0 40 dB, n 3.5, no shadowing
    m = fit_path_loss(d, pl)
    assert m.path_loss_d0_db == pytest.approx(40.0, abs=1e-9) and m.exponent == pytest.approx(3.5, abs=1e-9)
    assert m.shadowing_db == pytest.approx(0.0, abs=1e-9)


def test_shadowing_is_the_residual_spread():
    """Residuals +-s alternating on 2k points around the line: the least-squares line is the true one
    when the signs balance within each x pair, and sigma = s sqrt(2k / (2k - 2))."""
    d = np.repeat(np.geomspace(0.05, 0.4, 10), 2)
    s = 3.0
    pl = 45.0 + 42.6 * np.log10(d / 0.05) + np.tile([s, -s], 10)
    m = fit_path_loss(d, pl)
    assert m.path_loss_d0_db == pytest.approx(45.0, abs=1e-9) and m.exponent == pytest.approx(4.26, abs=1e-9)
    assert m.shadowing_db == pytest.approx(s * math.sqrt(20 / 18), rel=1e-12)


def test_too_few_links_are_refused():
    with pytest.raises(InputError):
        fit_path_loss([0.1, 0.1, 0.1], [50, 51, 52])
    with pytest.raises(InputError):
        fit_path_loss([0.1, 0.2], [50, 60])


def test_the_fitted_model_ranges_through_estimate_rss_and_a_spec(tmp_path):
    model = PathLossModel("fitted", 30.0, 5.0, 2.0)
    gain = 1e-3  # path gain -60 dB: PL 60 dB -> d = 0.05 10^((60 - 30) / 50)
    profile = PathProfile([1e-9], [gain])
    res = estimate_rss(profile, model=model, shadowing=False, trials=3, seed=0)
    assert res.model == "fitted" and res.median_distance_m == pytest.approx(0.05 * 10 ** (30 / 50), rel=1e-12)
    path = tmp_path / "m.json"
    import json

    path.write_text(json.dumps(model_dict(model)))
    assert load_model(path) == model
    spec = SweepSpec.from_dict({"capsule_positions": [{"site": "stomach"}], "receivers": [{"site": "belt_left"}],
                                "ranging": {"rss": {"model": model_dict(model)}}})
    assert spec["ranging"]["rss"]["model"]["exponent"] == 5.0
