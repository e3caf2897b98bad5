"""Position estimators against closed forms written here (no shared code with the package):
noiseless ranges / delays / path losses give the position back; the CRLB of a symmetric
layout; Monte Carlo spreads against the bound; typed input errors naming the field."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.errors import EstimatorInputError
from estimators.localization import (
    fit_path_loss_model,
    joint_velocity_crlb,
    joint_velocity_fix,
    linear_fix,
    nonlinear_fix,
    range_crlb,
    rss_fix,
    rss_position_crlb,
)
from estimators.rss import PathLossModel

C = 299_792_458.0
#: A non-degenerate 3-D layout: eight points on two tilted rings around a torso-sized volume.
SENSORS = np.array([[0.15, 0.0, 0.05], [0.0, 0.12, 0.06], [-0.15, 0.0, 0.04], [0.0, -0.12, 0.05],
                    [0.1, 0.09, 0.13], [-0.1, 0.09, 0.12], [-0.1, -0.08, 0.14], [0.11, -0.08, 0.12]])
POSITIONS = [np.array([0.02, -0.03, 0.01]), np.array([-0.05, 0.04, 0.09]), np.array([0.06, 0.02, -0.06])]
AXES = 0.1 * np.vstack([np.eye(3), -np.eye(3)])  # six sensors on the axes, 0.1 m from the origin


def distances(x):
    return np.sqrt(((SENSORS - x) ** 2).sum(axis=1))


@pytest.mark.parametrize("x", POSITIONS)
def test_noiseless_ranges_give_the_position_to_1e9_m(x):
    # exact arithmetic would give x; 1e-9 m leaves ~7 orders of magnitude for round-off
    r = distances(x)
    for fix in (linear_fix(SENSORS, r), nonlinear_fix(SENSORS, r), nonlinear_fix(SENSORS, r, 1e-3, loss="soft_l1")):
        assert np.max(np.abs(fix.position_m - x)) < 1e-9, fix.method
        assert fix.converged
        assert np.max(np.abs(fix.residuals_m)) < 1e-9


@pytest.mark.parametrize("x", POSITIONS)
@pytest.mark.parametrize("eps_r", [27.9, 55.0])
def test_joint_velocity_recovers_position_and_velocity_from_noiseless_delays(x, eps_r):
    v = C / math.sqrt(eps_r)
    fix = joint_velocity_fix(SENSORS, distances(x) / v, 1e-12)
    assert np.max(np.abs(fix.position_m - x)) < 1e-9
    assert fix.velocity_m_per_s == pytest.approx(v, rel=1e-9)
    assert fix.extra["relative_permittivity"] == pytest.approx(eps_r, rel=1e-8)


def test_joint_velocity_with_every_delay_equal_still_solves():
    # the closed form is singular (|x|^2 and v^2 columns parallel); the nonlinear fit is not
    v = C / math.sqrt(27.9)
    fix = joint_velocity_fix(AXES, np.full(6, 0.1 / v), 1e-12)
    assert np.max(np.abs(fix.position_m)) < 1e-9
    assert fix.velocity_m_per_s == pytest.approx(v, rel=1e-9)


def test_symmetric_layout_bound_is_sigma_over_root_two():
    # six sensors on the axes, equidistant: sum u u^T = 2 I, so Cov = sigma^2 / 2 I
    sigma = 1e-3
    b = range_crlb(AXES, np.zeros(3), sigma)
    np.testing.assert_allclose(b.sigma_m, sigma * math.sqrt(0.5), rtol=1e-12)
    np.testing.assert_allclose(b.covariance_m2, np.eye(3) * sigma**2 / 2, atol=1e-20)
    assert b.pdop == pytest.approx(math.sqrt(1.5), rel=1e-12)
    assert b.gdop == b.pdop  # known velocity: no nuisance parameter
    assert b.rms_m == pytest.approx(sigma * math.sqrt(1.5), rel=1e-12)


def test_joint_velocity_bound_at_the_centre_of_the_symmetric_layout():
    # rows (p u_i, d): sum u_i = 0 decouples the slowness, so the position block is unchanged
    # from the known-velocity case in delay units: sigma_x = sigma_tau v / sqrt(2)
    v, sigma_s = 0.6e8, 1e-12
    b = joint_velocity_crlb(AXES, np.zeros(3), v, sigma_s)
    np.testing.assert_allclose(b.sigma_m, sigma_s * v * math.sqrt(0.5), rtol=1e-9)


def test_rss_bound_of_the_symmetric_layout():
    # Fisher rows 10 n / (ln 10 d) u_i over sigma_dB: sigma_x = ln(10) sigma d / (10 n) / sqrt(2)
    b = rss_position_crlb(AXES, np.zeros(3), 4.26, 7.85)
    expected = math.log(10.0) * 7.85 * 0.1 / (10 * 4.26) / math.sqrt(2.0)
    np.testing.assert_allclose(b.sigma_m, expected, rtol=1e-12)


def test_nonlinear_fix_is_efficient_monte_carlo_covariance_meets_the_bound():
    # 2000 fixes with N(0, sigma^2) ranges: the sample covariance estimates the CRLB to
    # about sqrt(2 / 2000) = 3 % per variance (chi-square); 12 % leaves 4 standard errors,
    # and 1 mm noise on ~0.15 m ranges keeps the nonlinearity's bias far below that
    rng = np.random.default_rng(7)
    x, sigma = POSITIONS[0], 1e-3
    r0 = distances(x)
    est = np.array([nonlinear_fix(SENSORS, r0 + sigma * rng.standard_normal(len(r0)), sigma).position_m
                    for _ in range(2000)])
    u = (x - SENSORS) / r0[:, None]
    bound = np.linalg.inv(u.T @ u) * sigma**2  # written out here: the closed-form CRLB
    np.testing.assert_allclose(np.diag(np.cov(est.T)), np.diag(bound), rtol=0.12)
    assert np.all(np.abs(est.mean(axis=0) - x) < 4 * np.sqrt(np.diag(bound) / 2000) + 1e-6)
    fix = nonlinear_fix(SENSORS, r0, sigma)
    np.testing.assert_allclose(fix.covariance_m2, bound, rtol=1e-6, atol=1e-14)


def test_linear_fix_covariance_matches_its_monte_carlo_spread():
    # first-order propagation of the range variances; 0.1 mm noise keeps second-order terms
    # negligible; 2000 trials give ~3 % per variance, 12 % is 4 standard errors
    rng = np.random.default_rng(3)
    x, sigma = POSITIONS[1], 1e-4
    r0 = distances(x)
    est = np.array([linear_fix(SENSORS, r0 + sigma * rng.standard_normal(len(r0)), sigma).position_m
                    for _ in range(2000)])
    predicted = linear_fix(SENSORS, r0, sigma).covariance_m2
    np.testing.assert_allclose(np.diag(np.cov(est.T)), np.diag(predicted), rtol=0.12)
    # the linear estimator cannot beat the bound
    assert np.all(np.diag(predicted) >= np.diag(range_crlb(SENSORS, x, sigma).covariance_m2) * (1 - 1e-9))


def test_a_robust_loss_rejects_one_gross_outlier():
    x = POSITIONS[0]
    r = distances(x) + 1e-4 * np.random.default_rng(1).standard_normal(len(SENSORS))
    r[2] += 0.05  # 50 mm multipath error on one sensor
    plain = nonlinear_fix(SENSORS, r, 1e-4)
    robust = nonlinear_fix(SENSORS, r, 1e-4, loss="soft_l1", loss_scale=3.0)
    assert np.linalg.norm(plain.position_m - x) > 5e-3
    assert np.linalg.norm(robust.position_m - x) < 1e-3
    assert robust.residuals_m[2] == pytest.approx(0.05, abs=2e-3)


def test_rss_fix_inverts_noiseless_path_losses_and_accepts_a_fitted_model():
    model = PathLossModel("test", 47.14, 4.26, 7.85)
    x = POSITIONS[2]
    d = distances(x)
    pl = 47.14 + 10 * 4.26 * np.log10(d / 0.05)  # the CM2 law written out
    for m in ("cm2_deep_tissue", model, {"path_loss_d0_db": 47.14, "exponent": 4.26, "shadowing_db": 7.85}):
        fix = rss_fix(SENSORS, pl, m)
        assert np.max(np.abs(fix.position_m - x)) < 1e-9
    fitted = fit_path_loss_model(d, pl)
    assert fitted.path_loss_d0_db == pytest.approx(47.14, abs=1e-9)
    assert fitted.exponent == pytest.approx(4.26, abs=1e-9)
    # a subnormal distance underflows d / d0 to 0: refused naming the field (was an SVD error, a 500)
    with pytest.raises(EstimatorInputError) as info:
        fit_path_loss_model([1.0, 1.0, 5e-324], [0.0, 0.0, 0.0], reference_distance_m=2.0)
    assert info.value.field == "distances_m"


@pytest.mark.parametrize("call, field", [
    (lambda: linear_fix(SENSORS[:3], [0.1, 0.1, 0.1]), "sensors"),
    (lambda: joint_velocity_fix(SENSORS[:4], [1e-9] * 4), "sensors"),
    (lambda: linear_fix(np.vstack([SENSORS, SENSORS[:1] + 1e-6]), np.ones(9) * 0.1), "sensors[8].position_m"),
    (lambda: linear_fix(SENSORS * [1, 1, 0], np.ones(8) * 0.1), "sensors"),
    (lambda: linear_fix(np.outer(np.arange(1, 6), [0.01, 0.02, 0.03]), np.ones(5) * 0.1), "sensors"),
    (lambda: nonlinear_fix(SENSORS, [0.1] * 7 + [float("nan")]), "ranges_m[7]"),
    (lambda: nonlinear_fix(SENSORS, [0.1] * 7 + [-0.1]), "ranges_m[7]"),
    (lambda: nonlinear_fix(SENSORS, [0.1] * 8, [1e-3] * 7 + [-1e-3]), "sigma_m[7]"),
    (lambda: nonlinear_fix(SENSORS, [0.1] * 7), "ranges_m"),
    (lambda: nonlinear_fix(SENSORS, [0.1] * 8, loss="l2"), "loss"),
    (lambda: nonlinear_fix(SENSORS.tolist()[:7] + [[0.0, float("inf"), 0.0]], [0.1] * 8), "sensors[7].position_m"),
    (lambda: joint_velocity_fix(SENSORS, [1e-9] * 7 + [0.0]), "delays_s[7]"),
    (lambda: rss_fix(SENSORS, [60.0] * 8, "cm3"), "model"),
    (lambda: rss_fix(SENSORS, [60.0] * 8, {"exponent": 3, "shadowing_db": 4}), "model.path_loss_d0_db"),
])
def test_bad_input_names_the_field(call, field):
    with pytest.raises(EstimatorInputError) as exc:
        call()
    assert exc.value.field == field


def test_coplanar_and_collinear_messages_say_which():
    with pytest.raises(EstimatorInputError, match="coplanar"):
        linear_fix(SENSORS * [1, 1, 0], np.ones(8) * 0.1)
    with pytest.raises(EstimatorInputError, match="collinear"):
        linear_fix(np.outer(np.arange(1, 6), [0.01, 0.02, 0.03]), np.ones(5) * 0.1)


def test_which_delay_each_ranging_measures():
    """docs/science.md (S26): the envelope and PDOA time the group delay, the carrier-phase TOA
    methods the phase delay; sweep column prefixes name the same methods; RSS measures none."""
    from estimators.localization import DELAY_KINDS, check_delay_kind, measured_delay_kind

    assert DELAY_KINDS == ("group", "phase")
    expected = {"envelope": "group", "pdoa": "group", "regression": "group", "two_tone": "group",
                "toa_envelope": "group", "pdoa_regression": "group", "gcc": "phase", "all_peaks": "phase",
                "first_peak": "phase", "toa_gcc": "phase", "toa_first_peak": "phase"}
    assert {k: measured_delay_kind(k) for k in expected} == expected
    for bad in ("rss", "toa_rss", "music"):
        with pytest.raises(EstimatorInputError) as info:
            measured_delay_kind(bad)
        assert info.value.field == "ranging"
    assert check_delay_kind("phase") == "phase"
    with pytest.raises(EstimatorInputError) as info:
        check_delay_kind("Group", "sensors.delay_kind")
    assert info.value.field == "sensors.delay_kind"
