"""A channel profile as the figures read it: ``profiles[i]`` of POST /v1/channel as is, or hand-made.

Gains follow the API's convention (docs/service.md, "Gain convention"): a
channel profile's gains include the propagation phase exp(-j 2 pi f tau) at
``reference_frequency_hz`` (``gains_include_delay_phase: true``) and its
``band_gains`` at their own frequencies; a hand-made profile's do not.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from plots.figure import Data, PlotInputError

#: Most paths a figure accepts (the API's profile cap).
MAX_PATHS = 10_000
#: Most band frequencies per path.
MAX_BAND_POINTS = 1001
#: Most interactions per path (a channel request allows at most 10).
MAX_INTERACTIONS = 16
#: Bound on each gain component [-] (a passive channel has |a| <= 1; the service caps at 1e6 too).
MAX_GAIN = 1e6

Vec3 = list[float]


class GainData(Data):
    re: float = Field(ge=-MAX_GAIN, le=MAX_GAIN, description="Real part [-].")
    im: float = Field(ge=-MAX_GAIN, le=MAX_GAIN, description="Imaginary part [-].")


class BandGainData(Data):
    frequency_hz: float = Field(gt=0.0, le=1e12, description="Frequency [Hz].")
    gain: GainData


class InteractionData(Data):
    kind: Literal["reflection", "refraction", "total_internal_reflection"]
    point_m: Vec3 | None = Field(None, min_length=3, max_length=3, description="Where it happens [m].")


class PathData(Data):
    delay_s: float = Field(ge=0.0, le=1e-3, description="Absolute delay [s].")
    gain: GainData = Field(description="Complex gain at the carrier [-].")
    interactions: list[InteractionData] | None = Field(
        None, max_length=MAX_INTERACTIONS,
        description="Reflections / refractions along the path (their count colours the PDP).",
    )
    band_gains: list[BandGainData] | None = Field(None, max_length=MAX_BAND_POINTS)


class ProfileData(Data):
    paths: list[PathData] = Field(min_length=1, max_length=MAX_PATHS)
    receiver: str | None = Field(None, max_length=64)
    geometric_distance_m: float | None = Field(None, ge=0.0, le=100.0, description="Straight-line distance [m].")
    gains_include_delay_phase: bool = Field(
        False, description="true for profiles of POST /v1/channel (gains include exp(-j 2 pi f tau)).")
    reference_frequency_hz: float | None = Field(None, gt=0.0, le=1e12, description="Frequency of `gain` [Hz].")


def delays_s(profile: ProfileData) -> np.ndarray:
    return np.array([p.delay_s for p in profile.paths], float)


def gains(profile: ProfileData) -> np.ndarray:
    return np.array([complex(p.gain.re, p.gain.im) for p in profile.paths])


def band_gains(profile: ProfileData, field: str = "profile") -> tuple[np.ndarray, np.ndarray]:
    """(frequencies (F,) [Hz], per-path band gains (K, F)) from every path's ``band_gains``.

    Raises PlotInputError naming the first path without band gains or whose
    frequencies differ from the first path's."""
    first = profile.paths[0].band_gains
    if not first:
        raise PlotInputError("no band_gains: trace the channel with a `band`, or give `band` to use "
                             "frequency-flat path gains", f"{field}.paths[0].band_gains")
    freqs = np.array([b.frequency_hz for b in first], float)
    if freqs.size < 2 or np.any(np.diff(freqs) <= 0):
        raise PlotInputError("needs at least two strictly increasing frequencies", f"{field}.paths[0].band_gains")
    rows = []
    for k, path in enumerate(profile.paths):
        bg = path.band_gains
        if not bg:
            raise PlotInputError("missing (every path needs band_gains at the same frequencies)",
                                 f"{field}.paths[{k}].band_gains")
        f = np.array([b.frequency_hz for b in bg], float)
        if f.shape != freqs.shape or np.any(np.abs(f - freqs) > 1e-9 * freqs[-1]):
            raise PlotInputError("frequencies differ from paths[0]'s", f"{field}.paths[{k}].band_gains")
        rows.append([complex(b.gain.re, b.gain.im) for b in bg])
    return freqs, np.array(rows)
