"""Cubic-convolution interpolation (thesis Eq 3.5-3.9): what it reproduces exactly, and the warp."""

from __future__ import annotations

import numpy as np
import pytest

from vision.interpolation import KEYS_A, THESIS_A, cubic_kernel, interpolate, warp_similarity


def _thesis_eq_3_9(x: np.ndarray) -> np.ndarray:
    """Eq 3.9 exactly as printed in the thesis."""
    t = np.abs(x)
    return np.where(t < 1, t**3 - 2 * t**2 + 1, np.where(t < 2, -(t**3) + 5 * t**2 - 8 * t + 4, 0.0))


def _fractions(n: int = 400) -> np.ndarray:
    return np.random.default_rng(7).random(n)


def test_the_thesis_kernel_is_keys_with_a_minus_one() -> None:
    x = np.linspace(-3, 3, 1201)
    np.testing.assert_allclose(cubic_kernel(x, THESIS_A), _thesis_eq_3_9(x), atol=1e-14)


@pytest.mark.parametrize("a", [THESIS_A, KEYS_A, -0.75])
def test_samples_come_back_exactly_and_constants_are_reproduced(a) -> None:
    """S(0) = 1 and S(+-1) = S(+-2) = 0: interpolating at a pixel returns that pixel; the four
    weights sum to 1 for any a: a constant frame stays constant."""
    img = np.random.default_rng(0).random((9, 11))
    rows, cols = np.mgrid[0:9, 0:11]
    np.testing.assert_allclose(interpolate(img, rows, cols, a), img, atol=1e-14)
    r, c = 1 + 6 * _fractions(), 1 + 8 * _fractions()[::-1]
    np.testing.assert_allclose(interpolate(np.full((9, 11), 2.5), r, c, a), 2.5, atol=1e-13)


def test_keys_kernel_reproduces_biquadratic_polynomials_exactly() -> None:
    """With a = -1/2 the cubic convolution reproduces every polynomial of degree <= 2 in each
    coordinate (Keys 1981): sampled on the pixel grid and interpolated anywhere inside (4 x 4
    neighbourhood within the frame), it is exact to rounding (1e-9 on values up to ~1e3)."""
    rows, cols = np.mgrid[0:12, 0:12].astype(float)

    def f(r, c):
        return 1.5 - 2 * r + 0.7 * c + 0.3 * r * r - 0.2 * r * c + 0.45 * c * c + 0.05 * r * r * c * c

    r, c = 1 + 9 * _fractions(), 1 + 9 * _fractions()[::-1]
    np.testing.assert_allclose(interpolate(f(rows, cols), r, c, KEYS_A), f(r, c), atol=1e-9)


def test_no_cubic_convolution_reproduces_a_cubic_the_error_is_keys_closed_form() -> None:
    """A cubic c x^3 sampled on integers and interpolated at i + u with a = -1/2 comes back as
    c x^3 + c u (1 - u)(1 - 2u): Keys' third-order error (derived from the kernel's weights; zero
    only at u = 0, 1/2, 1). So the kernel does NOT reproduce cubics; this pins the exact error."""
    cols = np.arange(16, dtype=float)
    img = np.tile(0.8 * cols**3, (6, 1))
    x = 1 + 13 * _fractions()
    u = x - np.floor(x)
    got = interpolate(img, np.full_like(x, 2.0), x, KEYS_A)
    np.testing.assert_allclose(got, 0.8 * x**3 + 0.8 * u * (1 - u) * (1 - 2 * u), atol=1e-9)


def test_the_thesis_kernel_does_not_reproduce_a_ramp() -> None:
    """With Eq 3.9 (a = -1) even f = x is not reproduced: it comes back as
    x - (2a + 1) u (1 - u)(1 - 2u) = x + u (1 - u)(1 - 2u), up to 0.096 pixel of slope."""
    cols = np.arange(16, dtype=float)
    img = np.tile(2.0 * cols + 1.0, (6, 1))
    x = 1 + 13 * _fractions()
    u = x - np.floor(x)
    got = interpolate(img, np.full_like(x, 3.0), x, THESIS_A)
    np.testing.assert_allclose(got, 2.0 * x + 1.0 + 2.0 * u * (1 - u) * (1 - 2 * u), atol=1e-12)
    assert np.max(np.abs(got - (2.0 * x + 1.0))) > 0.15


def test_a_quarter_turn_is_numpys_rot90() -> None:
    """Rotating content by 90 deg counter-clockwise (as displayed) about the centre of a square
    frame maps pixels onto pixels: the warp must be np.rot90 (positions are integers to ~1e-14,
    where every kernel returns the sample)."""
    img = np.random.default_rng(1).random((15, 15))
    for a in (THESIS_A, KEYS_A):
        np.testing.assert_allclose(warp_similarity(img, 90.0, 1.0, a=a), np.rot90(img), atol=1e-12)
        np.testing.assert_allclose(warp_similarity(img, -90.0, 1.0, a=a), np.rot90(img, -1), atol=1e-12)


def test_scale_two_doubles_offsets_from_the_centre() -> None:
    """Magnifying by 2 about the centre pixel c (odd frame): out(c + 2d) = in(c + d) for integer
    offsets d; what falls outside the source frame is filled with 0."""
    img = np.random.default_rng(2).random((21, 21))
    out = warp_similarity(img, 0.0, 2.0)
    d = np.arange(-5, 6)
    np.testing.assert_allclose(out[np.ix_(10 + 2 * d, 10 + 2 * d)], img[np.ix_(10 + d, 10 + d)], atol=1e-12)
    small = warp_similarity(img, 0.0, 0.25)
    assert small[0, 0] == 0.0 and small[10, 10] == pytest.approx(img[10, 10])
