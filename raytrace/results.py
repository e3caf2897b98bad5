"""Tracer outputs: interactions, segments, paths, per-receiver profiles.

The channel between the transmitter and one receiver is
``h(t) = sum_k a_k delta(t - tau_k)`` (``docs/api.md``): ``a_k`` is the
complex path gain, ``|a_k|^2`` the power transfer between the two antennas, so
that a free-space line of sight at distance d has ``|a| = lambda0 / (4 pi d)``
(Friis, isotropic antennas) and, inside a homogeneous lossless medium of
refractive index n, ``|a| = lambda0 / (4 pi n d)``. Delays are absolute.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

InteractionKind = Literal["reflection", "refraction", "total_internal_reflection"]


@dataclass(frozen=True, slots=True)
class Interaction:
    """One event along a path.

    ``from_medium`` is the medium the wave arrives in; ``to_medium`` is the
    medium on the far side of the surface (entered on refraction, not entered
    on reflection / total internal reflection).
    """

    kind: InteractionKind
    point_m: np.ndarray
    from_medium: str
    to_medium: str


@dataclass(frozen=True, slots=True)
class Segment:
    """A straight piece of a path inside one medium."""

    medium: str
    length_m: float
    start_m: np.ndarray | None = None  # segment end points (the tracer fills them)
    end_m: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class Path:
    """One propagation path from the transmitter to a receiver.

    ``delay_s`` is its phase delay at the carrier, ``sum L_i Re n_i / c``: what the carrier's
    phase (and so PDOA on a narrow band, or a gain's argument) sees. ``group_delay_s`` is its
    group delay, the phase slope ``-d arg(gain) / d w`` at the carrier with everything that varies
    with frequency (the tissues' group index, lossy Fresnel phases, the near field; docs/science.md (S22)):
    when a pulse's envelope arrives, what a TOA estimator on a band-limited waveform measures.
    In dispersive tissue the two differ by ~10 % (docs/science.md, "Phase and group delay").
    """

    delay_s: float
    group_delay_s: float
    gain: complex
    length_m: float
    interactions: tuple[Interaction, ...]
    segments: tuple[Segment, ...]
    band_gains: np.ndarray | None = None  # complex, one per band frequency

    @property
    def gain_db(self) -> float:
        """20 log10 |a| (-inf for a zero gain; the service clamps it)."""
        with np.errstate(divide="ignore"):
            return float(20.0 * np.log10(abs(self.gain)))


#: Regimes where full-wave (FDTD) comparisons showed geometric optics to be off (docs/validation.md,
#: "Validity per receiver"); a profile lists those its receiver is in.
VALIDITY_FLAGS: tuple[str, ...] = ("near_field", "in_air_near_body", "grazing_exit", "near_critical_angle",
                                   "curved_layers", "no_direct_path", "earlier_arrival")


@dataclass(frozen=True)
class ReceiverProfile:
    """Every path found to one receiver, sorted by delay, with summary statistics.

    ``smallest_organ`` is the electrically smallest organ its paths cross and
    ``smallest_organ_size_wavelengths`` its width in wavelengths of its own tissue at the
    carrier; ``warnings`` says when that is below one wavelength, where geometric optics
    stops (:mod:`raytrace.solver.validity`, docs/science.md section 8). None / () without
    a path through an organ.

    ``validity`` names the regimes of :data:`VALIDITY_FLAGS` the receiver is in (empty: none of
    them; the FDTD error bands of each are in docs/validation.md).

    ``first_arrival_s`` and ``earlier_arrival_s`` are filled by :func:`evaluation.arrivals.annotate`
    (None otherwise): the eikonal (Fermat) first arrival at the receiver, and by how much it precedes
    the first traced path where it does beyond the eikonal grid's error (a head wave along the fat
    the tracer does not build; flag ``earlier_arrival``).
    """

    receiver: str
    position_m: np.ndarray
    medium: str
    geometric_distance_m: float
    paths: tuple[Path, ...]
    smallest_organ: str | None = None
    smallest_organ_size_wavelengths: float | None = None
    warnings: tuple[str, ...] = ()
    validity: tuple[str, ...] = ()
    first_arrival_s: float | None = None
    earlier_arrival_s: float | None = None

    @property
    def first_path_delay_s(self) -> float | None:
        return self.paths[0].delay_s if self.paths else None

    @property
    def path_gain_db(self) -> float:
        """10 log10 sum_k |a_k|^2: total power transfer (incoherent sum)."""
        power = sum(abs(p.gain) ** 2 for p in self.paths)
        with np.errstate(divide="ignore"):
            return float(10.0 * np.log10(power)) if power > 0 else float("-inf")

    @property
    def rms_delay_spread_s(self) -> float:
        """Power-weighted RMS delay spread sqrt(E[tau^2] - E[tau]^2) (0 for one path)."""
        if not self.paths:
            return 0.0
        tau = np.array([p.delay_s for p in self.paths])
        w = np.array([abs(p.gain) ** 2 for p in self.paths])
        if w.sum() <= 0:
            return 0.0
        mean = np.sum(w * tau) / w.sum()
        return float(np.sqrt(max(np.sum(w * (tau - mean) ** 2) / w.sum(), 0.0)))


@dataclass(frozen=True)
class TraceStats:
    rays_launched: int
    ray_segments_traced: int
    paths_found: int
    elapsed_s: float


@dataclass(frozen=True)
class ChannelResult:
    """What one channel computation returns."""

    phantom: str
    frequency_hz: float
    transmitter_position_m: np.ndarray
    transmitter_medium: str
    profiles: tuple[ReceiverProfile, ...]
    stats: TraceStats
    band_frequencies_hz: np.ndarray | None = None
