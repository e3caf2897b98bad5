"""Tests of raytrace.physics.em against oracles that share no code with it.

Oracles: closed forms written out here (normal incidence, Brewster, critical
angle, the real-arithmetic lossy-dielectric propagation constants), energy
conservation, Maxwell's tangential-field continuity built from the returned
basis vectors, and the independent ``tmm`` package (Byrnes) for single lossy
interfaces and a lossy three-layer stack whose response we sum ourselves
(Airy formula) from em.fresnel.

Tolerances: where the oracle is an exact formula evaluated in double precision
we use 1e-12..1e-10 (a few hundred ulp: complex sqrt and divisions); where the
oracle is an approximation or a rounded published number the tolerance is
derived from its truncation/rounding and said so at the assertion.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import tmm

from raytrace.errors import FrequencyOutOfRangeError, InputError, InvalidGeometryError
from raytrace.physics import em

EXACT = 1e-12  # relative/absolute tolerance for exact closed forms in double precision


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _tan(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Tangential part of (complex) vectors v with respect to unit normals n."""
    return v - np.sum(v * n, axis=-1, keepdims=True) * n


# Lossy indices used throughout (our convention, Im n < 0): muscle-like and
# fat-like at 402 MHz, computed here from eps = eps' - j sigma/(w eps0) by hand.
_W402 = 2 * math.pi * 402e6
_EPS0 = 8.8541878128e-12
N_MUSCLE = complex(np.sqrt(57.1 - 1j * 0.797 / (_W402 * _EPS0)))
N_FAT = complex(np.sqrt(11.6 - 1j * 0.0808 / (_W402 * _EPS0)))


# --------------------------------------------------------------------------- constants


def test_constants_are_codata():
    assert em.C0 == 299_792_458.0
    assert em.EPS0 == pytest.approx(8.8541878128e-12, rel=1e-10)
    assert em.MU0 == pytest.approx(1.25663706212e-6, rel=1e-10)
    # c0^2 mu0 eps0 = 1 holds to the CODATA 2018 uncertainty (~1.5e-10).
    assert em.C0**2 * em.MU0 * em.EPS0 == pytest.approx(1.0, abs=1e-9)


# --------------------------------------------------------------------------- media


def test_complex_permittivity_sign_and_value():
    eps = em.complex_relative_permittivity(50.0, 1.0, 1e9)
    assert eps.real == 50.0
    assert eps.imag == pytest.approx(-1.0 / (2 * math.pi * 1e9 * _EPS0), rel=EXACT)


def test_refractive_index_branch():
    eps = np.array([4.0, 57.1 - 35.6j, 1.0 - 1e-9j, 1e-3 - 100j])
    n = em.refractive_index(eps)
    assert np.all(n.real > 0) and np.all(n.imag <= 0)
    np.testing.assert_allclose(n**2, eps, rtol=EXACT)


