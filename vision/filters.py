"""Pre-processing of capsule frames: grey levels and the 2-D Butterworth low-pass (thesis Eq 3.1).

The thesis (Section 3.2.1) smooths every frame before the mutual information is computed: it
transforms the frame to the frequency domain, multiplies it by a 2-D Butterworth low-pass and
transforms it back. Eq 3.1 gives the filter's squared magnitude

    G^2(w) = |H(w)|^2 = 1 / (1 + (w / w_c)^(2 n))

with ``w`` the radial spatial frequency, ``w_c`` the cut-off (pass band) and ``n`` the order, so
the filter applied to the spectrum is the zero-phase ``H(w) = (1 + (w / w_c)^(2 n))^(-1/2)``
(-3 dB at ``w_c``). Frequencies here are in cycles per pixel (Nyquist = 0.5).

The discrete Fourier transform treats a frame as periodic; the frame is padded by reflection
(``pad_px``, default a few cut-off wavelengths) before the transform and cropped after, so the
left edge does not bleed into the right one. The transforms run in single precision on the frame
less its mean (H(0) = 1 passes the mean exactly): a relative error ~1e-7 of the frame's range,
far below an 8-bit grey level, at less than half the cost of double precision.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import scipy.fft

from .errors import VisionInputError

#: Default cut-off [cycles/pixel]: keeps structures wider than ~7 px, removes pixel noise
#: (the salt-and-pepper case of the thesis' Fig 3.1).
DEFAULT_CUTOFF = 0.15
#: Default order n of Eq 3.1.
DEFAULT_ORDER = 2

#: ITU-R BT.601 luma weights (R, G, B).
_LUMA = np.array([0.299, 0.587, 0.114])


def to_grey(image: np.ndarray, field: str = "image") -> np.ndarray:
    """A frame as a float64 grey-level array (H, W): grey frames as they are, RGB(A) by the
    BT.601 luma of their first three channels. Raises :class:`VisionInputError` naming ``field``
    for anything that is not a finite 2-D frame of at least 8 x 8 pixels."""
    a = np.asarray(image)
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.number)):
        raise VisionInputError(f"must be a numeric image array, got dtype {a.dtype}", field)
    if a.ndim == 3 and a.shape[2] in (3, 4):
        a = a[..., :3].astype(float) @ _LUMA
    elif a.ndim != 2:
        raise VisionInputError(f"must be a grey (H, W) or colour (H, W, 3|4) image, got shape {a.shape}", field)
    a = a.astype(float, copy=False)
    if min(a.shape) < 8:
        raise VisionInputError(f"must be at least 8 x 8 pixels, got {a.shape[1]} x {a.shape[0]}", field)
    if not np.isfinite(a).all():
        raise VisionInputError("must hold finite values only", field)
    return a


def butterworth_response(shape: tuple[int, int], cutoff: float, order: int) -> np.ndarray:
    """H(w) = (1 + (w / cutoff)^(2 order))^(-1/2) on the ``rfft2`` frequency grid of ``shape``
    (Eq 3.1 is |H|^2), ``w = sqrt(fx^2 + fy^2)`` in cycles per pixel."""
    fy = scipy.fft.fftfreq(shape[0])[:, None]
    fx = scipy.fft.rfftfreq(shape[1])[None, :]
    w2 = (fx * fx + fy * fy) / (cutoff * cutoff)
    return 1.0 / np.sqrt(1.0 + w2**order)


@functools.lru_cache(maxsize=4)  # bounded: ~9 MB for a 2048 px frame
def _response32(shape: tuple[int, int], cutoff: float, order: int) -> np.ndarray:
    """:func:`butterworth_response` in single precision, once per (shape, cutoff, order)."""
    out = butterworth_response(shape, cutoff, order).astype(np.float32)
    out.flags.writeable = False
    return out


def butterworth_lowpass(image: np.ndarray, cutoff: float = DEFAULT_CUTOFF, order: int = DEFAULT_ORDER,
                        pad_px: int | None = None) -> np.ndarray:
    """The frame low-passed by the 2-D Butterworth filter of Eq 3.1 (zero phase, applied as
    FFT -> multiply by H -> inverse FFT, module doc).

    ``cutoff``: w_c in cycles per pixel, in (0, 0.5 * sqrt(2)]; ``order``: n >= 1.
    ``pad_px``: reflection padding on every side (default ``ceil(2 / cutoff)``, two cut-off
    wavelengths, capped by the frame size). Grey (H, W) frames only; see :func:`to_grey`.
    """
    if not (isinstance(cutoff, (int, float)) and 0.0 < float(cutoff) <= 0.5 * math.sqrt(2.0)):
        raise VisionInputError(f"must be in (0, 0.707] cycles/pixel, got {cutoff!r}", "cutoff")
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or not 1 <= order <= 16:
        raise VisionInputError(f"must be an integer in [1, 16], got {order!r}", "order")
    a = np.asarray(image, dtype=float)
    if a.ndim != 2:
        raise VisionInputError(f"must be a grey (H, W) image, got shape {a.shape}", "image")
    if pad_px is None:
        pad_px = int(math.ceil(2.0 / cutoff))
    pad = int(min(max(pad_px, 0), a.shape[0] - 1, a.shape[1] - 1))
    mean = float(a.mean())
    padded = np.pad((a - mean).astype(np.float32), pad, mode="reflect") if pad else (a - mean).astype(np.float32)
    shape = (scipy.fft.next_fast_len(padded.shape[0], real=True), scipy.fft.next_fast_len(padded.shape[1], real=True))
    spectrum = scipy.fft.rfft2(padded, s=shape)
    spectrum *= _response32(shape, float(cutoff), int(order))
    out = scipy.fft.irfft2(spectrum, s=shape)
    return out[pad:pad + a.shape[0], pad:pad + a.shape[1]].astype(np.float64) + mean
