"""Mutual information (thesis Eq 3.2-3.4) against independent histograms and its known bias."""

from __future__ import annotations

import numpy as np
import pytest

from vision.errors import VisionInputError
from vision.kernels import histogram_mutual_information
from vision.mutual_information import independence_bias_nats, mutual_information


def _entropy_by_numpy(x: np.ndarray, bins: int) -> float:
    """-sum p ln p of numpy's own equal-width histogram over [min, max] (an independent binning)."""
    counts, _ = np.histogram(x, bins=bins)
    p = counts[counts > 0] / x.size
    return float(-(p * np.log(p)).sum())


def test_mi_of_a_frame_with_itself_is_its_entropy() -> None:
    """I(X, X) = H(X): the joint histogram is diagonal, so H(X, X) = H(X) in Eq 3.3 (exact)."""
    rng = np.random.default_rng(0)
    frame = rng.gamma(2.0, 1.0, size=(60, 70))
    for bins in (8, 64, 256):
        assert mutual_information(frame, frame, bins) == pytest.approx(_entropy_by_numpy(frame, bins), abs=1e-12)


def test_mi_is_eq_3_2_on_numpy_histograms() -> None:
    """Eq 3.2 written directly (sum of p(x,y) ln(p(x,y) / p(x) p(y)) over numpy's histogram2d)
    equals the implementation's H(X) + H(Y) - H(X,Y) form (Eq 3.3) to rounding."""
    rng = np.random.default_rng(1)
    x = rng.random((50, 40))
    y = np.sin(3 * x) + 0.3 * rng.random(x.shape)  # dependent, non-linearly
    bins = 16
    joint, _, _ = np.histogram2d(x.ravel(), y.ravel(), bins=bins)
    p = joint / joint.sum()
    px, py = p.sum(axis=1), p.sum(axis=0)
    nz = p > 0
    direct = float((p[nz] * np.log(p[nz] / np.outer(px, py)[nz])).sum())
    assert mutual_information(x, y, bins) == pytest.approx(direct, abs=1e-12)
    assert mutual_information(y, x, bins) == pytest.approx(direct, abs=1e-12)  # symmetric


def test_mi_ignores_an_affine_change_of_exposure() -> None:
    """Each frame is quantised over its own range, so gain and offset of a frame (an exposure
    change of the capsule camera) leave the bins, hence the MI, unchanged."""
    rng = np.random.default_rng(2)
    x, y = rng.random((32, 32)), rng.random((32, 32))
    y = x + 0.5 * y
    assert mutual_information(x, 3.0 * y + 7.0, 32) == pytest.approx(mutual_information(x, y, 32), abs=1e-12)


def test_mi_of_independent_noise_is_the_stated_bias() -> None:
    """Independent frames have I = 0, but the plug-in estimate has mean (B - 1)^2 / (2 N) and
    standard deviation sqrt(2) (B - 1) / (2 N) (2 N I_hat is the G statistic, chi-square with
    (B - 1)^2 degrees of freedom; vision.mutual_information module doc).

    One 256 x 256 pair, 32 bins: mean 7.33e-3, sd 3.3e-4; within 5 sd. Then the mean over 40
    pairs of 64 x 64, 16 bins (mean 0.0275, sd of the mean 4.1e-4): within 4 sd of the mean, and
    far from 0 (the bias is real; 0 would be 67 sd away).
    """
    rng = np.random.default_rng(3)
    n, bins = 256 * 256, 32
    mean = independence_bias_nats(bins, bins, n)
    assert mean == pytest.approx(31**2 / (2 * n))
    sd = np.sqrt(2.0) * (bins - 1) / (2 * n)
    mi = mutual_information(rng.random((256, 256)), rng.random((256, 256)), bins)
    assert abs(mi - mean) < 5 * sd

    n, bins, pairs = 64 * 64, 16, 40
    values = [mutual_information(rng.random((64, 64)), rng.random((64, 64)), bins) for _ in range(pairs)]
    mean = independence_bias_nats(bins, bins, n)
    sd_mean = np.sqrt(2.0) * (bins - 1) / (2 * n) / np.sqrt(pairs)
    assert abs(np.mean(values) - mean) < 4 * sd_mean
    assert np.mean(values) > 60 * sd_mean


def test_mi_inputs_are_checked() -> None:
    x = np.zeros((8, 8))
    with pytest.raises(VisionInputError) as e:
        mutual_information(x, np.zeros((8, 9)))
    assert e.value.field == "moving"
    with pytest.raises(VisionInputError) as e:
        mutual_information(x, x, bins=1)
    assert e.value.field == "bins"
    with pytest.raises(VisionInputError) as e:
        mutual_information(x, x, mask=np.zeros((8, 8), bool))
    assert e.value.field == "mask"
    assert mutual_information(x, x, 16) == 0.0  # a constant frame carries no information


def test_the_compiled_mi_of_histograms_equals_eq_3_2_written_out() -> None:
    """The search's compiled MI of joint histograms (vision.kernels) against Eq 3.2 evaluated
    here from the probabilities, on sparse and dense random histograms (rows and columns left
    empty, one all zero: MI 0, one diagonal: MI = H(X)). Same quantity, different arithmetic: 1e-12."""
    rng = np.random.default_rng(11)
    hists = rng.integers(0, 40, (6, 16, 12)) * (rng.random((6, 16, 12)) < 0.3)
    hists[1, 3, :] = 0
    hists[2, :, 5] = 0
    hists[3] = 0
    hists[4] = 0
    hists[4, np.arange(12), np.arange(12)] = np.arange(1, 13)  # Y a function of X
    got = histogram_mutual_information(hists.astype(np.int64))
    for h, value in zip(hists, got):
        total = h.sum()
        if total == 0:
            assert value == 0.0
            continue
        p = h / total
        px, py = p.sum(axis=1), p.sum(axis=0)
        nz = p > 0
        expected = float(np.sum(p[nz] * np.log(p[nz] / np.outer(px, py)[nz])))
        assert value == pytest.approx(expected, rel=1e-12, abs=1e-12)