def test_propagation_constants_match_real_closed_form():
    """alpha, beta of a lossy dielectric, written without complex arithmetic:
    beta/alpha = w sqrt(mu0 eps0 eps'/2) sqrt(sqrt(1 + tan^2) +/- 1)."""
    rng = np.random.default_rng(1)
    eps_r = rng.uniform(1.0, 80.0, 50)
    sigma = rng.uniform(0.0, 5.0, 50)
    f = rng.uniform(1e6, 1e10, 50)
    w = 2 * np.pi * f
    tan_d = sigma / (w * _EPS0 * eps_r)
    root = np.sqrt(1 + tan_d**2)
    scale = w * np.sqrt(eps_r / 2) / 299_792_458.0
    beta = scale * np.sqrt(root + 1)
    alpha = scale * np.sqrt(root - 1)
    eps = em.complex_relative_permittivity(eps_r, sigma, f)
    k = em.wavenumber(eps, f)
    np.testing.assert_allclose(k.real, beta, rtol=1e-12)
    # alpha via sqrt(root - 1) loses digits when tan_d is tiny; 1e-9 covers it.
    np.testing.assert_allclose(em.attenuation_np_per_m(eps, f), alpha, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(em.attenuation_db_per_m(eps, f), 20 * np.log10(np.e) * alpha, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(em.phase_velocity_m_per_s(eps, f), w / beta, rtol=1e-12)
    np.testing.assert_allclose(em.wavelength_m(eps, f), 2 * np.pi / beta, rtol=1e-12)


def test_lossless_medium_wavelength_and_velocity():
    f = 402e6
    assert em.wavelength_m(27.9, f) == pytest.approx(299_792_458.0 / f / math.sqrt(27.9), rel=EXACT)
    # docs/science.md: v = c / sqrt(27.9) = 0.568e8 m/s (3 digits: tolerance 1e-3). Its
    # "141.3 mm" wavelength (thesis Sec. 4: 141.28 mm) uses c = 3e8 m/s; with the
    # exact c0 it is 141.19 mm, which is what we check (4 digits).
    assert em.phase_velocity_m_per_s(27.9, f) == pytest.approx(0.568e8, rel=1e-3)
    assert em.wavelength_m(27.9, f) == pytest.approx(0.1412, rel=5e-4)
    assert em.attenuation_np_per_m(27.9, f) == 0.0


def test_sea_water_good_conductor_attenuation():
    """Sea water (eps' 81, sigma 4 S/m) at 1 MHz is a good conductor (tan d ~ 888):
    alpha ~ sqrt(pi f mu0 sigma) = 3.974 Np/m (skin depth 0.25 m). The
    approximation's relative error is about 1/(2 tan d) = 6e-4; tolerance 2e-3."""
    f, sigma = 1e6, 4.0
    eps = em.complex_relative_permittivity(81.0, sigma, f)
    alpha_good = math.sqrt(math.pi * f * 4e-7 * math.pi * sigma)
    assert em.attenuation_np_per_m(eps, f) == pytest.approx(alpha_good, rel=2e-3)
    assert alpha_good == pytest.approx(3.974, rel=1e-3)


def test_small_intestine_phase_velocity_below_lossless_value():
    """docs/tissues.md: small intestine at 402 MHz has v = w / Re k = 0.322e8 m/s while
    c / sqrt(eps') = 0.369e8 m/s (values rounded to 3 digits: tolerance 0.3 %)."""
    from raytrace.physics import tissues

    d = tissues.dielectric("small_intestine", 402e6)
    eps = em.complex_relative_permittivity(d.relative_permittivity, d.conductivity_s_per_m, 402e6)
    v = em.phase_velocity_m_per_s(eps, 402e6)
    assert v == pytest.approx(0.322e8, rel=3e-3)
    assert 299_792_458.0 / math.sqrt(d.relative_permittivity) == pytest.approx(0.369e8, rel=3e-3)
    assert v < 299_792_458.0 / math.sqrt(d.relative_permittivity)


def test_propagation_factor():
    """|exp(-jkL)| = exp(-alpha L) and arg = -beta L, with alpha, beta from the real
    closed form above (tolerance 1e-12: one exp of a double)."""
    eps_r, sigma, f = 57.1, 0.797, 402e6
    w = 2 * np.pi * f
    tan_d = sigma / (w * _EPS0 * eps_r)
    scale = w * np.sqrt(eps_r / 2) / 299_792_458.0
    beta = scale * np.sqrt(np.sqrt(1 + tan_d**2) + 1)
    alpha = scale * np.sqrt(np.sqrt(1 + tan_d**2) - 1)
    length = np.array([0.0, 0.01, 0.05, 0.1])
    eps = em.complex_relative_permittivity(eps_r, sigma, f)
    a = em.propagation_factor(eps, f, length)
    np.testing.assert_allclose(np.abs(a), np.exp(-alpha * length), rtol=1e-12)
    np.testing.assert_allclose(np.angle(a * np.exp(1j * beta * length)), 0.0, atol=1e-9)
    with pytest.raises(InputError) as info:
        em.propagation_factor(eps, f, -0.1)
    assert info.value.field == "length_m"


def test_broadcasting_over_media_and_frequencies():
    eps = np.array([10.0 - 1j, 50.0 - 20j, 4.0])[:, None]
    f = np.array([1e8, 4e8, 2.45e9, 5e9])[None, :]
    k = em.wavenumber(eps, f)
    assert k.shape == (3, 4)
    assert k[1, 2] == pytest.approx(em.wavenumber(50.0 - 20j, 2.45e9), rel=EXACT)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_frequency_is_typed_error(bad):
    with pytest.raises(FrequencyOutOfRangeError) as info:
        em.wavenumber(4.0, bad)
    assert info.value.field == "frequency_hz"


def test_gain_medium_is_rejected_with_hint():
    """A positive imaginary part is the exp(-i w t) convention (e.g. tmm): refuse it."""
    with pytest.raises(InputError) as info:
        em.refractive_index(50.0 + 10j)
    assert info.value.field == "eps"
    assert "conj" in info.value.reason
    with pytest.raises(InputError):
        em.fresnel(1.0, np.conj(N_MUSCLE), 0.5)


def test_negative_conductivity_rejected():
    with pytest.raises(InputError) as info:
        em.complex_relative_permittivity(10.0, -0.1, 1e9)
    assert info.value.field == "conductivity_s_per_m"


# --------------------------------------------------------------------------- Snell


def test_critical_angle_and_snell_angle():
    assert em.critical_angle(1.5, 1.0) == pytest.approx(math.asin(1 / 1.5), rel=EXACT)
    assert np.isnan(em.critical_angle(1.0, 1.5))
    theta = np.deg2rad([0.0, 20.0, 40.0, 41.0, 60.0])
    t = em.snell_angle(1.5, 1.0, theta)
    ok = 1.5 * np.sin(theta) <= 1.0
    np.testing.assert_allclose(np.sin(t[ok]), 1.5 * np.sin(theta[ok]), rtol=EXACT)
    assert np.all(np.isnan(t[~ok]))
    assert list(em.is_total_internal_reflection(1.5, 1.0, np.cos(theta))) == list(~ok)
    # real parts are used for the geometric test
    assert bool(em.is_total_internal_reflection(N_MUSCLE, N_FAT, math.cos(math.radians(70))))


def test_cos_transmitted_branches():
    ci = np.cos(np.deg2rad([0.0, 30.0, 60.0, 85.0]))
    # lossless, no TIR: real positive root
    ct = em.cos_transmitted(1.0, 1.5, ci)
    np.testing.assert_allclose(ct.imag, 0.0, atol=EXACT)
    assert np.all(ct.real > 0)
    # lossless TIR: evanescent root, Im(n2 ct) < 0 so exp(-j k0 n2 ct z) decays
    ct = em.cos_transmitted(1.5, 1.0, np.cos(np.deg2rad([50.0, 70.0])))
    np.testing.assert_allclose(ct.real, 0.0, atol=EXACT)
    assert np.all(ct.imag < 0)
    # lossy: Im(n2 ct) < 0 and Snell holds
    ct = em.cos_transmitted(N_FAT, N_MUSCLE, ci)
    assert np.all((N_MUSCLE * ct).imag < 0)
    np.testing.assert_allclose(N_FAT**2 * (1 - ci**2), N_MUSCLE**2 * (1 - ct**2), rtol=1e-12)


# --------------------------------------------------------------------------- Fresnel


def test_normal_incidence_closed_forms():
    n1 = np.array([1.0, 1.5, N_FAT, 1.0])
    n2 = np.array([1.5, 1.0, N_MUSCLE, N_MUSCLE])
    f = em.fresnel(n1, n2, 1.0)
    np.testing.assert_allclose(f.r_te, (n1 - n2) / (n1 + n2), rtol=EXACT, atol=EXACT)
    np.testing.assert_allclose(f.r_tm, (n2 - n1) / (n1 + n2), rtol=EXACT, atol=EXACT)
    np.testing.assert_allclose(f.t_te, 2 * n1 / (n1 + n2), rtol=EXACT)
    np.testing.assert_allclose(f.t_tm, 2 * n1 / (n1 + n2), rtol=EXACT)
    np.testing.assert_allclose(f.cos_t, 1.0, rtol=EXACT)


def test_identical_media_transmit_everything():
    f = em.fresnel(N_MUSCLE, N_MUSCLE, np.array([1.0, 0.5, 0.0]))
    np.testing.assert_allclose(f.r_te, 0.0, atol=EXACT)
    np.testing.assert_allclose(f.r_tm, 0.0, atol=EXACT)
    np.testing.assert_allclose(f.t_te, 1.0, atol=EXACT)
    np.testing.assert_allclose(f.t_tm, 1.0, atol=EXACT)


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.5, 1.0), (1.0, 7.55), (7.55, 3.4)])
def test_brewster_angle_zeroes_tm_reflection(n1, n2):
    theta_b = math.atan(n2 / n1)
    f = em.fresnel(n1, n2, math.cos(theta_b))
    assert abs(f.r_tm) < 1e-12
    assert abs(f.r_te) > 0.1


