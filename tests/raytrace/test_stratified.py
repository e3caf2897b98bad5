"""Paths through planar layers against the exact layered-medium solution (raytrace/solver/stratified.py).

Oracle (bench/fullwave/layered_exact.py, sharing no code with the tracer; also the planar full-wave
cases' second reference): the field of a horizontal Hertzian
dipole in a planar multilayer from transmission-line Green's functions (Michalski & Mosig, IEEE
TAP 45(3), 1997): ``E_t = G p`` with, for a unit current source and the receiver at lateral
offset rho at azimuth phi,

    G_xx = -1/2 [S0{Ve + Vh} - cos 2phi S2{Ve - Vh}],   G_yy = -1/2 [S0{Ve + Vh} + cos 2phi S2{Ve - Vh}],
    G_xy = G_yx = 1/2 sin 2phi S2{Ve - Vh},             S_n{f} = 1/(2 pi) int_0^inf f J_n(kr rho) kr dkr,

``Ve`` and ``Vh`` the TM and TE line voltages at the receiver for a unit shunt current at the
source (``Z_TE = w mu0 / kz``, ``Z_TM = kz / (w eps)``, the source in the bottom half-space, every
multiple reflection by the lines' generalized reflection coefficients). The tracer builds each
path's field from a plane-wave (Weyl) spectrum split into TE and TM with the azimuth resolved by
a Fourier series; the oracle sums Bessel integrals of line voltages: two formulations that agree
only if both are right. Its line recursion is checked against the ``tmm`` package (Byrnes), its
homogeneous limit against the closed-form dipole field (Jackson 9.18), and its layered values were
compared with gprMax on the planar bench cases (2 mm cells: within 0.22 dB and 1.2 deg of it but
at 100 mm depth; docs/validation.md). The oracle's integral runs on a trapezoid of
40 000 points along a path lifted above the real axis (relative error ~1e-6, checked against the
closed form).

What the tests require (the tolerances' reasons are in each): every traced generalized ray (the
direct path, the skin's reverberations, the fat's) equals its own exact integral to 1e-4; the sum of
the traced paths (at most 6 interactions) is the exact field at contact and in-air receivers to
within the ray series' truncation (0.5 dB, measured -0.08 to +0.34 dB); stationary phase misses the
same sums by up to 5.3 dB at contact sensors and 7.7 dB in air.
"""

from __future__ import annotations

import numpy as np
import pytest
import tmm

import raytrace as rt
from bench.fullwave import stack_phantom
from bench.fullwave.layered_exact import EPS0, MU0, F, as_gain, decaying_kz, exact_field, line_voltages
from raytrace.physics import tissues
from raytrace.physics.tissues import DEFAULT_FAT
from raytrace.solver import stratified

C = 299_792_458.0


def test_oracle_line_recursion_is_tmm_and_its_homogeneous_limit_the_dipole():
    """The generalized reflection the oracle's lines give at the bottom interface is tmm's r for the
    same stack (tmm uses exp(-j w t): conjugate indices, conjugate answer; its r_p is minus the
    tangential-field ratio), to 1e-9 (5e-11 seen: the receiver sits 1e-12 m above the
    interface); and in one medium the oracle is Jackson's dipole field to 1e-5
    (the 40 000-point trapezoid)."""
    eps = [57.1 - 35.6j, 11.6 - 3.6j, 46.7 - 30.8j, 1.0 + 0j]
    d = [0.020, 0.002]
    w = 2 * np.pi * F
    n = np.sqrt(np.array(eps))
    for sin_muscle in (0.0, 0.2, 0.5):
        kr = w / C * (n[0] * sin_muscle).real
        # the oracle's reflection: total voltage at the interface / incident - 1, source at h = 0
        for pol, sign, tmm_pol in (("e", -1.0, "p"), ("h", 1.0, "s")):
            v = line_voltages(np.array([kr]), w, eps, d, 0.0, 1e-12)[0 if pol == "e" else 1][0]
            kz0 = decaying_kz(w / C * n[0], kr)
            z0 = kz0 / (w * EPS0 * eps[0]) if pol == "e" else w * MU0 / kz0
            gamma = v / (z0 / 2) - 1.0
            th0 = np.arcsin(kr / (w / C) / np.conj(n[0]))
            ref = tmm.coh_tmm(tmm_pol, np.conj(n), [np.inf, d[0], d[1], np.inf], th0, C / F)["r"]
            assert abs(gamma - sign * np.conj(ref)) < 1e-9, (pol, sin_muscle)
    eps_m = [eps[0]] * 3
    for rho, phi in ((0.0, 0.0), (0.03, 0.0), (0.05, np.pi / 2), (0.04, 0.7)):
        h, zr = 0.02, 0.01
        r = np.array([rho * np.cos(phi), rho * np.sin(phi), h + zr])
        dist = np.linalg.norm(r)
        u = r / dist
        k = w / C * n[0]
        x = 1 / (1j * k * dist)
        p = np.array([1.0, 0.0, 0.0])
        e = -1j * w * MU0 / (4 * np.pi * dist) * np.exp(-1j * k * dist) * (
            (p - u * (u @ p)) * (1 + x + x * x) - 2 * (x + x * x) * u * (u @ p))
        got = exact_field(eps_m, [0.01], h, zr, r[:2], p[:2], p[:2])
        assert abs(got / e[0] - 1) < 1e-5


