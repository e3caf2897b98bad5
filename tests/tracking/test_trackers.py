"""The trackers against oracles written here: a straight tube whose points are a + s u (no
centreline code), truths simulated here from the closed-form white-noise-acceleration model,
chi-square bands from scipy, and a fold-back tract built by hand."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from raytrace.body.centreline import Centreline
from tracking import (
    Observation,
    RfFix,
    TrackerConfig,
    TrackingInputError,
    VisualMotion,
    kalman_track,
    nees,
    particle_track,
)

A = np.array([0.01, -0.02, 0.03])
U = np.array([1.0, 2.0, 2.0]) / 3.0  # an oblique tube: the projection's variance t^T C t is not a diagonal entry
LENGTH = 0.4


def _tube(length: float = LENGTH) -> Centreline:
    # several collinear vertices, so the filter crosses segment boundaries
    return Centreline([("tube", [A + s * U for s in np.linspace(0.0, length, 9)])])


def test_noiseless_measurements_reproduce_the_trajectory_to_a_micrometre():
    """Exact fixes and advances declared with 1 nm sigmas: the estimate is the truth to 1e-6 m
    (the residual is the prior's weight against 1e-18 m^2 of measurement variance, ~1e-12 m)."""
    t = 0.5 * np.arange(200)
    s = 0.05 + 1.5e-3 * t + 2e-3 * np.sin(2 * np.pi * t / 8.0) + 0.02 * (t > 60)  # with a jump back and forth
    s = np.where(t > 60, s - 0.02, s)
    roll = np.cumsum(np.r_[0.0, np.full(199, 3.0)])
    obs = [Observation(t[k], RfFix(A + s[k] * U, 1e-18 * np.eye(3)),
                       None if k == 0 else VisualMotion(s[k] - s[k - 1], 1e-9, roll[k] - roll[k - 1], 1e-9))
           for k in range(len(t))]
    track = kalman_track(_tube(), obs, TrackerConfig(initial_s_m=0.04, initial_s_sigma_m=0.01, gate_probability=None))
    assert np.max(np.abs(track.s_m - s)) < 1e-6
    assert np.max(np.linalg.norm(track.position_m - (A + s[:, None] * U), axis=1)) < 1e-6
    assert np.max(np.abs(track.roll_deg - roll)) < 1e-6
    # RF alone (no video) fixes the position at every step just as well
    rf_only = [Observation(o.t_s, o.rf) for o in obs]
    assert np.max(np.abs(kalman_track(_tube(), rf_only, TrackerConfig(gate_probability=None)).s_m - s)) < 1e-6
    # video alone from an exact start: dead reckoning, exact
    video = [Observation(o.t_s, None, o.visual) for o in obs]
    vt = kalman_track(_tube(), video, TrackerConfig(initial_s_m=s[0], initial_s_sigma_m=1e-9))
    assert np.max(np.abs(vt.s_m - s)) < 1e-6


def test_particle_filter_noiseless_within_its_prior_sampling():
    """The particle filter keeps the particle nearest to the first exact fix: its error is the
    prior's sampling, ~ sigma_0 / N (1 mm / 4000 = 2.5e-7 m); tolerance 1e-5 m (40 x that)."""
    t = 0.5 * np.arange(60)
    s = 0.1 + 2e-3 * t
    obs = [Observation(t[k], RfFix(A + s[k] * U, 1e-14 * np.eye(3)),
                       None if k == 0 else VisualMotion(s[k] - s[k - 1], 1e-7, 0.0, 1e-3)) for k in range(len(t))]
    track = particle_track(_tube(), obs, TrackerConfig(initial_s_m=0.1, initial_s_sigma_m=1e-3, particles=4000))
    assert np.max(np.abs(track.s_m - s)) < 1e-5


def _simulate(rng, steps, dt, q, qr, s0, s0_sigma, v_sigma, C, sigma_adv, sigma_roll):
    """Truth from the discretised white-noise-acceleration model (Bar-Shalom Eq 6.2.2-12, written out
    here), and Gaussian measurements with the declared covariances."""
    Qs = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    x = np.array([rng.normal(s0, s0_sigma), rng.normal(0.0, v_sigma)])
    roll = rng.normal(0.0, 1e-3)
    S, V, R = [], [], []
    for k in range(steps):
        if k:
            x = np.array([x[0] + x[1] * dt, x[1]]) + rng.multivariate_normal([0, 0], Qs)
            roll += rng.normal(0.0, np.sqrt(qr * dt))
        S.append(x[0]), V.append(x[1]), R.append(roll)
    S, V, R = map(np.array, (S, V, R))
    obs = []
    for k in range(steps):
        fix = RfFix(A + S[k] * U + rng.multivariate_normal(np.zeros(3), C), C)
        vis = None if k == 0 else VisualMotion(S[k] - S[k - 1] + rng.normal(0, sigma_adv), sigma_adv,
                                               R[k] - R[k - 1] + rng.normal(0, sigma_roll), sigma_roll)
        obs.append(Observation(k * dt, fix, vis))
    return S, V, R, obs


def _anees(declared_scale: float) -> tuple[np.ndarray, tuple[float, float]]:
    # a 4 m tube, starting in its middle: the truth never reaches an end (checked: it stays within 1.5 m)
    runs, steps, dt = 40, 100, 0.5
    q, qr = 1e-8, 20.0
    C = np.array([[1.0, 0.3, 0.0], [0.3, 2.0, -0.4], [0.0, -0.4, 1.5]]) * 1e-4  # ~10-14 mm, correlated axes
    sa, sr = 3e-4, 0.2
    rng = np.random.default_rng(7)
    cfg = TrackerConfig(accel_psd_m2_per_s3=q, roll_psd_deg2_per_s=qr, initial_s_m=2.0, initial_s_sigma_m=5e-3,
                        initial_v_sigma_m_per_s=3e-3, gate_probability=None)
    total = np.zeros(steps)
    for _ in range(runs):
        S, V, R, obs = _simulate(rng, steps, dt, q, qr, 2.0, 5e-3, 3e-3, C, sa, sr)
        if declared_scale != 1.0:  # a filter told the noise is smaller than it is
            obs = [Observation(o.t_s, RfFix(o.rf.position_m, o.rf.covariance_m2 * declared_scale**2),
                               None if o.visual is None else VisualMotion(
                                   o.visual.advance_m, o.visual.advance_sigma_m * declared_scale,
                                   o.visual.roll_deg, o.visual.roll_sigma_deg * declared_scale)) for o in obs]
        assert np.all(np.abs(S - 2.0) < 1.5)
        total += nees(kalman_track(_tube(4.0), obs, cfg), S, V, R)
    anees = total / runs
    dof = 3 * runs  # runs x ANEES ~ chi-square(3 runs) when consistent (Bar-Shalom Eq 5.4.2-4)
    return anees, (chi2.ppf(0.025, dof) / runs, chi2.ppf(0.975, dof) / runs)


def test_nees_is_inside_its_95_percent_band_when_the_noise_is_as_declared():
    """40 Monte Carlo runs x 100 steps, state (s, v, roll), known Gaussian noise: the per-step average
    NEES is inside the two-sided 95 % chi-square(120)/40 band at >= 90 % of the steps (95 % expected;
    over 100 steps the binomial sd is 2.2 %, so 90 % is 2.3 sd below) and its mean over the run
    within 10 % of 3 (the state dimension)."""
    anees, (lo, hi) = _anees(1.0)
    inside = np.mean((anees >= lo) & (anees <= hi))
    assert inside >= 0.90, (inside, lo, hi, anees.min(), anees.max())
    assert abs(anees.mean() - 3.0) < 0.3


def test_nees_leaves_the_band_when_the_filter_is_overconfident():
    """The same test can fail: declared sigmas half the true ones put most steps above the band."""
    anees, (lo, hi) = _anees(0.5)
    assert np.mean(anees > hi) > 0.8


# ----------------------------------------------------------------------- fold-back
R_TURN = 0.006
LEG = 0.10


def _fold_back() -> tuple[Centreline, float]:
    """Leg A along +x, a semicircle of radius 6 mm, leg B back along -x, 12 mm beside leg A."""
    leg_a = [[x, 0.0, 0.0] for x in np.linspace(0.0, LEG, 51)]
    phi = np.linspace(-np.pi / 2, np.pi / 2, 31)[1:-1]
    turn = [[LEG + R_TURN * np.cos(p), R_TURN + R_TURN * np.sin(p), 0.0] for p in phi]
    leg_b = [[x, 2 * R_TURN, 0.0] for x in np.linspace(LEG, 0.0, 51)]
    return Centreline([("gut", leg_a + turn + leg_b)]), LEG + np.pi * R_TURN


def _truth_point(s: float) -> np.ndarray:
    start_b = LEG + np.pi * R_TURN
    if s <= LEG:
        return np.array([s, 0.0, 0.0])
    if s >= start_b:
        return np.array([LEG - (s - start_b), 2 * R_TURN, 0.0])
    p = -np.pi / 2 + (s - LEG) / R_TURN
    return np.array([LEG + R_TURN * np.cos(p), R_TURN + R_TURN * np.sin(p), 0.0])


def test_particle_filter_resolves_a_fold_back_the_kalman_filter_cannot():
    """The capsule runs 60 mm along leg B (s from 0.14 m, x from 0.08 to 0.02 m) with no prior on
    where it is; its RF fixes have 15 mm of noise per axis, more than the 12 mm between the legs, so
    each fix alone cannot tell leg A from leg B. The video's advance says which way along s it
    moves; only the sequence of fixes moving in -x tells the legs apart (on leg A the same advance
    moves +x). The particle filter keeps both legs alive at first (>= 20 % of the mass on each at some step of
    the first 10 s; measured 45 / 44 %),
    then puts > 95 % on leg B and ends within 5 mm; the Kalman filter's single Gaussian, fed fixes
    projected onto whichever leg is nearer, averages the two legs' arc lengths and ends more than
    20 mm off (measured 33 mm) while claiming a sigma 5 x smaller than its error (1.5 mm)."""
    line, start_b = _fold_back()
    rng = np.random.default_rng(3)
    sigma = 0.015
    t = 0.5 * np.arange(120)
    s = start_b + 0.006 + 1e-3 * t  # 1 mm per step along leg B
    obs = []
    for k in range(len(t)):
        fix = RfFix(_truth_point(s[k]) + rng.normal(0, sigma, 3), sigma**2 * np.eye(3))
        vis = None if k == 0 else VisualMotion(s[k] - s[k - 1] + rng.normal(0, 1e-4), 1e-4)
        obs.append(Observation(t[k], fix, vis))
    cfg = TrackerConfig(initial_s_m=None, particles=4000, seed=1, gate_probability=None)
    pf = particle_track(line, obs, cfg, keep_particles=True)
    kf = kalman_track(line, obs, cfg)

    on_b = pf.extra["particles_s_m"] >= start_b
    mass_b = np.sum(pf.extra["weights"] * on_b, axis=1)
    mass_a = np.sum(pf.extra["weights"] * (pf.extra["particles_s_m"] <= LEG), axis=1)
    assert np.max(np.minimum(mass_a, mass_b)[:20]) >= 0.2  # ambiguous at first: both legs alive at once
    assert mass_b[-1] > 0.95
    assert abs(pf.s_m[-1] - s[-1]) < 5e-3
    assert np.linalg.norm(pf.position_m[-1] - _truth_point(s[-1])) < 5e-3

    kf_err = abs(kf.s_m[-1] - s[-1])
    assert kf_err > 0.02
    assert kf_err > 5 * kf.s_sigma_m[-1]


def test_bad_observations_name_the_field():
    line = _tube()
    with pytest.raises(TrackingInputError) as e:
        kalman_track(line, [Observation(0.0), Observation(0.0)])
    assert e.value.field == "observations[1].t_s"
    with pytest.raises(TrackingInputError) as e:
        kalman_track(line, [Observation(0.0, RfFix(np.zeros(3), -np.eye(3)))])
    assert e.value.field == "observations[0].rf.covariance_m2"
    # singular, with an entry near the float limit (the fuzzer's case: NaN eigenvalues used to pass as definite)
    huge = np.zeros((3, 3))
    huge[2, 2], huge[2, 0] = 1.7976931348623157e308, 6e-41
    with pytest.raises(TrackingInputError) as e:
        kalman_track(line, [Observation(0.0, RfFix(np.zeros(3), huge))])
    assert e.value.field == "observations[0].rf.covariance_m2"
    with pytest.raises(TrackingInputError) as e:
        particle_track(line, [Observation(0.0, None, VisualMotion(1e-3, 0.0))])
    assert e.value.field == "observations[0].visual.advance_sigma_m"
    with pytest.raises(TrackingInputError) as e:
        TrackerConfig(particles=3)
    assert e.value.field == "config.particles"


# ----------------------------------------------------------------------- consistency tools, gates, 3-D point
def _nis_runs(declared_rf: float, declared_visual: float, tracker):
    """Per run the NIS of the used fixes and advances, the noise as _simulate draws it, declared to
    the filter with its covariance scaled by ``declared_*`` (1: as drawn)."""
    runs, steps, dt = 6, 100, 0.5
    q, qr = 1e-8, 20.0
    C = np.array([[1.0, 0.3, 0.0], [0.3, 2.0, -0.4], [0.0, -0.4, 1.5]]) * 1e-4
    sa, sr = 3e-4, 0.2
    rng = np.random.default_rng(11)
    cfg = TrackerConfig(accel_psd_m2_per_s3=q, roll_psd_deg2_per_s=qr, initial_s_m=2.0, initial_s_sigma_m=5e-3,
                        initial_v_sigma_m_per_s=3e-3, gate_probability=None, particles=1000)
    rf, vis = [], []
    for _ in range(runs):
        _, _, _, obs = _simulate(rng, steps, dt, q, qr, 2.0, 5e-3, 3e-3, C, sa, sr)
        obs = [Observation(o.t_s, RfFix(o.rf.position_m, o.rf.covariance_m2 * declared_rf),
                           None if o.visual is None else VisualMotion(
                               o.visual.advance_m, o.visual.advance_sigma_m * np.sqrt(declared_visual),
                               o.visual.roll_deg, o.visual.roll_sigma_deg)) for o in obs]
        track = tracker(_tube(4.0), obs, cfg)
        rf.append(track.extra["nis_rf"])
        vis.append(track.extra["nis_visual"])
    return rf, vis, track.extra["nis_rf_dof"]


@pytest.mark.parametrize("tracker", [kalman_track, particle_track])
def test_nis_is_inside_its_band_as_declared_and_leaves_it_when_a_covariance_is_ten_times_off(tracker):
    """Innovations of a consistent filter are white with covariance S: the average NIS of the RF fixes
    (chi-square(1) for the Kalman filter's projected fix, chi-square(3) for the particle filter's 3-D
    fix) and of the advances (chi-square(1)) over 6 runs x 100 steps lies in the two-sided 95 % band.
    R scaled by 10 (or by 1/10) moves the average out of it: by construction the fix's innovation
    variance is then mostly the wrong R."""
    from tracking import average_band

    rf, vis, dof = _nis_runs(1.0, 1.0, tracker)
    assert average_band(rf, dof, correlated=False).inside, average_band(rf, dof, correlated=False)
    assert average_band(vis, 1, correlated=False).inside, average_band(vis, 1, correlated=False)
    for scale in (10.0, 0.1):
        rf, _, dof = _nis_runs(scale, 1.0, tracker)
        assert not average_band(rf, dof, correlated=False).inside, (scale, average_band(rf, dof, correlated=False))
        _, vis, _ = _nis_runs(1.0, scale, tracker)
        assert not average_band(vis, 1, correlated=False).inside, (scale, average_band(vis, 1, correlated=False))


def test_integrated_autocorrelation_of_white_and_ar1_series():
    """Oracles: 1 for white noise; (1 + phi) / (1 - phi) for an AR(1) process x_k = phi x_{k-1} + e_k
    (9 at phi = 0.8). 20 000 samples: the estimator's relative error is ~sqrt(2 (2M + 1) / n) ~ 15 %."""
    from tracking import integrated_autocorrelation

    rng = np.random.default_rng(5)
    assert integrated_autocorrelation(rng.standard_normal(20_000)) == pytest.approx(1.0, abs=0.15)
    e = rng.standard_normal(20_000)
    x = np.empty_like(e)
    x[0] = e[0]
    for k in range(1, len(e)):
        x[k] = 0.8 * x[k - 1] + e[k]
    assert integrated_autocorrelation(x) == pytest.approx(9.0, rel=0.25)


def test_rf_fixes_are_used_once_per_spacing_along_the_tract():
    """rf_min_spacing_m = 9.5 mm on a capsule advancing 1 mm per step with exact measurements: a fix is
    used every 10 steps (the first, then each once the estimate has moved 9.5 mm), none while it stops."""
    t = 0.5 * np.arange(80)
    s = 0.1 + 1e-3 * np.minimum(np.arange(80), 50)  # moves 50 mm, then stops
    obs = [Observation(t[k], RfFix(A + s[k] * U, 1e-10 * np.eye(3)),
                       None if k == 0 else VisualMotion(s[k] - s[k - 1], 1e-6)) for k in range(80)]
    cfg = TrackerConfig(initial_s_m=0.1, initial_s_sigma_m=1e-3, rf_min_spacing_m=0.0095, gate_probability=None)
    for tracker in (kalman_track, particle_track):
        used = np.flatnonzero(tracker(_tube(), obs, cfg).rf_used)
        assert used.tolist() == [0, 10, 20, 30, 40, 50], (tracker.__name__, used)


def test_a_gate_cannot_starve_a_filter_that_lost_the_capsule():
    """A Kalman filter told the capsule is at s = 0.30 m +- 1 mm when it is at 0.10 m: every fix is
    200 sigma off and the 0.9999 gate refuses it. With the default max_consecutive_gated (5) the sixth
    fix is used with var(s) widened to explain it, and the filter is on the capsule within 1 mm after
    it; with the guard off (10 000 refusals allowed) it never recovers (the test can fail)."""
    t = 0.5 * np.arange(40)
    s = 0.10 + 1e-3 * np.arange(40)
    obs = [Observation(t[k], RfFix(A + s[k] * U, 1e-6 * np.eye(3)),
                       None if k == 0 else VisualMotion(s[k] - s[k - 1], 1e-4)) for k in range(40)]
    lost = TrackerConfig(initial_s_m=0.30, initial_s_sigma_m=1e-3, initial_v_sigma_m_per_s=1e-4)
    track = kalman_track(_tube(), obs, lost)
    assert np.flatnonzero(track.rf_used)[0] == 5
    assert np.max(np.abs(track.s_m[6:] - s[6:])) < 1e-3
    starved = kalman_track(_tube(), obs, TrackerConfig(**{**lost.__dict__, "max_consecutive_gated": 10_000}))
    assert not starved.rf_used.any() and np.min(np.abs(starved.s_m - s)) > 0.1


def test_kalman_3d_point_is_the_expected_point_across_a_junction():
    """Two pieces 40 mm apart (a junction: c(s) jumps). With s_hat on the junction and sigma 2 mm the
    reported point is E[c(S)], here by a 200 001-point quadrature of the normal density written in the
    test (tolerance 1e-5 m: the trapezoid's own error here is ~1e-8 m, the filter's rule splits the
    integral at the junction), about halfway between the two sides; c(s_hat) would be 20 mm from it.
    Off the junction, on a straight piece, it is c(s_hat) and var(s) t t^T."""
    from scipy.stats import norm

    a = [[x, 0.0, 0.0] for x in np.linspace(0.0, 0.1, 11)]
    b = [[0.1, 0.04, 0.0], [0.2, 0.04, 0.0]]
    line = Centreline([("one", a), ("two", b)])
    j = float(line.junctions_s_m[0])
    obs = [Observation(0.0, RfFix(np.array([0.1, 0.02, 0.0]), 1e-12 * np.eye(3)))]
    # the fix projects onto one side; what matters is the reported point for the filter's own s and sigma
    track = kalman_track(line, [Observation(0.0)], TrackerConfig(initial_s_m=j, initial_s_sigma_m=2e-3))
    grid = np.linspace(j - 0.02, j + 0.02, 200_001)
    w = norm.pdf(grid, j, 2e-3)
    w /= w.sum()
    pts = np.where((grid <= j)[:, None], np.stack([grid, 0 * grid, 0 * grid], 1),
                   np.stack([0.1 + (grid - j), 0.04 + 0 * grid, 0 * grid], 1))
    expected = w @ pts
    assert np.linalg.norm(track.position_m[0] - expected) < 1e-5, (track.position_m[0], expected)
    assert abs(expected[1] - 0.02) < 2e-3
    assert np.linalg.norm(line.point_m(j) - expected) > 0.015
    assert obs  # (the fix is not used: a lone prior)
    from tracking.kalman import expected_point

    mean, cov = expected_point(line, 0.05, 4e-6)
    assert np.allclose(mean, [0.05, 0.0, 0.0], atol=1e-9)
    assert np.allclose(cov, np.diag([4e-6, 0.0, 0.0]), atol=1e-9 * 4e-6 + 1e-14)


def test_the_smooth_bias_transition_is_the_matern_process():
    """bias_transition against an oracle computed here: F = expm(A d) of the Matern-3/2 state-space
    form, A = [[0, 1], [-lam^2, -2 lam]], lam = 1/ell (scipy's expm), and Q = int_0^d expm(A u) L q L^T
    expm(A u)^T du with L = [0, 1]^T and the white-noise density q = 4 lam^3 that makes the stationary
    variance 1 (midpoint rule, 400 steps: relative error ~1e-6); the stationary autocorrelation
    F[0, 0] + F[0, 1] * 0 (the state starting at (1, 0)) is (1 + d/ell) exp(-d/ell)."""
    from scipy.linalg import expm

    from tracking.kalman import bias_transition

    ell, d = 3.2e-3, 1.7e-3
    lam = 1.0 / ell
    A = np.array([[0.0, 1.0], [-lam * lam, -2.0 * lam]])
    F, Q = bias_transition(d, ell)
    np.testing.assert_allclose(F, expm(A * d), rtol=1e-12, atol=1e-12)
    u = (np.arange(400) + 0.5) * d / 400
    Lq = np.array([[0.0], [1.0]])
    Q_oracle = sum(expm(A * x) @ (Lq @ Lq.T) @ expm(A * x).T for x in u) * 4 * lam**3 * d / 400
    np.testing.assert_allclose(Q, Q_oracle, rtol=1e-4, atol=1e-7 * np.abs(Q_oracle).max())
    assert F[0, 0] == pytest.approx((1 + d / ell) * np.exp(-d / ell), rel=1e-12)
    F0, Q0 = bias_transition(0.0, ell)
    np.testing.assert_allclose(F0, np.eye(2), atol=1e-15) and np.testing.assert_allclose(Q0, 0.0, atol=1e-15)


def test_a_stopped_capsules_repeated_fixes_do_not_shrink_the_uncertainty_below_the_bias():
    """A capsule at rest, 40 fixes all offset by the same 8 mm bias (the body's, at that spot), declared
    with a bias covariance of (8 mm)^2 per axis: with the bias model (rf_correlation_length_m) the
    filter's s sigma stays at the bias's (~8 mm, here >= 6 mm) and its error is inside 2 sigma; treated
    as white noise (the old way) the 40 fixes shrink sigma to ~1.3 mm while the error stays 8 mm
    (6 sigma): the overconfidence the bias model removes."""
    s_true = 0.2
    biased = A + s_true * U + 0.008 * U  # the bias along the tract
    obs = [Observation(0.5 * k, RfFix(biased, 1e-10 * np.eye(3), 6.4e-5 * np.eye(3))) for k in range(40)]
    base = dict(initial_s_m=0.2, initial_s_sigma_m=0.02, initial_v_sigma_m_per_s=1e-5, gate_probability=None,
                accel_psd_m2_per_s3=1e-12)
    smooth = kalman_track(_tube(), obs, TrackerConfig(**base, rf_correlation_length_m=3e-3))
    white = kalman_track(_tube(), obs, TrackerConfig(**base))
    assert smooth.s_sigma_m[-1] >= 6e-3 and abs(smooth.s_m[-1] - s_true) <= 2 * smooth.s_sigma_m[-1]
    assert white.s_sigma_m[-1] < 2e-3 and abs(white.s_m[-1] - s_true) > 4 * white.s_sigma_m[-1]