def test_total_internal_reflection_is_total_for_both_polarizations():
    n1, n2 = 1.5, 1.0
    theta_c = math.asin(n2 / n1)
    theta = np.linspace(theta_c + 1e-6, math.pi / 2 - 1e-6, 50)
    f = em.fresnel(n1, n2, np.cos(theta))
    np.testing.assert_allclose(np.abs(f.r_te), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.abs(f.r_tm), 1.0, rtol=1e-12)
    # below it, strictly partial
    f = em.fresnel(n1, n2, np.cos(np.linspace(0, theta_c - 1e-3, 20)))
    assert np.all(np.abs(f.r_te) < 1) and np.all(np.abs(f.r_tm) < 1)


def test_energy_conservation_lossless_random_angles():
    """|r|^2 + (n2 cos t / n1 cos i) |t|^2 = 1 (real media, no TIR), both polarizations."""
    rng = np.random.default_rng(7)
    m = 2000
    n1 = rng.uniform(1.0, 9.0, m)
    n2 = rng.uniform(1.0, 9.0, m)
    theta = rng.uniform(0, math.pi / 2 * 0.999, m)
    s_t = n1 * np.sin(theta) / n2
    keep = s_t < 1
    n1, n2, theta, s_t = n1[keep], n2[keep], theta[keep], s_t[keep]
    ci, ct_oracle = np.cos(theta), np.sqrt(1 - s_t**2)
    f = em.fresnel(n1, n2, ci)
    np.testing.assert_allclose(f.cos_t.real, ct_oracle, rtol=1e-9, atol=1e-12)
    ratio = n2 * ct_oracle / (n1 * ci)
    np.testing.assert_allclose(np.abs(f.r_te) ** 2 + ratio * np.abs(f.t_te) ** 2, 1.0, rtol=1e-10)
    np.testing.assert_allclose(np.abs(f.r_tm) ** 2 + ratio * np.abs(f.t_tm) ** 2, 1.0, rtol=1e-10)
    # and the library's own power forms agree with that
    np.testing.assert_allclose(
        em.power_reflectance(f.r_te) + em.power_transmittance(n1, n2, ci, f.t_te, "te"), 1.0, rtol=1e-10
    )
    np.testing.assert_allclose(
        em.power_reflectance(f.r_tm) + em.power_transmittance(n1, n2, ci, f.t_tm, "tm"), 1.0, rtol=1e-10
    )