def _stack(skin_m, fat_m, extra=()):
    layers = [("skin", "skin_dry", 0.0), ("fat", DEFAULT_FAT, skin_m), ("muscle", "muscle", skin_m + fat_m)]
    return list(layers) + list(extra)


def _eps(tissue_names):
    return [complex(tissues.complex_relative_permittivity(t, F)) for t in tissue_names]


def _trace(layers, depth_m, tx_pol, receivers, near_field=True):
    """The tracer on the stack: a dipole ``tx_pol`` at ``depth_m``, dipole receivers (position, pol)."""
    ph = stack_phantom(layers, "stack")
    tx = rt.Antenna(position_m=[0.0, depth_m, 0.0], polarization=tx_pol, pattern="dipole")
    rxs = [rt.Antenna(position_m=pos, name=f"r{i}", polarization=pol, pattern="dipole")
           for i, (pos, pol) in enumerate(receivers)]
    spec = rt.ChannelSpec(tx, rxs, phantom=ph.name, frequency_hz=F, max_interactions=6, rays=100_000,
                          near_field=near_field)
    return rt.trace_channel(spec, ph)


def _oracle_geometry(layers, depth_m, pos):
    """The oracle's stack (bottom up: the capsule's half-space, the finite layers, air) and the
    source depth / receiver height in it. The phantom's y grows into the body; the oracle's z up."""
    fronts = [f for _, _, f in layers]
    tissue = [t for _, t, _ in layers]
    eps = _eps(tissue[::-1]) + [1.0 + 0j]
    d = list(np.diff(fronts)[::-1])  # finite layers, bottom up
    inner = fronts[-1]
    return eps, d, depth_m - inner, inner - pos[1]


def _to_oracle_xy(vec):
    """Phantom (x, z) in the layers' plane -> the oracle's horizontal axes."""
    return np.array([vec[0], vec[2]])


@pytest.mark.parametrize("seed", range(4))
def test_each_traced_ray_through_layers_is_its_exact_integral(seed):
    """Skin 1-3 mm, fat 5-25 mm, muscle, the capsule 30-100 mm under the skin surface; contact
    sensors 0.2 mm under the surface at 0-60 deg off the normal; random horizontal (tangential)
    dipoles. The direct path and its first three reverberations in the skin, each traced, against
    its own generalized-ray integral of the oracle: 1e-4 relative (the oracle's trapezoid ~1e-6, the
    tracer's Gauss-Legendre panels ~1e-7; the path itself is the same: planar, so exact)."""
    rng = np.random.default_rng(seed)
    skin, fat = rng.uniform(0.001, 0.003), rng.uniform(0.005, 0.025)
    depth = rng.uniform(0.03, 0.10)
    layers = _stack(skin, fat)

    def tangential():
        b = rng.uniform(0, 2 * np.pi)
        return np.array([np.cos(b), 0.0, np.sin(b)])

    p = tangential()
    receivers = []
    for angle in rng.uniform(0.0, 60.0, 3):
        az = rng.uniform(0, 2 * np.pi)
        off = depth * np.tan(np.radians(angle))
        receivers.append((np.array([off * np.cos(az), 0.0002, off * np.sin(az)]), tangential()))
    res = _trace(layers, depth, p, receivers)
    eps, d, h, _ = _oracle_geometry(layers, depth, receivers[0][0])
    n = np.sqrt(np.array(eps))
    for prof, (pos, q) in zip(res.profiles, receivers):
        zr = layers[-1][2] - pos[1]
        for k in range(4):
            media = ["muscle", "fat"] + ["skin"] * (k + 1)
            (path,) = [x for x in prof.paths if [s.medium for s in x.segments] == media]
            want = as_gain(exact_field(eps, d, h, zr, _to_oracle_xy(pos), _to_oracle_xy(p), _to_oracle_xy(q),
                                       reverberations=k), n[0], n[2])
            assert abs(path.gain / want - 1) < 1e-4, (seed, k, path.gain, want)


