"""Group index and group delay (docs/science.md (S22)-(S23)) against oracles that share no
code with the implementation: central finite differences of the complex index, and the
phase slope of a traced path's band gains."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import raytrace as rt
from raytrace.physics import em, tissues

C = 299_792_458.0


@pytest.mark.parametrize("tissue", ["muscle", "fat_average_infiltrated", "small_intestine", "skin_dry", "blood"])
@pytest.mark.parametrize("frequency_hz", [402e6, 2.45e9, 1e3])
def test_group_index_equals_a_finite_difference_of_the_phase_index(tissue, frequency_hz):
    # n_g = d(w Re n)/dw. Central difference of w Re n(w) (numpy's sqrt of the Cole-Cole eps,
    # not em.refractive_index) over +-1e-4 relative: truncation error ~ (1e-4)^2 relative,
    # round-off ~ 1e-16 / 1e-4; 1e-6 relative covers both with margin.
    h = 1e-4 * frequency_hz
    def k_real(f):
        n = np.sqrt(tissues.complex_relative_permittivity(tissue, f))
        return 2 * np.pi * f * abs(n.real)
    fd = (k_real(frequency_hz + h) - k_real(frequency_hz - h)) / (2 * np.pi * 2 * h)
    eps = tissues.complex_relative_permittivity(tissue, frequency_hz)
    deps = tissues.complex_relative_permittivity_derivative(tissue, frequency_hz)
    assert em.group_index(eps, deps, frequency_hz) == pytest.approx(fd, rel=1e-6)


def test_group_index_of_an_explicit_conductor_and_of_a_lossless_medium():
    # constant eps' = 50, sigma = 1 S/m: d eps/dw = j sigma / (w^2 eps0) (closed form); a lossless
    # constant medium is dispersionless: n_g = n.
    f = 402e6
    h = 1e-4 * f
    m = rt.Material(relative_permittivity=50.0, conductivity_s_per_m=1.0)
    def k_real(ff):
        return 2 * np.pi * ff * np.sqrt(50.0 - 1j * 1.0 / (2 * np.pi * ff * 8.8541878128e-12)).real
    fd = (k_real(f + h) - k_real(f - h)) / (2 * np.pi * 2 * h)
    assert float(m.group_index(f)) == pytest.approx(fd, rel=1e-6)
    assert float(rt.Material(relative_permittivity=27.9, conductivity_s_per_m=0.0).group_index(f)) == pytest.approx(
        np.sqrt(27.9), rel=1e-15)


def test_a_single_dispersive_path_has_the_group_delay_of_its_band_phase_slope():
    # The homogeneous muscle sphere, transmitter at the centre, 'inner' receiver 50 mm away: one
    # direct path with no interface, so its band gains' phase is -w Re n(w) L / c plus a
    # constant, and -d(phase)/dw at the carrier is the group delay L n_g / c. A central
    # difference over +-100 kHz errs by ~(1e5/4e8)^2 relative of the second derivative's
    # share: far below the 0.1 ps tolerance (1e-4 of the 1.2 ns delay).
    base = rt.get_scenario("homogeneous-sphere").spec
    # near field off: its factor 1 + u + u^2 has a phase slope of its own (docs/validation.md)
    spec = dataclasses.replace(base, band=rt.Band(frequencies_hz=[401.9e6, 402.0e6, 402.1e6]), near_field=False)
    path = rt.trace_channel(spec).profiles[0].paths[0]
    assert path.interactions == ()
    phase = np.unwrap(np.angle(path.band_gains))
    slope_s = -(phase[2] - phase[0]) / (2 * np.pi * 0.2e6)
    assert abs(path.group_delay_s - slope_s) < 0.1e-12
    # and in muscle at 402 MHz the envelope is ~10 % faster than the carrier's phase
    assert 0.85 < path.group_delay_s / path.delay_s < 0.95


def test_group_delay_of_a_torso_path_is_the_sum_over_its_segments():
    # sum L_i n_g,i / c over the segments the tracer reports, with n_g from the tissue model
    spec = rt.ChannelSpec(rt.Antenna(site="small_intestine_1"), [rt.Antenna(site="belt_anterior")], rays=20_000)
    torso = rt.get_phantom("torso")
    path = rt.trace_channel(spec).profiles[0].paths[0]
    total = 0.0
    for seg in path.segments:
        if seg.medium == "air":
            total += seg.length_m
            continue
        material = torso.organs[torso.organ_index(seg.medium)].material
        eps = tissues.complex_relative_permittivity(material.tissue, 402e6)
        deps = tissues.complex_relative_permittivity_derivative(material.tissue, 402e6)
        total += seg.length_m * float(em.group_index(eps, deps, 402e6))
    assert path.group_delay_s == pytest.approx(total / C, rel=1e-12)