def test_power_transmittance_rejects_unknown_polarization():
    with pytest.raises(InputError) as info:
        em.power_transmittance(1.0, 1.5, 1.0, 0.8, "x")
    assert info.value.field == "polarization"


@pytest.mark.parametrize("bad", [-0.5, 1.5, float("nan")])
def test_bad_cosine_is_typed_error(bad):
    with pytest.raises(InvalidGeometryError) as info:
        em.fresnel(1.0, 1.5, bad)
    assert info.value.field == "cos_i"


# --------------------------------------------------------------------------- tmm oracle


_TMM_POL = {"te": "s", "tm": "p"}
_ANGLES_DEG = [0.0, 10.0, 30.0, 45.0, 60.0, 75.0, 89.0]


@pytest.mark.parametrize("pol", ["te", "tm"])
@pytest.mark.parametrize(
    "n1,n2",
    [(1.0, N_MUSCLE), (3.4, N_MUSCLE), (7.0, N_FAT), (1.0, 1.5), (1.5, 1.0)],
    ids=["air-muscle", "fatlike-muscle", "dense-fat", "air-glass", "glass-air-tir"],
)
def test_single_interface_matches_tmm(pol, n1, n2):
    """tmm uses exp(-i w t) and n + i kappa: its fields are the complex conjugates
    of ours, so r_ours = conj(r_tmm(conj n)). Same closed forms evaluated by a
    different code path; tolerance 1e-10 absolute (|r|, |t| <= 2)."""
    lam = 299_792_458.0 / 402e6
    for deg in _ANGLES_DEG:
        th0 = math.radians(deg)
        ref = tmm.coh_tmm(_TMM_POL[pol], [n1, np.conj(n2)], [np.inf, np.inf], th0, lam)
        f = em.fresnel(n1, n2, math.cos(th0))
        r = f.r_te if pol == "te" else f.r_tm
        t = f.t_te if pol == "te" else f.t_tm
        assert complex(r) == pytest.approx(np.conj(ref["r"]), abs=1e-10), deg
        assert complex(t) == pytest.approx(np.conj(ref["t"]), abs=1e-10), deg
        assert float(em.power_reflectance(r)) == pytest.approx(ref["R"], abs=1e-10)
        assert float(em.power_transmittance(n1, n2, math.cos(th0), t, pol)) == pytest.approx(ref["T"], abs=1e-10)


