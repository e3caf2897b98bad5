"""What the trackers measure and what they report (docs/tracking.md, "Measurements").

Per time step an :class:`Observation`: the time ``t_s``, optionally an RF position fix
(:class:`RfFix`: a 3-D position and its covariance, e.g. ``PositionResult.position_m`` /
``covariance_m2`` of ``estimators.localization``, inflated by the fix's bias), and optionally the
visual motion since the previous step (:class:`VisualMotion`: the advance along the lumen from the
frame pair's MI scale, ``vision.advance.advance_for_scale``, and the roll about the optical axis,
each with its standard deviation). A :class:`Track` is a tracker's answer per step: arc length and
rate along the centreline, roll, the 3-D point with its covariance, each with an uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .errors import TrackingInputError

__all__ = ["MAX_OBSERVATIONS", "Observation", "RfFix", "Track", "TrackerConfig", "VisualMotion", "check_observations"]

#: Most observations one tracker call accepts (work bound).
MAX_OBSERVATIONS = 20_000


def _finite(value: Any, where: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not math.isfinite(value):
        raise TrackingInputError(f"must be a finite number, got {value!r}", where)
    if positive and value <= 0:
        raise TrackingInputError(f"must be > 0, got {value!r}", where)
    return float(value)


def _covariance(value, where: str, *, definite: bool) -> np.ndarray:
    c = np.asarray(value, dtype=float)
    if c.shape != (3, 3) or not np.isfinite(c).all():
        raise TrackingInputError("must be a 3 x 3 matrix of finite numbers [m^2]", where)
    if not np.allclose(c, c.T, rtol=1e-9, atol=1e-18):
        raise TrackingInputError("must be symmetric", where)
    sym = 0.5 * c + 0.5 * c.T  # halves first: c + c.T overflows for entries near 1e308
    eig = np.linalg.eigvalsh(sym)
    low = eig.min() if np.isfinite(eig).all() else -1.0  # NaN eigenvalues (entries near 1e308) fail too
    if (low <= 0) if definite else (low < -1e-12 * max(float(np.abs(eig).max()), 1e-300)):
        raise TrackingInputError("must be positive definite" if definite else "must be positive semi-definite",
                                 where)
    return sym


@dataclass(frozen=True)
class RfFix:
    """A 3-D position fix [m] and its 3 x 3 covariance [m^2] (symmetric positive definite): the
    fix's white error. Optionally ``bias_covariance_m2``: the stationary covariance of the part of
    its error that the fixes nearby share (the body's bias where the capsule is; measured per organ by
    evaluation.error_models), which the filters model as correlated along the tract when
    ``TrackerConfig.rf_correlation_length_m`` is set, and add to the white part when it is not."""

    position_m: np.ndarray
    covariance_m2: np.ndarray
    bias_covariance_m2: np.ndarray | None = None

    def checked(self, where: str) -> "RfFix":
        p = np.asarray(self.position_m, dtype=float)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise TrackingInputError("must be three finite coordinates [m]", f"{where}.position_m")
        c = _covariance(self.covariance_m2, f"{where}.covariance_m2", definite=True)
        b = None if self.bias_covariance_m2 is None else _covariance(
            self.bias_covariance_m2, f"{where}.bias_covariance_m2", definite=False)
        return RfFix(p, c, b)


@dataclass(frozen=True)
class VisualMotion:
    """Motion since the previous step from a frame pair: ``advance_m`` along the lumen (negative:
    backwards) with ``advance_sigma_m``; optionally the roll increment ``roll_deg`` about the
    optical axis with ``roll_sigma_deg``."""

    advance_m: float
    advance_sigma_m: float
    roll_deg: float | None = None
    roll_sigma_deg: float | None = None

    def checked(self, where: str) -> "VisualMotion":
        adv = _finite(self.advance_m, f"{where}.advance_m")
        sig = _finite(self.advance_sigma_m, f"{where}.advance_sigma_m", positive=True)
        if (self.roll_deg is None) != (self.roll_sigma_deg is None):
            missing = "roll_sigma_deg" if self.roll_sigma_deg is None else "roll_deg"
            raise TrackingInputError("roll_deg and roll_sigma_deg go together", f"{where}.{missing}")
        if self.roll_deg is None:
            return VisualMotion(adv, sig)
        return VisualMotion(adv, sig, _finite(self.roll_deg, f"{where}.roll_deg"),
                            _finite(self.roll_sigma_deg, f"{where}.roll_sigma_deg", positive=True))


@dataclass(frozen=True)
class Observation:
    """One time step: ``t_s``, an optional RF fix, an optional visual motion from the previous step
    (ignored at the first step, which has no previous frame)."""

    t_s: float
    rf: RfFix | None = None
    visual: VisualMotion | None = None


def check_observations(observations: Sequence[Observation], field_name: str = "observations") -> list[Observation]:
    """Validated copies; times strictly increasing; at most :data:`MAX_OBSERVATIONS`."""
    obs = list(observations)
    if not obs:
        raise TrackingInputError("give at least one observation", field_name)
    if len(obs) > MAX_OBSERVATIONS:
        raise TrackingInputError(f"at most {MAX_OBSERVATIONS} observations, got {len(obs)}", field_name)
    out = []
    last = -math.inf
    for i, o in enumerate(obs):
        where = f"{field_name}[{i}]"
        t = _finite(o.t_s, f"{where}.t_s")
        if t <= last:
            raise TrackingInputError(f"times must increase strictly; {t!r} s follows {last!r} s", f"{where}.t_s")
        last = t
        out.append(Observation(t, None if o.rf is None else o.rf.checked(f"{where}.rf"),
                               None if o.visual is None else o.visual.checked(f"{where}.visual")))
    return out


@dataclass(frozen=True)
class TrackerConfig:
    """Motion model and prior shared by the trackers (docs/tracking.md, "Trackers").

    The arc length moves with a continuous white-noise acceleration of power spectral density
    ``accel_psd_m2_per_s3`` (Bar-Shalom, Li & Kirubarajan 2001, Sec 6.2.2: over dt the state (s, v)
    gains the covariance q [[dt^3/3, dt^2/2], [dt^2/2, dt]]); the roll is a random walk of
    ``roll_psd_deg2_per_s`` (variance q_r dt per step). Prior at the first step: s ~ N(initial_s_m,
    initial_s_sigma_m^2), or, when ``initial_s_m`` is None, anywhere on the centreline (uniform for
    the particle filter; the Kalman filter takes its mean and variance, L/2 and L^2/12);
    v ~ N(initial_v_m_per_s, initial_v_sigma_m_per_s^2); roll starts at 0 +- initial_roll_sigma_deg.
    ``gate_probability``: the Kalman filter ignores an RF fix whose normalised innovation squared
    exceeds this quantile of chi-square(1) (None: never). ``visual_gate_probability``: likewise both
    filters ignore a visual advance whose innovation against the predicted advance (the Kalman
    filter's, or the particles' mean with their spread) exceeds this quantile (None, the default:
    never; a frame pair can be an outlier, e.g. a periodic fold texture aliased by one period,
    docs/tracking.md). ``lateral_sigma_m``: added isotropically
    to every fix's covariance in the particle filter's 3-D likelihood (the capsule's offset from the
    centreline inside the lumen).

    ``rf_correlation_length_m``: the length along the tract over which the fixes' bias decorrelates
    (the bias part of :class:`RfFix`): the filters carry it as a state, a Gauss-Markov process in
    the distance travelled (tracking.kalman, tracking.particle). None: every fix's error is white.
    A fix's error is mostly the body's bias at that position (heterogeneity, multipath), which the
    fixes of the next millimetres share; as independent measurements they would be counted many
    times over (a stopped capsule's repeated fixes would pull the filter to the bias).
    ``rf_min_spacing_m``: a fix is used only once the estimate, or the fix's own projection onto the
    line, has moved at least this far along the tract from the last used one (0: every fix). The
    bias model is first-order; the body's bias is smoother than that between positions a few
    millimetres apart, and fixes that close carry little new information anyway.
    ``speed_range_m_per_s``: (lowest, highest) speed along the tract the capsule can have; a visual
    advance outside [lowest dt, highest dt] is not a motion the capsule can make (a frame pair matched
    a fold period off, docs/tracking.md) and both filters drop it, whatever their prediction says.
    None: no such bound. ``max_consecutive_gated``: after this many consecutive fixes (or visual
    advances) refused by a gate, the next one is used with the state's variance widened to explain its innovation (the
    gate cannot starve a filter that has lost the capsule)."""

    accel_psd_m2_per_s3: float = 4e-6
    roll_psd_deg2_per_s: float = 20.0
    initial_s_m: float | None = None
    initial_s_sigma_m: float = 5e-3
    initial_v_m_per_s: float = 0.0
    initial_v_sigma_m_per_s: float = 3e-3
    initial_roll_sigma_deg: float = 1e-3
    gate_probability: float | None = 0.9999
    visual_gate_probability: float | None = None
    lateral_sigma_m: float = 0.0
    rf_correlation_length_m: float | None = None
    rf_min_spacing_m: float = 0.0
    speed_range_m_per_s: tuple[float, float] | None = None
    max_consecutive_gated: int = 5
    particles: int = 2000
    resample_fraction: float = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("accel_psd_m2_per_s3", "roll_psd_deg2_per_s", "initial_s_sigma_m", "initial_v_sigma_m_per_s",
                     "initial_roll_sigma_deg"):
            _finite(getattr(self, name), f"config.{name}", positive=True)
        _finite(self.initial_v_m_per_s, "config.initial_v_m_per_s")
        if self.initial_s_m is not None:
            _finite(self.initial_s_m, "config.initial_s_m")
        for name in ("gate_probability", "visual_gate_probability"):
            if getattr(self, name) is not None:
                g = _finite(getattr(self, name), f"config.{name}")
                if not 0.5 < g < 1.0:
                    raise TrackingInputError(f"must be in (0.5, 1), got {g!r}", f"config.{name}")
        if _finite(self.lateral_sigma_m, "config.lateral_sigma_m") < 0:
            raise TrackingInputError("must be >= 0", "config.lateral_sigma_m")
        if self.rf_correlation_length_m is not None \
                and not 1e-4 <= _finite(self.rf_correlation_length_m, "config.rf_correlation_length_m") <= 10.0:
            raise TrackingInputError("must be in [1e-4, 10] m", "config.rf_correlation_length_m")
        if not 0.0 <= _finite(self.rf_min_spacing_m, "config.rf_min_spacing_m") <= 1.0:
            raise TrackingInputError("must be in [0, 1] m", "config.rf_min_spacing_m")
        if self.speed_range_m_per_s is not None:
            try:
                lo, hi = (float(v) for v in self.speed_range_m_per_s)
            except (TypeError, ValueError):
                raise TrackingInputError("must be two numbers [m/s]", "config.speed_range_m_per_s") from None
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi and lo <= 0.0 <= hi <= 1.0 and lo >= -1.0):
                raise TrackingInputError("must be [lowest <= 0, highest >= 0] within [-1, 1] m/s",
                                         "config.speed_range_m_per_s")
            object.__setattr__(self, "speed_range_m_per_s", (lo, hi))
        if isinstance(self.max_consecutive_gated, bool) or not isinstance(self.max_consecutive_gated,
                                                                          (int, np.integer)) \
                or not 1 <= self.max_consecutive_gated <= 10_000:
            raise TrackingInputError(f"must be an integer in [1, 10000], got {self.max_consecutive_gated!r}",
                                     "config.max_consecutive_gated")
        if isinstance(self.particles, bool) or not isinstance(self.particles, (int, np.integer)) \
                or not 10 <= self.particles <= 200_000:
            raise TrackingInputError(f"must be an integer in [10, 200000], got {self.particles!r}", "config.particles")
        if not 0.0 < _finite(self.resample_fraction, "config.resample_fraction") <= 1.0:
            raise TrackingInputError("must be in (0, 1]", "config.resample_fraction")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise TrackingInputError(f"must be a non-negative integer, got {self.seed!r}", "config.seed")


@dataclass(frozen=True)
class Track:
    """A tracker's estimate per step (arrays of the observations' length).

    ``s_m`` / ``s_sigma_m``: arc length and its standard deviation; ``v_m_per_s`` / ``v_sigma_m_per_s``
    its rate; ``roll_deg`` / ``roll_sigma_deg``; ``position_m`` (n, 3) and ``position_cov_m2``
    (n, 3, 3): the 3-D point and its covariance (Kalman: the centreline point at s with
    var(s) t t^T, t the tangent; particle: the particles' points' weighted mean and covariance);
    ``rf_used``: whether the step's RF fix was used (False when absent or gated out);
    ``extra``: per step ``state_covariance`` (n, 3, 3) of (s, v, roll), ``nis_rf`` and
    ``nis_visual`` (the normalised innovation squared of the RF fix and of the visual advance used
    at that step, NaN where none; chi-square with ``nis_rf_dof`` and 1 degrees of freedom for a
    consistent filter), and tracker-specific arrays (the particle filter's ``ess``)."""

    tracker: str
    t_s: np.ndarray
    s_m: np.ndarray
    s_sigma_m: np.ndarray
    v_m_per_s: np.ndarray
    v_sigma_m_per_s: np.ndarray
    roll_deg: np.ndarray
    roll_sigma_deg: np.ndarray
    position_m: np.ndarray
    position_cov_m2: np.ndarray
    rf_used: np.ndarray
    extra: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: one entry per step."""
        return {"tracker": self.tracker, "steps": [
            {"t_s": float(self.t_s[k]), "s_m": float(self.s_m[k]), "s_sigma_m": float(self.s_sigma_m[k]),
             "v_m_per_s": float(self.v_m_per_s[k]), "v_sigma_m_per_s": float(self.v_sigma_m_per_s[k]),
             "roll_deg": float(self.roll_deg[k]), "roll_sigma_deg": float(self.roll_sigma_deg[k]),
             "position_m": self.position_m[k].tolist(), "position_cov_m2": self.position_cov_m2[k].tolist(),
             "rf_used": bool(self.rf_used[k])} for k in range(len(self.t_s))]}
