"""The Butterworth pre-filter (thesis Eq 3.1) against its closed-form response."""

from __future__ import annotations

import numpy as np
import pytest

from vision.errors import VisionInputError
from vision.filters import butterworth_lowpass, to_grey


@pytest.mark.parametrize("frequency, cutoff, order", [(0.05, 0.15, 2), (0.15, 0.15, 2), (0.25, 0.15, 3),
                                                      (0.10, 0.20, 1)])
def test_a_sinusoid_is_scaled_by_the_butterworth_magnitude(frequency, cutoff, order) -> None:
    """Eq 3.1 gives |H|^2 = 1 / (1 + (w / w_c)^(2n)), so a grey sinusoid of spatial frequency w
    keeps its phase and has its amplitude multiplied by (1 + (w / w_c)^(2n))^(-1/2) (-3 dB at
    w = w_c). The frame is 160 px wide; measured away from the edges (the reflection padding
    breaks the sinusoid there), by least squares on the known cos / sin pair. Tolerance 1e-4:
    what departs from the closed form is the padding's leak from the edges, decaying as the
    filter's impulse response (measured <= 6e-7 at 30 px from the edges for these cases)."""
    rows, cols = np.mgrid[0:96, 0:160].astype(float)
    theta = np.radians(30.0)  # an oblique tone: both axes of the 2-D filter matter
    phase = 2 * np.pi * frequency * (cols * np.cos(theta) + rows * np.sin(theta))
    out = butterworth_lowpass(np.cos(phase), cutoff, order)
    inner = (slice(30, 66), slice(30, 130))
    design = np.stack([np.cos(phase[inner]).ravel(), np.sin(phase[inner]).ravel()], axis=1)
    (c, s), *_ = np.linalg.lstsq(design, out[inner].ravel(), rcond=None)
    expected = 1.0 / np.sqrt(1.0 + (frequency / cutoff) ** (2 * order))
    assert np.hypot(c, s) == pytest.approx(expected, rel=1e-4)
    assert abs(s) < 1e-4 * expected  # zero phase


def test_the_mean_grey_level_passes_unchanged() -> None:
    """H(0) = 1: a constant frame is returned as it is (to rounding)."""
    out = butterworth_lowpass(np.full((40, 50), 0.37), 0.1, 4)
    np.testing.assert_allclose(out, 0.37, atol=1e-12)


def test_salt_and_pepper_noise_is_removed() -> None:
    """The thesis' Fig 3.1 case: 5 % of the pixels of a smooth frame set to 0 or 1. After the
    low-pass the frame is far closer to the clean one (the RMS error falls by more than 4x:
    impulses are spread over ~1 / w_c^2 pixels)."""
    rng = np.random.default_rng(3)
    rows, cols = np.mgrid[0:128, 0:128] / 128.0
    clean = 0.5 + 0.3 * np.sin(6 * rows) * np.cos(5 * cols)
    noisy = clean.copy()
    hit = rng.random(clean.shape) < 0.05
    noisy[hit] = rng.integers(0, 2, hit.sum())
    before = np.sqrt(np.mean((noisy - clean) ** 2))
    after = np.sqrt(np.mean((butterworth_lowpass(noisy, 0.1, 2) - clean) ** 2))
    assert after < before / 4


def test_bad_filter_parameters_name_their_field() -> None:
    img = np.zeros((16, 16))
    with pytest.raises(VisionInputError) as e:
        butterworth_lowpass(img, cutoff=0.0)
    assert e.value.field == "cutoff"
    with pytest.raises(VisionInputError) as e:
        butterworth_lowpass(img, order=0)
    assert e.value.field == "order"


def test_grey_levels_of_colour_frames_and_bad_frames() -> None:
    rgb = np.zeros((10, 12, 3))
    rgb[..., 1] = 1.0
    np.testing.assert_allclose(to_grey(rgb), 0.587)  # BT.601 green weight
    for bad, why in ((np.zeros((4, 40)), "8 x 8"), (np.zeros((10, 10, 2)), "shape"),
                     (np.full((10, 10), np.nan), "finite"), (np.array([["a"] * 9] * 9), "numeric")):
        with pytest.raises(VisionInputError, match=why) as e:
            to_grey(bad, "reference")
        assert e.value.field == "reference"