@pytest.mark.parametrize("pol", ["te", "tm"])
def test_lossy_three_layer_stack_matches_tmm(pol):
    """Air-like (real 1.3) / 20 mm fat / muscle at 402 MHz, oblique incidence.
    Our side: Airy sum of the multiple reflections in the fat layer built from
    em.fresnel at both interfaces (the second one with the complex cos of the
    fat layer) and the layer phase exp(-j k0 n_fat cos_fat d). A sign or
    conjugation slip in any coefficient's phase convention breaks this."""
    n0, n1, n2 = 1.3, N_FAT, N_MUSCLE
    f_hz = 402e6
    lam = 299_792_458.0 / f_hz
    d = 0.02
    th = np.deg2rad(np.array(_ANGLES_DEG))
    ci = np.cos(th)
    f01 = em.fresnel(n0, n1, ci)
    c1 = f01.cos_t
    f12 = em.fresnel(n1, n2, c1)
    delta = 2 * np.pi / lam * n1 * c1 * d  # complex phase thickness (Im < 0: decay)
    prop = np.exp(-1j * delta)
    key = "te" if pol == "te" else "tm"
    r01, t01 = getattr(f01, f"r_{key}"), getattr(f01, f"t_{key}")
    r12, t12 = getattr(f12, f"r_{key}"), getattr(f12, f"t_{key}")
    r = (r01 + r12 * prop**2) / (1 + r01 * r12 * prop**2)
    t = t01 * t12 * prop / (1 + r01 * r12 * prop**2)
    T = em.power_transmittance(n0, n2, ci, t, pol)
    for i, th0 in enumerate(th):
        ref = tmm.coh_tmm(_TMM_POL[pol], [n0, np.conj(n1), np.conj(n2)], [np.inf, d, np.inf], th0, lam)
        assert r[i] == pytest.approx(np.conj(ref["r"]), abs=1e-10)
        assert t[i] == pytest.approx(np.conj(ref["t"]), abs=1e-10)
        assert T[i] == pytest.approx(ref["T"], abs=1e-10)
        assert abs(r[i]) ** 2 == pytest.approx(ref["R"], abs=1e-10)


# --------------------------------------------------------------------------- geometry / basis


def _random_geometry(rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray]:
    d = _unit(rng.normal(size=(m, 3)))
    n = _unit(rng.normal(size=(m, 3)))
    return d, n


