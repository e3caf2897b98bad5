"""The estimators' input: a multipath channel profile.

A profile is the discrete channel impulse response of docs/api.md,

    h(t) = sum_k a_k delta(t - tau_k),        H(f) = sum_k a_k exp(-j 2 pi f tau_k),

with absolute delays ``tau_k`` (seconds, never shifted to make the first path
zero) and complex gains ``a_k``. In dispersive tissue a path's gain depends on
frequency, H(f) = sum_k b_k(f) exp(-j 2 pi f tau_k) with b_k(f) slowly varying
(the fast propagation phase is carried by tau_k, the phase delay). The
profile knows b_k(f) from the best data it holds, and says which
(:attr:`PathProfile.channel_model`, docs/science.md "Waveforms through the channel"):

* ``"band_gains"``: each path's gain at a set of band frequencies (the tracer's
  band mode: dispersive tissue, Fresnel coefficients and absorption re-evaluated
  at every frequency). Inside the band b_k is interpolated linearly between
  the band frequencies; outside it (only on request, ``extrapolate=True``: a
  waveform's spectrum has no edge) it is continued to first order from the
  nearest band edge, ln b_k(f) = ln b_k(f_e) + (f - f_e) d ln b_k / df with the
  edge interval's slope: its phase slope is the edge's group delay; its
  log-magnitude slope (absorption growing with frequency) is followed for one
  band span beyond the edge and held after that, so that a waveform's far
  spectral tails meet neither a gain growing without bound nor a cut.
* ``"group_delay"``: each path's group delay ``group_delays_s`` (the tracer's
  ``group_delay_s``) beside its phase delay, no band: the first-order model
  b_k(f) = a_k exp(-j 2 pi (f - f0) (tau_g,k - tau_k)), f0 the reference
  frequency. A pulse's envelope then arrives at tau_g,k and its carrier phase
  is that of tau_k (docs/science.md (S21)-(S22)).
* ``"non_dispersive"``: delays and gains only, b_k(f) = a_k at every frequency
  (a hand-made profile; today's model).

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
_CHUNK_ELEMENTS = 1 << 21  # paths x frequencies evaluated at once (bounded memory)
_TINY = np.finfo(float).tiny  # a zero band gain's magnitude in logarithms


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
            (required when ``gains_include_delay_phase`` or ``group_delays_s``).
        group_delays_s: optional (K,) absolute group delays (finite): the
            first-order dispersive model of the module docstring. A traced path's is the
            phase slope of its gain, which a dipole's reactive near field can turn negative
            (a few cm apart in fat at 402 MHz; docs/science.md (S22)).

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
    group_delays_s: np.ndarray | None = None
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

        group = None
        if self.group_delays_s is not None:
            group = _as_array(self.group_delays_s, "profile.paths.group_delay_s", float).reshape(-1)
            if group.size != delays.size:
                raise EstimatorInputError(f"{group.size} group delays for {delays.size} paths (one per path)",
                                          "profile.paths.group_delay_s")
            bad = np.flatnonzero(~np.isfinite(group))
            if bad.size:
                raise EstimatorInputError(f"must be finite, got {group[bad[0]]!r}",
                                          f"profile.paths[{bad[0]}].group_delay_s")
            if ref is None:
                raise EstimatorInputError(
                    "required with group delays (the frequency at which delay_s is the phase delay and the "
                    "group delays were taken)", "profile.reference_frequency_hz")

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
        object.__setattr__(self, "group_delays_s", group)
        if self.gains_include_delay_phase:
            base = gains * np.exp(2j * np.pi * ref * delays)
            base_band = None if band is None else band * np.exp(2j * np.pi * freqs[None, :] * delays[:, None])
        else:
            base, base_band = gains, band
        object.__setattr__(self, "baseband_gains", base)
        object.__setattr__(self, "baseband_band_gains", base_band)

    # ------------------------------------------------------------------ derived
    @classmethod
    def from_traced(cls, paths, reference_frequency_hz: float, band_frequencies_hz=None) -> "PathProfile":
        """The profile of a tracer's paths (objects with ``delay_s``, ``group_delay_s``, ``gain``
        and ``band_gains``, as ``raytrace.Path``; no import of the tracer here): their gains
        carry the propagation phase at ``reference_frequency_hz``, band gains are used when
        ``band_frequencies_hz`` is given and every path has them, and group delays always."""
        paths = list(paths)
        band = None
        if band_frequencies_hz is not None and paths and all(p.band_gains is not None for p in paths):
            band = [p.band_gains for p in paths]
        return cls([p.delay_s for p in paths], [p.gain for p in paths],
                   band_frequencies_hz=None if band is None else band_frequencies_hz, band_gains=band,
                   gains_include_delay_phase=True, reference_frequency_hz=float(reference_frequency_hz),
                   group_delays_s=[p.group_delay_s for p in paths])

    @property
    def first_path_delay_s(self) -> float:
        """Earliest path delay (the geometric TOA target of a ranging method)."""
        return float(self.delays_s.min())

    @property
    def gain_scale(self) -> float:
        """Largest |Re| or |Im| of a gain over paths (and band gains): divide by it to work at unit
        scale. Within sqrt(2) of the largest |gain|, and finite for every finite gain (|1e308 +
        1e308 j| is not)."""
        def largest(g: np.ndarray) -> float:
            return float(max(np.max(np.abs(g.real)), np.max(np.abs(g.imag))))

        scale = largest(self.baseband_gains)
        if self.baseband_band_gains is not None:
            scale = max(scale, largest(self.baseband_band_gains))
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

    @property
    def channel_model(self) -> str:
        """Which b_k(f) the profile evaluates (module docstring): ``"band_gains"``,
        ``"group_delay"`` or ``"non_dispersive"``."""
        if self.baseband_band_gains is not None:
            return "band_gains"
        if self.group_delays_s is not None:
            return "group_delay"
        return "non_dispersive"

    def band_coverage(self, frequencies_hz, weights) -> float | None:
        """Share of ``weights`` (e.g. a spectrum's energy per frequency) at frequencies inside the
        profile's band; None without band gains (the model then holds at every frequency)."""
        if self.band_frequencies_hz is None:
            return None
        f = np.asarray(frequencies_hz, float)
        w = np.asarray(weights, float)
        total = float(np.sum(w))
        if not total > 0.0:
            return None
        bf = self.band_frequencies_hz
        tol = 1e-9 * bf[-1]
        return float(np.sum(w[(f >= bf[0] - tol) & (f <= bf[-1] + tol)]) / total)

    def path_responses(self, frequencies_hz: np.ndarray, paths: slice = slice(None), *, extrapolate: bool = False,
                       scale: float = 1.0) -> np.ndarray:
        """b_k(f) / ``scale`` of the paths ``paths`` at ``frequencies_hz`` (1-D; not checked here):
        shape (K, F), the delay phase exp(-j 2 pi f tau_k) excluded (module docstring).

        Outside the band of a ``"band_gains"`` profile it raises unless ``extrapolate``
        (first-order continuation from the nearest edge, module docstring).
        """
        f = np.asarray(frequencies_hz, float).reshape(-1)
        a = self.baseband_gains[paths] / scale
        model = self.channel_model
        if model == "non_dispersive":
            return np.repeat(a[:, None], f.size, axis=1)
        tau = self.delays_s[paths]
        if model == "group_delay":
            extra = self.group_delays_s[paths] - tau
            return a[:, None] * np.exp(-2j * np.pi * (f - self.reference_frequency_hz)[None, :] * extra[:, None])
        bf = self.band_frequencies_hz
        band = self.baseband_band_gains[paths] / scale
        tol = 1e-9 * bf[-1]
        below, above = f < bf[0] - tol, f > bf[-1] + tol
        if (below.any() or above.any()) and not extrapolate:
            raise EstimatorInputError(
                f"outside the profile's band [{bf[0]:.6g}, {bf[-1]:.6g}] Hz (per-frequency gains are "
                "only known inside it)", "frequencies_hz")
        if bf.size == 1:  # one frequency: the phase continues with the group delay's slope
            rate, _ = self.edge_rates(paths)
            return band * np.exp(rate[:, None] * (f - bf[0])[None, :])
        hi = np.clip(np.searchsorted(bf, f, side="left"), 1, bf.size - 1)
        lo = hi - 1
        w = np.clip((f - bf[lo]) / (bf[hi] - bf[lo]), 0.0, 1.0)
        b = band[:, lo] * (1.0 - w) + band[:, hi] * w
        if below.any() or above.any():
            rate_lo, rate_hi = self.edge_rates(paths)
            b[:, below] = band[:, :1] * np.exp(self._continuation(rate_lo, f[below] - bf[0]))
            b[:, above] = band[:, -1:] * np.exp(self._continuation(rate_hi, f[above] - bf[-1]))
        return b

    @property
    def continuation_span_hz(self) -> float:
        """How far beyond its band a ``band_gains`` profile continues each path's log-magnitude
        slope: one band span (beyond it, the magnitude is held and only the phase continues)."""
        bf = self.band_frequencies_hz
        return float(bf[-1] - bf[0])

    def _continuation(self, rate: np.ndarray, df: np.ndarray) -> np.ndarray:
        """ln(b(f_e + df) / b(f_e)) of the first-order continuation (module docstring)."""
        span = self.continuation_span_hz
        return (rate.real[:, None] * np.clip(df, -span, span)[None, :]
                + 1j * rate.imag[:, None] * df[None, :])

    def edge_rates(self, paths: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """d ln b_k / df [1/Hz] (real part: log-magnitude slope, imaginary: phase slope) with which
        a ``band_gains`` profile continues each path below and above its band: the first and
        last band interval's, or with one band frequency -j 2 pi (tau_g,k - tau_k) from the
        group delays (0 without)."""
        band = self.baseband_band_gains[paths]
        bf = self.band_frequencies_hz
        if bf.size == 1:
            rate = (np.zeros(band.shape[0], complex) if self.group_delays_s is None
                    else -2j * np.pi * (self.group_delays_s[paths] - self.delays_s[paths]))
            return rate, rate

        def log_ratio(hi_col, lo_col):
            mag = np.log(np.maximum(np.abs(hi_col), _TINY) / np.maximum(np.abs(lo_col), _TINY))
            return mag + 1j * np.angle(hi_col * np.conj(lo_col))

        return (log_ratio(band[:, 1], band[:, 0]) / (bf[1] - bf[0]),
                log_ratio(band[:, -1], band[:, -2]) / (bf[-1] - bf[-2]))

    def frequency_response(self, frequencies_hz, normalise: bool = False, extrapolate: bool = False) -> np.ndarray:
        """Channel transfer function H(f) = sum_k b_k(f) exp(-j 2 pi f tau_k) at ``frequencies_hz``
        (complex, same shape), with b_k(f) from :attr:`channel_model` (module docstring).

        Without band gains or group delays: H(f) = sum_k a_k exp(-j 2 pi f tau_k) (a_k in the
        default convention). With band gains, b_k(f) (default convention, i.e. with the fast
        delay phase removed, so it varies slowly with f) is linearly interpolated between the
        band frequencies; asking outside the band raises EstimatorInputError unless
        ``extrapolate``. ``normalise`` divides every gain by :attr:`gain_scale` first (for
        scale-free estimators, immune to overflow/underflow).
        """
        f = _as_array(frequencies_hz, "frequencies_hz", float)
        if not np.all(np.isfinite(f)) or np.any(f <= 0):
            raise EstimatorInputError("must be finite and > 0", "frequencies_hz")
        shape = f.shape
        f = f.reshape(-1)
        scale = self.gain_scale if normalise else 1.0
        if self.channel_model == "non_dispersive":
            phase = np.exp(-2j * np.pi * f[None, :] * self.delays_s[:, None])  # (K, F)
            return ((self.baseband_gains / scale) @ phase).reshape(shape)
        h = np.zeros(f.size, complex)
        chunk = max(1, _CHUNK_ELEMENTS // max(f.size, 1))
        for start in range(0, self.delays_s.size, chunk):
            sl = slice(start, start + chunk)
            b = self.path_responses(f, sl, extrapolate=extrapolate, scale=scale)
            h += np.sum(b * np.exp(-2j * np.pi * f[None, :] * self.delays_s[sl, None]), axis=0)
        return h.reshape(shape)


def single_path(delay_s: float, gain: complex = 1.0) -> PathProfile:
    """Convenience: a one-path (line-of-sight) profile."""
    return PathProfile(np.array([delay_s]), np.array([gain], dtype=complex))
