"""Mutual information of two frames from their joint grey-level histogram (thesis Eq 3.2-3.4).

With p(x, y) the joint distribution of the grey levels of corresponding pixels and p(x), p(y)
its marginals (Eq 3.2):

    I(X, Y) = sum_{x, y} p(x, y) log( p(x, y) / (p(x) p(y)) )
            = H(X) + H(Y) - H(X, Y)                              (Eq 3.3, written correctly)
    H(X)    = - sum_x p(x) log p(x)                              (Eq 3.4, written correctly)

Errata of the thesis' notation: Eq 3.3 writes the last term H(X u Y) -- it is the JOINT
entropy H(X, Y) of the pair (the "gray scale mapping matrix" of its text is the joint
histogram); Eq 3.4 lacks the minus sign. Its listing (A.1) computes what is written here.
Natural logarithms throughout: information in nats.

Estimation: the probabilities are the plug-in estimates (histogram counts / N) over ``bins``
equal-width grey-level bins per image. Each image is quantised over its own [min, max]
(:func:`quantize`), as the thesis' listing does with 256 levels.

Bias (stated for the tests and the docs): for two INDEPENDENT images the plug-in estimate is
not 0 but, to first order in 1 / N (Miller 1955, "Note on the bias of information estimates";
the same expansion gives Miller-Madow's entropy correction (B - 1) / (2 N)),

    E[I_hat] = (B_x - 1)(B_y - 1) / (2 N),

with B_x, B_y the occupied bins and N the pixel count; 2 N I_hat is then the G statistic of a
test of independence, chi-square distributed with (B_x - 1)(B_y - 1) degrees of freedom, so
its standard deviation is sqrt(2 (B_x - 1)(B_y - 1)) / (2 N). :func:`independence_bias_nats`
returns the mean. Example: 64 x 64 bins over 256 x 256 pixels: 0.030 nats +- 0.001.
"""

from __future__ import annotations

import numpy as np
from scipy.special import entr

from .errors import VisionInputError

#: Default grey-level bins per image (the thesis' listing uses 256; fewer bins give a smoother
#: MI surface and a smaller bias, docs/vision.md "Choices").
DEFAULT_BINS = 64


def check_bins(bins, field: str = "bins") -> int:
    """``bins`` as an int in [2, 1024], else :class:`VisionInputError`."""
    if isinstance(bins, bool) or not isinstance(bins, (int, np.integer)) or not 2 <= int(bins) <= 1024:
        raise VisionInputError(f"must be an integer in [2, 1024], got {bins!r}", field)
    return int(bins)


def grey_range(values: np.ndarray) -> tuple[float, float]:
    """(lo, width) of the values; width 1 for a constant image (all pixels fall in bin 0)."""
    lo, hi = float(np.min(values)), float(np.max(values))
    return lo, (hi - lo) if hi > lo else 1.0


def quantize(values: np.ndarray, bins: int, lo: float | None = None, width: float | None = None) -> np.ndarray:
    """Bin index in [0, bins) of every value over [lo, lo + width] (default: the values' own range),
    equal-width bins, the maximum in the last bin, values outside clipped to the end bins."""
    v = np.asarray(values, dtype=float)
    if lo is None or width is None:
        lo, width = grey_range(v)
    q = np.floor((v - lo) * (bins / width)).astype(np.int64)
    return np.clip(q, 0, bins - 1)


def joint_histogram(qx: np.ndarray, qy: np.ndarray, bins: int) -> np.ndarray:
    """Counts (bins, bins) of the pairs (qx[k], qy[k]) of quantised grey levels, vectorised
    (one ``bincount`` of the flat pair index)."""
    flat = np.asarray(qx, np.int64).ravel() * bins + np.asarray(qy, np.int64).ravel()
    return np.bincount(flat, minlength=bins * bins).reshape(bins, bins)


def entropy_nats(counts: np.ndarray, axis=None) -> np.ndarray:
    """Shannon entropy -sum p log p (Eq 3.4 with its sign) of a histogram, p = counts / total,
    over ``axis`` (None: all of it); 0 log 0 = 0."""
    c = np.asarray(counts, dtype=float)
    total = c.sum(axis=axis, keepdims=True)
    p = c / np.where(total > 0, total, 1.0)
    return entr(p).sum(axis=axis)


def mutual_information_from_histogram(joint: np.ndarray) -> np.ndarray:
    """I = H(X) + H(Y) - H(X, Y) (Eq 3.3) of joint histograms (..., bins, bins), in nats."""
    h = np.asarray(joint, dtype=float)
    hx = entropy_nats(h.sum(axis=-1), axis=-1)
    hy = entropy_nats(h.sum(axis=-2), axis=-1)
    hxy = entropy_nats(h.reshape(*h.shape[:-2], -1), axis=-1)
    return hx + hy - hxy


def mutual_information(x: np.ndarray, y: np.ndarray, bins: int = DEFAULT_BINS,
                       mask: np.ndarray | None = None) -> float:
    """Mutual information (Eq 3.2-3.4, nats) of two equally shaped grey frames over the pixels
    of ``mask`` (default all), each quantised into ``bins`` levels over its own range."""
    bins = check_bins(bins)
    a, b = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if a.shape != b.shape:
        raise VisionInputError(f"frames differ in shape: {a.shape} vs {b.shape}", "moving")
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != a.shape:
            raise VisionInputError(f"mask shape {m.shape} differs from the frames' {a.shape}", "mask")
        a, b = a[m], b[m]
    if a.size == 0:
        raise VisionInputError("no pixels to compare", "mask")
    return float(mutual_information_from_histogram(joint_histogram(quantize(a, bins), quantize(b, bins), bins)))


def independence_bias_nats(occupied_x: int, occupied_y: int, pixels: int) -> float:
    """First-order mean of the plug-in MI of two independent images (module doc):
    (B_x - 1)(B_y - 1) / (2 N) nats."""
    return (occupied_x - 1) * (occupied_y - 1) / (2.0 * pixels)