def test_reflect_direction():
    rng = np.random.default_rng(3)
    d, n = _random_geometry(rng, 500)
    r = em.reflect_direction(d, n)
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.sum(r * n, axis=1), -np.sum(d * n, axis=1), atol=1e-12)
    np.testing.assert_allclose(_tan(r, n), _tan(d, n), atol=1e-12)
    # either normal orientation gives the same reflection
    np.testing.assert_allclose(em.reflect_direction(d, -n), r, atol=1e-12)


def test_refract_direction_obeys_snell_and_flags_tir():
    rng = np.random.default_rng(4)
    m = 2000
    d, n = _random_geometry(rng, m)
    n1 = rng.uniform(1.0, 8.0, m)
    n2 = rng.uniform(1.0, 8.0, m)
    t, tir = em.refract_direction(d, n, n1, n2)
    sin_i = np.linalg.norm(np.cross(d, n), axis=1)
    expected_tir = n1 * sin_i / n2 > 1
    assert np.array_equal(tir, expected_tir)
    assert expected_tir.any() and (~expected_tir).any()
    ok = ~tir
    assert np.all(np.isnan(t[tir]))
    dt, nt, n1t, n2t = t[ok], n[ok], n1[ok], n2[ok]
    np.testing.assert_allclose(np.linalg.norm(dt, axis=1), 1.0, rtol=1e-12)
    # Snell: n1 sin_i = n2 sin_t
    np.testing.assert_allclose(n1t * sin_i[ok], n2t * np.linalg.norm(np.cross(dt, nt), axis=1), rtol=1e-9, atol=1e-12)
    # coplanar with d and n, and on the far side (same side as d)
    np.testing.assert_allclose(np.sum(dt * np.cross(d[ok], nt), axis=1), 0.0, atol=1e-12)
    assert np.all(np.sum(dt * nt, axis=1) * np.sum(d[ok] * nt, axis=1) > 0)
    # complex indices: only the real parts matter for geometry
    t2, tir2 = em.refract_direction(d, n, n1 - 0.3j, n2 - 2.0j)
    np.testing.assert_allclose(t2[ok], t[ok], atol=1e-14)
    assert np.array_equal(tir2, tir)