def _lateral_layers():
    return _stack(0.002, 0.020)


@pytest.mark.slow
def test_contact_and_air_receivers_match_the_exact_layered_field():
    """The bench's lateral stack (skin 2 mm, fat 20 mm, muscle; z dipoles 30 mm behind the fat):
    contact sensors 0.2 mm under the skin 0-55 mm aside and receivers in air 10-30 mm off the skin.
    The sum of the traced paths against the oracle's full field (every reflection order): within
    0.5 dB / 4 deg at contact sensors and 0.5 dB / 5 deg in air (the traced ray series stops at 6
    interactions, the request's default: measured -0.08 to +0.34 dB and <= 2.6 deg at contact, +0.03
    to +0.08 dB and <= 2.7 deg in air; at 12 interactions within 0.05 dB). Stationary phase (near_field
    off, as before the generalized-ray model) misses the same sums by -0.5 to -5.3 dB at contact and
    -3.9 to -7.7 dB in air: checked (> 4 dB somewhere), so that the test can fail."""
    layers = _lateral_layers()
    z = np.array([0.0, 0.0, 1.0])
    contact = [(np.array([x, 0.0002, 0.0]), z) for x in (0.0, 0.01, 0.02, 0.03, 0.04, 0.055)]
    air = [(np.array([x, y, 0.0]), z) for x, y in ((0.0, -0.01), (0.0, -0.03), (0.02, -0.01))]
    eps, d, h, _ = _oracle_geometry(layers, 0.052, contact[0][0])
    n = np.sqrt(np.array(eps))
    exact = []
    for pos, q in contact + air:
        zr = layers[-1][2] - pos[1]
        n_rx = n[2] if pos[1] > 0 else n[3]
        exact.append(as_gain(exact_field(eps, d, h, zr, _to_oracle_xy(pos), _to_oracle_xy(z), _to_oracle_xy(q)),
                             n[0], n_rx))
    res = _trace(layers, 0.052, z, contact + air)
    for prof, (pos, _), want in zip(res.profiles, contact + air, exact):
        got = sum(x.gain for x in prof.paths)
        db, deg = 20 * np.log10(abs(got / want)), np.degrees(np.angle(got / want))
        tol_db, tol_deg = (0.5, 4.0) if pos[1] > 0 else (0.5, 5.0)
        assert abs(db) < tol_db and abs(deg) < tol_deg, (pos, db, deg)
    # the stationary-phase (geometric-optics) sums of the same paths miss it by far
    go = _trace(layers, 0.052, z, contact + air, near_field=False)
    worst = max(abs(20 * np.log10(abs(sum(x.gain for x in prof.paths) / want)))
                for prof, want in zip(go.profiles, exact))
    assert worst > 4.0


def test_stack_ray_needs_parallel_interfaces():
    """A path whose interfaces' normals are within 20 deg of their mean is a stack ray; 30 deg apart
    (a tilted layer) it is left to geometric optics; a leg that runs back against its sense (a
    curved path no stack has) too."""
    n = np.full((1, 3), 2.0 + 0j)
    pts = np.array([[0, 0, 0], [0.01, 0, 0.02], [0.02, 0, 0.04], [0.03, 0, 0.05]], float)

    def normals(tilt_deg):
        t = np.radians(tilt_deg)
        return np.array([[0, 0, 1.0], [np.sin(t), 0, np.cos(t)]])

    args = (np.array([False, False]), np.array([1, 2, 0]), np.array([2, 0]), n, np.array([1.0, 0, 0]),
            np.array([1.0, 0, 0]))
    assert stratified.stack_ray(pts, normals(10.0), *args) is not None
    assert stratified.stack_ray(pts, normals(45.0), *args) is None
    back = pts.copy()
    back[3, 2] = 0.03  # the last leg runs back down
    assert stratified.stack_ray(back, normals(0.0), *args) is None
