"""The seeded journey against closed forms: the two-state chain's stationary stop fraction, the
peristaltic sinusoid, the roll random walk's spread, determinism, and named input errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from raytrace.body.centreline import Centreline
from tracking import JourneySpec, TrackingInputError, simulate_journey

LINE = Centreline([("gut", [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])])


def test_same_seed_same_journey_other_seed_other_journey():
    a = simulate_journey(LINE, JourneySpec(steps=300, seed=4))
    b = simulate_journey(LINE, JourneySpec(steps=300, seed=4))
    c = simulate_journey(LINE, JourneySpec(steps=300, seed=5))
    assert np.array_equal(a.s_m, b.s_m) and np.array_equal(a.roll_deg, b.roll_deg)
    assert not np.array_equal(a.s_m, c.s_m)


def test_positions_are_the_lines_points_and_organ():
    j = simulate_journey(LINE, JourneySpec(steps=200, start_m=0.9, mean_speed_m_per_s=2e-3))
    s = j.s_m
    want = np.where(s[:, None] <= 1.0, np.stack([s, 0 * s, 0 * s], 1), np.stack([0 * s + 1, s - 1, 0 * s], 1))
    assert np.allclose(j.position_m, want, atol=1e-12)
    assert set(j.organ) == {"gut"}


def test_stops_take_the_stationary_fraction_of_the_two_state_chain():
    """Moving -> stopped with p = dt/20 s per step, back with q = dt/6 s: stationary stopped fraction
    p / (p + q) = 6 / 26 = 0.231. Over 5000 steps of 0.5 s (~190 stop/go cycles) the fraction's sd is
    about 0.02; tolerance 0.06 (3 sd). While stopped with no peristalsis the capsule does not move."""
    spec = JourneySpec(steps=5000, seed=1, start_m=0.0, mean_speed_m_per_s=1e-4, peristalsis_amplitude_m=0.0)
    j = simulate_journey(LINE, spec)
    assert abs((~j.moving).mean() - 6 / 26) < 0.06
    stopped_steps = ~j.moving[:-1]
    assert np.all(np.diff(j.s_m)[stopped_steps] == 0.0)
    assert np.all(np.diff(j.s_m)[~stopped_steps] > 0.0)


def test_peristalsis_alone_is_the_sinusoid_back_and_forth():
    """No propulsion: s(t) - s(0) = A (sin(2 pi t / T + phi) - sin phi), so its range is 2 A and it
    runs backwards half the time (within one step per period at the turning points); a least-squares
    sinusoid of period T fits it to 1e-12 m with amplitude A."""
    A, T = 2e-3, 8.0
    j = simulate_journey(LINE, JourneySpec(steps=800, start_m=0.5, mean_speed_m_per_s=0.0,
                                           peristalsis_amplitude_m=A, peristalsis_period_s=T))
    # sampled every T/16: a peak is missed by at most 1 - cos(pi/16) = 1.9 %
    assert j.s_m.max() - j.s_m.min() == pytest.approx(2 * A, rel=0.02)
    back = np.mean(np.diff(j.s_m) < 0)
    assert abs(back - 0.5) < 1 / 16
    resid = j.s_m - 0.5
    X = np.stack([np.sin(2 * np.pi * j.t_s / T), np.cos(2 * np.pi * j.t_s / T), np.ones_like(j.t_s)], 1)
    coef, *_ = np.linalg.lstsq(X, resid, rcond=None)
    assert np.max(np.abs(X @ coef - resid)) < 1e-12 and math.hypot(coef[0], coef[1]) == pytest.approx(A, rel=1e-9)


def test_roll_is_a_random_walk_of_the_stated_step():
    """Increments N(0, 3 deg): over 4999 increments the sample sd's relative sampling error is
    sqrt(1 / (2 n)) = 1 %; tolerance 4 % (4 sd)."""
    j = simulate_journey(LINE, JourneySpec(steps=5000, seed=2, mean_speed_m_per_s=0.0))
    assert np.std(np.diff(j.roll_deg)) == pytest.approx(3.0, rel=0.04)
    assert j.roll_deg[0] == 0.0


@pytest.mark.parametrize("kwargs, field", [
    ({"steps": 1}, "journey.steps"), ({"dt_s": 0.0}, "journey.dt_s"), ({"seed": -1}, "journey.seed"),
    ({"mean_speed_m_per_s": float("nan")}, "journey.mean_speed_m_per_s"), ({"start_m": -0.1}, "journey.start_m"),
])
def test_bad_spec_names_the_field(kwargs, field):
    with pytest.raises(TrackingInputError) as e:
        JourneySpec(**kwargs)
    assert e.value.field == field


def test_unknown_field_and_start_beyond_the_line():
    with pytest.raises(TrackingInputError) as e:
        JourneySpec.from_dict({"stepz": 3})
    assert e.value.field == "journey.stepz"
    with pytest.raises(TrackingInputError) as e:
        simulate_journey(LINE, JourneySpec(start_m=5.0))
    assert e.value.field == "journey.start_m"