def test_interface_basis_is_orthonormal_and_right_handed():
    rng = np.random.default_rng(5)
    m = 1000
    d, n = _random_geometry(rng, m)
    b = em.interface_basis(d, n, 1.0, 1.4)
    s, p_in, p_r, p_t = b  # tuple-like unpacking
    k_r = em.reflect_direction(d, n)
    for p, k in [(p_in, d), (p_r, k_r), (p_t, b.k_transmitted)]:
        np.testing.assert_allclose(np.linalg.norm(p, axis=1), 1.0, rtol=1e-12)
        np.testing.assert_allclose(np.sum(p * k, axis=1), 0.0, atol=1e-12)
        np.testing.assert_allclose(np.sum(p * s, axis=1), 0.0, atol=1e-12)
        np.testing.assert_allclose(np.cross(p, s), k, atol=1e-12)  # (p, s, k) right-handed
    np.testing.assert_allclose(np.linalg.norm(s, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.sum(s * n, axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(b.k_reflected, k_r, atol=1e-12)
    np.testing.assert_allclose(b.cos_i, np.abs(np.sum(d * n, axis=1)), atol=1e-12)
    # s = k_in x n_forward / |.| with n_forward along the propagation
    nf = n * np.sign(np.sum(d * n, axis=1))[:, None]
    np.testing.assert_allclose(s, _unit(np.cross(d, nf)), atol=1e-12)
    # the normal's orientation does not matter
    b2 = em.interface_basis(d, -n, 1.0, 1.4)
    for a, c in [(b.s, b2.s), (b.p_in, b2.p_in), (b.p_reflected, b2.p_reflected), (b.p_transmitted, b2.p_transmitted)]:
        np.testing.assert_allclose(a, c, atol=1e-12)


def test_interface_basis_without_indices_and_under_tir():
    b = em.interface_basis(np.array([[0.6, 0.0, 0.8]]), np.array([[0.0, 0.0, 1.0]]))
    assert b.p_transmitted is None and b.k_transmitted is None
    b = em.interface_basis(np.array([[0.8, 0.0, 0.6]]), np.array([[0.0, 0.0, 1.0]]), 1.5, 1.0)
    assert b.tir[0] and np.all(np.isnan(b.p_transmitted[0]))


def test_normal_incidence_basis_is_deterministic():
    normals = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0], _unit(np.array([1.0, 2.0, 3.0]))])
    b = em.interface_basis(normals, normals, 1.0, 2.0)
    again = em.interface_basis(normals.copy(), normals.copy(), 1.0, 2.0)
    np.testing.assert_array_equal(b.s, again.s)
    assert np.all(np.isfinite(b.s))
    np.testing.assert_allclose(np.linalg.norm(b.s, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.sum(b.s * normals, axis=1), 0.0, atol=1e-12)
    # reference axis x: s = x_hat x n / |.| for n = z
    np.testing.assert_allclose(b.s[0], [0.0, -1.0, 0.0], atol=1e-15)
    # at normal incidence p_reflected = -p_in, and the reflected field is r_te times
    # the incident one for any polarization (r_tm = -r_te)
    np.testing.assert_allclose(b.p_reflected, -b.p_in, atol=1e-12)
    np.testing.assert_allclose(b.p_transmitted, b.p_in, atol=1e-12)


def _fields(b, n1, n2, f, a_s, a_p, p_t, k_t):
    """Total E and H (times eta0) on each side of the interface, from the returned
    basis and coefficients. H_j = n_j k_j x E_j for a plane wave."""
    s = b.s
    e_i = a_s[:, None] * s + a_p[:, None] * b.p_in
    e_r = (f.r_te * a_s)[:, None] * s + (f.r_tm * a_p)[:, None] * b.p_reflected
    e_t = (f.t_te * a_s)[:, None] * s + (f.t_tm * a_p)[:, None] * p_t
    h_i = n1[:, None] * np.cross(b.k_in, e_i)
    h_r = n1[:, None] * np.cross(b.k_reflected, e_r)
    h_t = n2[:, None] * np.cross(k_t, e_t)
    return e_i + e_r, e_t, h_i + h_r, h_t


def test_tangential_field_continuity_lossless():
    """Maxwell boundary conditions with the returned basis vectors and Fresnel
    coefficients, random directions, normals, indices and Jones vectors
    (lossless media, no TIR so the transmitted direction is real)."""
    rng = np.random.default_rng(11)
    m = 1000
    d, n = _random_geometry(rng, m)
    n1 = rng.uniform(1.0, 8.0, m)
    n2 = n1 * rng.uniform(1.0, 3.0, m)  # n2 >= n1: never TIR
    a_s = rng.normal(size=m) + 1j * rng.normal(size=m)
    a_p = rng.normal(size=m) + 1j * rng.normal(size=m)
    b = em.interface_basis(d, n, n1, n2)
    f = em.fresnel(n1, n2, b.cos_i)
    e1, e2, h1, h2 = _fields(b, n1, n2, f, a_s, a_p, b.p_transmitted, b.k_transmitted)
    nf = b.normal_forward
    np.testing.assert_allclose(_tan(e1, nf), _tan(e2, nf), atol=1e-10)
    np.testing.assert_allclose(_tan(h1, nf), _tan(h2, nf), atol=1e-9)
    # and the normal component of D = eps E (eps = n^2) is continuous too
    np.testing.assert_allclose(
        n1**2 * np.sum(e1 * nf, axis=1), n2**2 * np.sum(e2 * nf, axis=1), atol=1e-8 * np.max(n2**2)
    )


def test_tangential_field_continuity_lossy_and_tir():
    """Same with lossy media (and TIR cases) where the transmitted wave is
    inhomogeneous: its complex direction k_t = (n1/n2)(k_i - ci nf) + ct nf and
    p_t = s x k_t are built here from cos_t."""
    rng = np.random.default_rng(12)
    m = 1000
    d, n = _random_geometry(rng, m)
    n1 = rng.uniform(1.0, 8.0, m) - 1j * rng.uniform(0.0, 0.3, m)
    n2 = rng.uniform(1.0, 8.0, m) - 1j * rng.uniform(0.0, 3.0, m)
    n2[:100] = rng.uniform(1.0, 2.0, 100)  # some lossless second media, often TIR
    n1[:100] = rng.uniform(3.0, 8.0, 100)
    a_s = rng.normal(size=m) + 1j * rng.normal(size=m)
    a_p = rng.normal(size=m) + 1j * rng.normal(size=m)
    b = em.interface_basis(d, n)
    f = em.fresnel(n1, n2, b.cos_i)
    nf = b.normal_forward
    ci = b.cos_i[:, None]
    k_t = (n1 / n2)[:, None] * (b.k_in - ci * nf) + f.cos_t[:, None] * nf
    np.testing.assert_allclose(np.sum(k_t * k_t, axis=1), 1.0, atol=1e-12)  # complex unit vector
    p_t = np.cross(b.s, k_t)
    e1, e2, h1, h2 = _fields(b, n1, n2, f, a_s, a_p, p_t, k_t)
    np.testing.assert_allclose(_tan(e1, nf), _tan(e2, nf), atol=1e-10)
    np.testing.assert_allclose(_tan(h1, nf), _tan(h2, nf), atol=1e-9)


def test_interface_basis_rejects_bad_vectors():
    with pytest.raises(InvalidGeometryError):
        em.interface_basis(np.zeros((2, 3)), np.ones((2, 3)))
    with pytest.raises(InvalidGeometryError):
        em.interface_basis(np.ones((2, 2)), np.ones((2, 2)))
    with pytest.raises(InvalidGeometryError):
        em.refract_direction(np.array([[np.nan, 0, 1.0]]), np.array([[0, 0, 1.0]]), 1.0, 1.5)


def test_ray_in_lossy_tissue_takes_the_root_continuous_with_the_lossless_limit():
    """A ray in lossy tissue (complex tangential index n1 sin_i) leaving into a less lossy
    medium: the decaying-wave rule (right for a real tangential index, tmm's case) would pick
    the backward root (Re cos_t < 0, |r| > 1). Oracle: continuity in the loss. Scaling Im n1
    from 0 (lossless: the Born & Wolf 1.5.20-21 closed form with real cos_t) up to the
    tissue value must move every coefficient continuously (no branch jump: consecutive
    steps of a 1000-point 1e-8..1 geometric scan differ by < 0.3 of the coefficient's
    magnitude: the smooth variation per step is < 0.1 of it, the wrong root jumps by ~2), with
    Re cos_t > 0 and |r| < 1 throughout, below the geometric critical angle."""
    pairs = [(N_MUSCLE, 1.0 + 0j), (N_MUSCLE, N_FAT), (7.17 - 2.15j, 1.0 + 0j), (9.32 - 4.56j, N_MUSCLE)]
    for n1, n2 in pairs:
        theta_c = np.arcsin(n2.real / n1.real)
        for theta in np.linspace(0.0, 0.95 * theta_c, 5):
            ci = np.cos(theta)
            scale = np.concatenate([[0.0], np.geomspace(1e-8, 1.0, 1000)])
            n1s = n1.real + 1j * n1.imag * scale
            f = em.fresnel(n1s, n2, ci)
            ct0 = np.sqrt(1 - (n1.real / n2) ** 2 * (1 - ci**2))
            assert abs(f.r_te[0] - (n1.real * ci - n2 * ct0) / (n1.real * ci + n2 * ct0)) < EXACT
            for coef in (f.r_te, f.r_tm, f.t_te, f.t_tm, f.cos_t):
                assert np.max(np.abs(np.diff(coef))) < 0.3 * max(np.abs(coef).max(), 0.1)
            assert np.all(f.cos_t.real > 0)
            assert np.all(np.abs(f.r_te) < 1) and np.all(np.abs(f.r_tm) < 1)
    # a real tangential index (the complex cos inside a slab entered from air) keeps the
    # decaying-wave root: Im(n2 cos_t) < 0
    ci_slab = em.cos_transmitted(1.0, N_MUSCLE, np.cos(np.deg2rad(40.0)))
    ct = em.cos_transmitted(N_MUSCLE, N_FAT, ci_slab)
    assert (N_FAT * ct).imag < 0
