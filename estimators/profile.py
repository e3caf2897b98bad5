"""The estimators' input: a multipath channel profile.

A profile is the discrete channel impulse response of docs/api.md,

    h(t) = sum_k a_k delta(t - tau_k),        H(f) = sum_k a_k exp(-j 2 pi f tau_k),

with absolute delays ``tau_k`` (seconds, never shifted to make the first path
zero) and complex gains ``a_k``. Optionally each path also carries its gain at
a set of band frequencies (frequency-dependent tissue properties), in which
case H(f_i) = sum_k b_k(f_i) exp(-j 2 pi f_i tau_k).

Phase convention (important, and explicit because a silent double count of
the propagation phase would shift every carrier-phase estimate):

* ``gains_include_delay_phase=False`` (default, the docs/api.md h(t) convention):
  ``gains`` / ``band_gains`` exclude the propagation phase exp(-j 2 pi f tau_k);
  it is carried by the delay. Reflection-coefficient phases and the like stay
  in the gain.
* ``gains_include_delay_phase=True``: the gains already contain
  exp(-j 2 pi f tau_k) -- ``gains`` evaluated at ``reference_frequency_hz``
  (required) and ``band_gains`` at their own frequencies. The profile converts
  them to the default convention on construction (``baseband_gains`` /
  ``baseband_band_gains``), so every estimator sees one convention.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._checks import finite_float
from .errors import EstimatorInputError

MAX_PATHS = 100_000


def _as_array(value, name: str, dtype) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError):
        raise EstimatorInputError(f"must be an array of numbers, got {type(value).__name__}", name) from None
    return arr


@dataclass(frozen=True)
class PathProfile:
    """Validated multipath profile (see module docstring for the phase convention).

    Attributes:
        delays_s: (K,) absolute path delays, finite and >= 0.
        gains: (K,) complex path gains a_k (not all zero).
        band_frequencies_hz: optional (F,) strictly increasing, > 0.
        band_gains: optional (K, F) complex per-path gains at those frequencies.
        gains_include_delay_phase: see module docstring.
        reference_frequency_hz: frequency at which ``gains`` were evaluated
            (required when ``gains_include_delay_phase``).

    Raises:
        EstimatorInputError naming ``profile.paths`` / ``profile.paths.delay_s`` /
        ``profile.paths.gain`` / ``profile.band_gains`` ... on an empty profile,
        non-finite numbers, negative delays or shape mismatches.
    """

    delays_s: np.ndarray
    gains: np.ndarray
    band_frequencies_hz: np.ndarray | None = None
    band_gains: np.ndarray | None = None
    gains_include_delay_phase: bool = False
    reference_frequency_hz: float | None = None
    baseband_gains: np.ndarray = field(init=False, repr=False, compare=False)
    baseband_band_gains: np.ndarray | None = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        delays = _as_array(self.delays_s, "profile.paths.delay_s", float)
        if delays.ndim > 1:
            raise EstimatorInputError("must be a 1-D array of delays", "profile.paths.delay_s")
        delays = delays.reshape(-1)
        gains = _as_array(self.gains, "profile.paths.gain", complex)
        if gains.ndim > 1:
            raise EstimatorInputError("must be a 1-D array of complex gains", "profile.paths.gain")
        gains = gains.reshape(-1)
        if delays.size == 0:
            raise EstimatorInputError("profile has no paths (at least one path is required)", "profile.paths")
        if delays.size > MAX_PATHS:
            raise EstimatorInputError(f"at most {MAX_PATHS} paths, got {delays.size}", "profile.paths")
        if gains.size != delays.size:
            raise EstimatorInputError(
                f"{gains.size} gains for {delays.size} delays (one gain per path)", "profile.paths.gain")
        bad = np.flatnonzero(~np.isfinite(delays))
        if bad.size:
            raise EstimatorInputError("must be finite", f"profile.paths[{bad[0]}].delay_s")
        bad = np.flatnonzero(delays < 0.0)
        if bad.size:
            raise EstimatorInputError(f"must be >= 0 (absolute delay), got {delays[bad[0]]!r}",
                                      f"profile.paths[{bad[0]}].delay_s")
        bad = np.flatnonzero(~np.isfinite(gains))
        if bad.size:
            raise EstimatorInputError("must be finite", f"profile.paths[{bad[0]}].gain")
        if not np.any(gains != 0):
            raise EstimatorInputError("every path gain is zero: no signal to range on", "profile.paths.gain")

        ref = self.reference_frequency_hz
        if ref is not None:
            ref = finite_float(ref, "profile.reference_frequency_hz", positive=True)
        if self.gains_include_delay_phase and ref is None:
            raise EstimatorInputError(
                "required when gains_include_delay_phase is true (the frequency the gains were evaluated at)",
                "profile.reference_frequency_hz")

        freqs = band = None
        if (self.band_frequencies_hz is None) != (self.band_gains is None):
            raise EstimatorInputError("band_frequencies_hz and band_gains must be given together",
                                      "profile.band_gains")
        if self.band_frequencies_hz is not None:
            freqs = _as_array(self.band_frequencies_hz, "profile.band_frequencies_hz", float)
            if freqs.ndim != 1 or freqs.size == 0:
                raise EstimatorInputError("must be a non-empty 1-D array", "profile.band_frequencies_hz")
            if not np.all(np.isfinite(freqs)) or np.any(freqs <= 0):
                raise EstimatorInputError("must be finite and > 0", "profile.band_frequencies_hz")
            if freqs.size > 1 and np.any(np.diff(freqs) <= 0):
                raise EstimatorInputError("must be strictly increasing", "profile.band_frequencies_hz")
            band = _as_array(self.band_gains, "profile.band_gains", complex)
            if band.shape != (delays.size, freqs.size):
                raise EstimatorInputError(
                    f"shape {band.shape} does not match (paths, frequencies) = ({delays.size}, {freqs.size})",
                    "profile.band_gains")
            if not np.all(np.isfinite(band)):
                k, i = np.argwhere(~np.isfinite(band))[0]
                raise EstimatorInputError("must be finite", f"profile.paths[{k}].band_gains[{i}]")

        object.__setattr__(self, "delays_s", delays)
        object.__setattr__(self, "gains", gains)
        object.__setattr__(self, "band_frequencies_hz", freqs)
        object.__setattr__(self, "band_gains", band)
        object.__setattr__(self, "reference_frequency_hz", ref)
        if self.gains_include_delay_phase:
            base = gains * np.exp(2j * np.pi * ref * delays)
            base_band = None if band is None else band * np.exp(2j * np.pi * freqs[None, :] * delays[:, None])
        else:
            base, base_band = gains, band
        object.__setattr__(self, "baseband_gains", base)
        object.__setattr__(self, "baseband_band_gains", base_band)

    # ------------------------------------------------------------------ derived
    @property
    def first_path_delay_s(self) -> float:
        """Earliest path delay (the geometric TOA target of a ranging method)."""
        return float(self.delays_s.min())

    @property
    def gain_scale(self) -> float:
        """Largest |gain| over paths (and band gains): divide by it to work at unit scale."""
        scale = float(np.max(np.abs(self.baseband_gains)))
        if self.baseband_band_gains is not None:
            scale = max(scale, float(np.max(np.abs(self.baseband_band_gains))))
        return scale

    @property
    def path_gain_db(self) -> float:
        """Total power gain 10 log10(sum_k |a_k|^2) (incoherent sum); path loss is its negative.

        Computed as 20 log10(max |a|) + 10 log10(sum (|a| / max |a|)^2), so gains
        near the float limits (1e-300, 1e300) neither underflow nor overflow.
        """
        mag = np.abs(self.gains)
        peak = float(mag.max())
        return float(20.0 * np.log10(peak) + 10.0 * np.log10(np.sum((mag / peak) ** 2)))

    def frequency_response(self, frequencies_hz, normalise: bool = False) -> np.ndarray:
        """Channel transfer function H(f) at ``frequencies_hz`` (complex, same shape).

        Without band gains: H(f) = sum_k a_k exp(-j 2 pi f tau_k) (a_k in the
        default convention). With band gains: H(f) = sum_k b_k(f) exp(-j 2 pi f tau_k),
        where b_k(f) (default convention, i.e. with the fast delay phase removed,
        so it varies slowly with f) is linearly interpolated between the band
        frequencies; asking outside the band raises EstimatorInputError.
        ``normalise`` divides every gain by :attr:`gain_scale` first (for
        scale-free estimators, immune to overflow/underflow).
        """
        f = _as_array(frequencies_hz, "frequencies_hz", float)
        if not np.all(np.isfinite(f)) or np.any(f <= 0):
            raise EstimatorInputError("must be finite and > 0", "frequencies_hz")
        shape = f.shape
        f = f.reshape(-1)
        phase = np.exp(-2j * np.pi * f[None, :] * self.delays_s[:, None])  # (K, F)
        scale = self.gain_scale if normalise else 1.0
        if self.baseband_band_gains is None:
            h = (self.baseband_gains / scale) @ phase
        else:
            bf = self.band_frequencies_hz
            tol = 1e-9 * bf[-1]
            if np.any(f < bf[0] - tol) or np.any(f > bf[-1] + tol):
                raise EstimatorInputError(
                    f"outside the profile's band [{bf[0]:.6g}, {bf[-1]:.6g}] Hz (per-frequency gains are "
                    "only known inside it)", "frequencies_hz")
            band = self.baseband_band_gains / scale
            if bf.size == 1:
                b = np.repeat(band, f.size, axis=1)
            else:
                hi = np.clip(np.searchsorted(bf, f, side="left"), 1, bf.size - 1)
                lo = hi - 1
                w = np.clip((f - bf[lo]) / (bf[hi] - bf[lo]), 0.0, 1.0)
                b = band[:, lo] * (1.0 - w) + band[:, hi] * w
            h = np.sum(b * phase, axis=0)
        return h.reshape(shape)


def single_path(delay_s: float, gain: complex = 1.0) -> PathProfile:
    """Convenience: a one-path (line-of-sight) profile."""
    return PathProfile(np.array([delay_s]), np.array([gain], dtype=complex))
