"""A capsule's journey along a centreline: arc length over time, with stops, peristaltic
back-and-forth and roll, from a seed (docs/tracking.md, "The journey").

Motion model, per step k of ``dt_s`` (k = 0 .. steps - 1, t_k = k dt):

* **Propulsion.** A two-state chain, moving or stopped: a moving capsule stops with probability
  ``dt / mean_move_s`` per step and a stopped one starts again with probability
  ``dt / mean_stop_s``. While moving it advances at ``mean_speed_m_per_s * g_k``, where
  ``g_k >= 0`` is a log-normal gain following an AR(1) process in its logarithm (correlation time
  ``speed_correlation_s``, spread ``speed_variation``); stopped, it does not advance.
* **Peristalsis.** On top, a back-and-forth oscillation ``A sin(2 pi t / T + phi)`` of amplitude
  ``peristalsis_amplitude_m`` and period ``peristalsis_period_s`` (phase phi from the seed),
  going on through the stops: the capsule is pushed and pulled back by the contractions, so the
  arc length runs backwards part of the time.
* **Roll** about the capsule's long axis: a random walk of ``roll_step_deg`` per step.

``s`` is kept inside ``[0, length]`` of the centreline (clipped). At step k the position is
``line.point_m(s_k)`` (the capsule on the centreline) and the organ ``line.organ_at(s_k)``.

Deterministic: the same spec and centreline give the same journey (``numpy.random.default_rng(seed)``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from .errors import TrackingInputError

__all__ = ["MAX_STEPS", "Journey", "JourneySpec", "simulate_journey"]

#: Most steps of one journey (work bound: each step may cost a trace and a rendered frame).
MAX_STEPS = 5000

_BOUNDS = {  # field: (low, high, low inclusive)
    "dt_s": (1e-3, 60.0, False),
    "mean_speed_m_per_s": (0.0, 0.05, True),
    "speed_variation": (0.0, 2.0, True),
    "speed_correlation_s": (1e-3, 3600.0, False),
    "mean_move_s": (1e-3, 1e5, False),
    "mean_stop_s": (1e-3, 1e5, False),
    "peristalsis_amplitude_m": (0.0, 0.05, True),
    "peristalsis_period_s": (0.1, 3600.0, False),
    "roll_step_deg": (0.0, 45.0, True),
}


@dataclass(frozen=True)
class JourneySpec:
    """Parameters of :func:`simulate_journey` (module docstring). Defaults: 2 frames per second
    (a capsule camera's rate), 1.5 mm/s of propulsion, stops of 6 s on average every 20 s of
    motion, +-1.5 mm of peristalsis every 8 s, 3 deg of roll per frame, from 0.20 m (the small
    intestine of the default torso). The propulsion is faster than a real capsule's (about
    0.3-1 mm/s in the small bowel) so that a few hundred frames cross organs; the advance per frame
    stays below 2 mm (half the small bowel's fold spacing, docs/vision.md)."""

    steps: int = 400
    seed: int = 0
    dt_s: float = 0.5
    start_m: float = 0.20
    mean_speed_m_per_s: float = 1.5e-3
    speed_variation: float = 0.3
    speed_correlation_s: float = 5.0
    mean_move_s: float = 20.0
    mean_stop_s: float = 6.0
    peristalsis_amplitude_m: float = 1.5e-3
    peristalsis_period_s: float = 8.0
    roll_step_deg: float = 3.0

    def __post_init__(self) -> None:
        for name in ("steps", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise TrackingInputError(f"must be an integer, got {v!r}", f"journey.{name}")
        if not 2 <= self.steps <= MAX_STEPS:
            raise TrackingInputError(f"must be in [2, {MAX_STEPS}], got {self.steps}", "journey.steps")
        if not 0 <= self.seed < 2**63:
            raise TrackingInputError(f"must be a non-negative integer, got {self.seed}", "journey.seed")
        for name, (lo, hi, closed) in _BOUNDS.items():
            v = getattr(self, name)
            ok = isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool) \
                and math.isfinite(v) and (lo <= v if closed else lo < v) and v <= hi
            if not ok:
                raise TrackingInputError(f"must be a number in {'[' if closed else '('}{lo:g}, {hi:g}], got {v!r}",
                                         f"journey.{name}")
        if isinstance(self.start_m, bool) or not isinstance(self.start_m, (int, float, np.floating, np.integer)) \
                or not math.isfinite(self.start_m) or self.start_m < 0:
            raise TrackingInputError(f"must be a non-negative arc length [m], got {self.start_m!r}",
                                     "journey.start_m")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict | None) -> "JourneySpec":
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        extra = sorted(set(data) - known)
        if extra:
            raise TrackingInputError(f"unknown field; one of {', '.join(sorted(known))}", f"journey.{extra[0]}")
        return cls(**data)


@dataclass(frozen=True)
class Journey:
    """The ground truth: per step ``t_s``, ``s_m``, ``roll_deg``, ``position_m`` (steps, 3),
    ``organ`` (names), ``moving`` (the propulsion's state), and the spec."""

    spec: JourneySpec
    t_s: np.ndarray
    s_m: np.ndarray
    roll_deg: np.ndarray
    position_m: np.ndarray
    organ: tuple[str, ...]
    moving: np.ndarray

    @property
    def advance_m(self) -> np.ndarray:
        """(steps - 1,) arc-length increments from each step to the next."""
        return np.diff(self.s_m)


def simulate_journey(line, spec: JourneySpec | None = None) -> Journey:
    """The journey of ``spec`` along ``line`` (a :class:`raytrace.body.centreline.Centreline`)."""
    spec = spec or JourneySpec()
    if spec.start_m > line.length_m:
        raise TrackingInputError(f"{spec.start_m:g} m is beyond the centreline's {line.length_m:.6g} m",
                                 "journey.start_m")
    rng = np.random.default_rng(spec.seed)
    n, dt = spec.steps, spec.dt_s
    t = dt * np.arange(n)
    p_stop = min(1.0, dt / spec.mean_move_s)
    p_go = min(1.0, dt / spec.mean_stop_s)
    rho = math.exp(-dt / spec.speed_correlation_s)
    sigma = spec.speed_variation
    u_switch = rng.random(n)
    eps = rng.standard_normal(n)
    phase = rng.uniform(0.0, 2.0 * math.pi)
    roll_steps = rng.normal(0.0, spec.roll_step_deg, n - 1) if spec.roll_step_deg > 0 else np.zeros(n - 1)

    moving = np.empty(n, bool)
    drift = np.empty(n)
    state, log_gain, s_drift = True, 0.0, 0.0
    for k in range(n):
        moving[k] = state
        drift[k] = s_drift
        # AR(1) in the log of the speed gain, stationary spread sigma, mean gain 1
        log_gain = rho * log_gain + sigma * math.sqrt(1.0 - rho * rho) * eps[k]
        if state:
            s_drift += spec.mean_speed_m_per_s * math.exp(log_gain - 0.5 * sigma * sigma) * dt
        state = (u_switch[k] >= p_stop) if state else (u_switch[k] < p_go)
    osc = spec.peristalsis_amplitude_m * (np.sin(2.0 * math.pi * t / spec.peristalsis_period_s + phase)
                                          - math.sin(phase))
    s = np.clip(spec.start_m + drift + osc, 0.0, line.length_m)
    roll = np.concatenate([[0.0], np.cumsum(roll_steps)])
    organ = line.organ_at(s)
    return Journey(spec=spec, t_s=t, s_m=s, roll_deg=roll, position_m=line.point_m(s),
                   organ=tuple(str(o) for o in organ), moving=moving)
