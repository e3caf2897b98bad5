"""Eikonal travel-time fields against closed forms written here: a homogeneous medium
(T = n |x - s| / c) and the head wave of a planar fast layer; the model-based fix on them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.errors import EstimatorInputError
from estimators.localization import (
    TravelTimeFields,
    cached_travel_time_field,
    model_based_fix,
    nonlinear_fix,
    travel_time_field,
)
from estimators.localization.traveltime import cache_info, clear_cache

C = 299_792_458.0
H = 0.004
N_MUSCLE = math.sqrt(27.9)


def homogeneous(n=N_MUSCLE, cells=(60, 60, 60)):
    return np.full(cells, n), np.zeros(3)


def centres(shape, origin=None, h=H):
    origin = np.zeros(3) if origin is None else origin
    axes = [origin[i] + (np.arange(shape[i]) + 0.5) * h for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def test_homogeneous_field_is_n_r_over_c_within_the_stated_error():
    index, origin = homogeneous()
    s = np.array([0.1213, 0.1187, 0.1202])
    f = travel_time_field(index, origin, H, s)
    r = np.linalg.norm(centres(index.shape) - s, axis=-1)
    exact = N_MUSCLE * r / C
    err = f.time_s - exact
    assert f.discretisation_error_s == pytest.approx(N_MUSCLE * H / C)  # the stated bound
    assert np.max(np.abs(err)) <= f.discretisation_error_s
    # second order beyond the source: at most 0.4 n h / c at 50 mm and more (module docstring)
    assert np.max(np.abs(err[r > 0.05])) <= 0.4 * N_MUSCLE * H / C
    # exact inside the source ball
    inside = r <= f.source_radius_m
    np.testing.assert_allclose(f.time_s[inside], exact[inside], rtol=1e-12)
    assert f.source_index == pytest.approx(N_MUSCLE, rel=1e-12)


def test_head_wave_along_a_fast_layer():
    # slow half-space n1 over fast n2 (interface on a cell boundary, so the grid holds it exactly);
    # source and receiver in the slow medium at heights a, b above it, offset X: the first
    # arrival is min(direct, head wave) with the head wave n1 (a + b) cos(tc) + n2 X (sin tc = n2 / n1)
    n1, n2 = 7.9, 3.45
    shape = (100, 20, 40)
    index = np.full(shape, n1)
    index[:, :, :10] = n2  # z < 0.04 m is the fast layer
    s = np.array([0.04, 0.0401, 0.0602])
    f = travel_time_field(index, np.zeros(3), H, s)
    x = centres(shape)
    a = s[2] - 0.04
    b = x[..., 2] - 0.04
    offset = np.hypot(x[..., 0] - s[0], x[..., 1] - s[1])
    tc = math.asin(n2 / n1)
    direct = n1 * np.hypot(offset, x[..., 2] - s[2])
    head = np.where(offset > (a + b) * math.tan(tc), n1 * (a + b) * math.cos(tc) + n2 * offset, np.inf)
    exact = np.minimum(direct, head) / C
    above = (b > 0.002) & (offset > 0.02)
    assert np.any(head[above] < direct[above])  # the head wave arrives first somewhere
    assert np.max(np.abs(f.time_s[above] - exact[above])) <= f.discretisation_error_s


def test_cells_outside_the_domain_are_not_crossed():
    # a wall of NaN cells with one gap: behind the wall, T follows the detour through the gap
    n = N_MUSCLE
    index = np.full((60, 20, 60), n)
    index[:, :, 30] = np.nan
    index[28:32, :, 30] = n  # gap around x = 0.12
    s = np.array([0.0401, 0.0402, 0.0603])
    f = travel_time_field(index, np.zeros(3), H, s)
    target = np.array([0.0402, 0.0402, 0.1802])  # behind the wall, straight above the source
    cell = tuple(np.floor(target / H).astype(int))
    gap = np.array([0.112, 0.0402, 0.122])  # nearest gap edge in the wall's plane
    detour = (np.linalg.norm(gap - s) + np.linalg.norm(target - gap)) * n / C
    assert f.time_s[cell] >= detour - f.discretisation_error_s
    assert f.time_s[cell] > np.linalg.norm(target - s) * n / C + 5 * f.discretisation_error_s
    assert not f.domain[:, :, 30].any() or f.domain[28:32, :, 30].all()


def test_model_based_fix_equals_the_constant_velocity_fix_in_a_homogeneous_medium():
    # T_i = n |x - s_i| / c: both fixes solve the same problem, the model-based one up to the
    # grid's error; the range equivalent of the stated error is n h / c * c / n = h, so the
    # positions agree within PDOP * h (here they agree far better, see the second assertion)
    index, origin = homogeneous(cells=(64, 64, 64))
    sensors = np.array([[0.2, 0.128, 0.13], [0.05, 0.13, 0.125], [0.13, 0.22, 0.14], [0.128, 0.05, 0.12],
                        [0.17, 0.17, 0.21], [0.09, 0.09, 0.2], [0.09, 0.17, 0.05], [0.17, 0.09, 0.06]])
    fields = TravelTimeFields([travel_time_field(index, origin, H, s) for s in sensors])
    for x in (np.array([0.121, 0.135, 0.128]), np.array([0.1, 0.16, 0.1])):
        r = np.linalg.norm(sensors - x, axis=1)
        cv = nonlinear_fix(sensors, r, 1e-5)
        mb = model_based_fix(fields, r * N_MUSCLE / C, 1e-5 * N_MUSCLE / C)
        assert np.linalg.norm(mb.position_m - cv.position_m) <= mb.pdop * H
        assert np.linalg.norm(mb.position_m - x) <= 0.3 * H
        # the bound from travel-time gradients equals the unit-vector bound (|grad T| = n / c)
        np.testing.assert_allclose(mb.bound.sigma_m, cv.bound.sigma_m, rtol=0.05)


def test_cache_returns_the_same_field_and_is_bounded():
    clear_cache()
    index, origin = homogeneous(cells=(20, 20, 20))
    s = np.array([0.041, 0.042, 0.043])
    a = cached_travel_time_field(index, origin, H, s)
    assert cached_travel_time_field(index.copy(), origin, H, s) is a  # keyed by content
    b = cached_travel_time_field(index, origin, H, s + 0.004)
    assert b is not a
    assert cache_info()["fields"] == 2 and cache_info()["bytes"] <= cache_info()["max_bytes"]


@pytest.mark.parametrize("kwargs, field", [
    ({"sensor_position_m": [1.0, 0.1, 0.1]}, "sensor_position_m"),
    ({"sensor_position_m": [0.1, float("nan"), 0.1]}, "sensor_position_m"),
    ({"index": np.full((20, 20, 20), 0.5)}, "index"),
    ({"index": np.full((20, 20, 20), np.nan)}, "index"),
    ({"index": np.ones((20, 20))}, "index"),
    ({"spacing_m": -1.0}, "spacing_m"),
    ({"order": 3}, "order"),
])
def test_bad_field_input_names_the_field(kwargs, field):
    args = {"index": np.ones((20, 20, 20)), "origin_m": np.zeros(3), "spacing_m": H,
            "sensor_position_m": [0.04, 0.04, 0.04]}
    args.update(kwargs)
    with pytest.raises(EstimatorInputError) as exc:
        travel_time_field(**args)
    assert exc.value.field == field


def test_a_sensor_outside_the_domain_is_refused():
    index = np.full((20, 20, 20), np.nan)
    index[10:, :, :] = 7.0
    with pytest.raises(EstimatorInputError) as exc:
        travel_time_field(index, np.zeros(3), H, [0.0101, 0.04, 0.04])
    assert exc.value.field == "sensor_position_m"
