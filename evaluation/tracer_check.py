"""Independent check of the tracer by the eikonal equation (docs/localization.md,
"Eikonal check of the tracer").

The first-arrival time T_s(x) from a sensor s solves |grad T| = n / c: it is Fermat's
minimum of the travel time over every continuous path inside the propagation domain (head
waves along a faster layer included), so no traced path -- a particular such path -- may
arrive earlier than T_s(capsule) minus the grid's stated discretisation error, and where
the tracer's fastest path is the global minimum the two agree within that error. By
reciprocity the field from the sensor gives the capsule -> sensor time. The eikonal side
shares no code with the tracer: a voxel grid of the phantom's media (the phantom's own
point-in-organ test) and scikit-fmm's fast marching.

Pairs whose eikonal arrival is earlier than every traced path by more than the error are
listed with the media the eikonal ray (steepest descent of T from the capsule) crosses:
there the global minimum is a path the tracer does not build (a head wave along the fast
fat layer, n ~ 3.4 against ~ 7.9 in muscle, or a detour through the lungs or the spine).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

import raytrace as rt
from evaluation.fields import (
    DEFAULT_CELL_SIZE_M,
    eikonal_path,
    path_media,
    sensor_fields,
    voxel_grid,
)
from raytrace import Phantom


@dataclass(frozen=True)
class PairCheck:
    """One capsule x sensor pair. difference_s = traced first arrival - eikonal arrival
    (None without a traced path). verdict: ``agree`` (|difference| <= error),
    ``eikonal_earlier`` (difference > error: the tracer misses the global minimum),
    ``traced_earlier`` (difference < -error: a violation of Fermat's bound), ``no_path``.
    eikonal_media: fraction of the eikonal ray's length per medium."""

    capsule: str
    sensor: str
    eikonal_s: float
    traced_first_s: float | None
    difference_s: float | None
    verdict: str
    eikonal_media: dict


@dataclass(frozen=True)
class TracerCheck:
    pairs: tuple[PairCheck, ...]
    cell_size_m: float
    error_s: float
    frequency_hz: float

    def by_verdict(self, verdict: str) -> list[PairCheck]:
        return [p for p in self.pairs if p.verdict == verdict]


def check_tracer(phantom: Phantom, capsules: Sequence[str], sensors: Sequence[str], frequency_hz: float = 402e6,
                 *, cell_size_m: float = DEFAULT_CELL_SIZE_M, rays: int = 100_000,
                 max_interactions: int = 6) -> TracerCheck:
    """Eikonal arrival against the fastest traced path for every capsule x sensor site pair
    (module docstring), the index being Re n at ``frequency_hz`` as in the tracer's delays."""
    sens = np.array([phantom.sites[s].position_m for s in sensors])
    fields = sensor_fields(phantom, sens, frequency_hz, cell_size_m, delay_kind="phase")  # the paths' delay_s
    grid = voxel_grid(phantom, cell_size_m)
    err = fields.discretisation_error_s
    receivers = [rt.Antenna(p, name=s) for s, p in zip(sensors, sens)]
    pairs = []
    for cap in capsules:
        x = phantom.sites[cap].position_m
        spec = rt.ChannelSpec(rt.Antenna(x, name=cap), tuple(receivers), phantom=phantom.name,
                              frequency_hz=frequency_hz, rays=rays, max_interactions=max_interactions)
        result = rt.trace_channel(spec, phantom)
        t_eik, _ = fields.evaluate(x)
        for j, name in enumerate(sensors):
            first = result.profiles[j].first_path_delay_s
            diff = None if first is None else first - float(t_eik[j])
            if diff is None:
                verdict = "no_path"
            elif diff < -err:
                verdict = "traced_earlier"
            elif diff > err:
                verdict = "eikonal_earlier"
            else:
                verdict = "agree"
            media = path_media(grid, eikonal_path(fields, j, x)) if verdict != "agree" else {}
            pairs.append(PairCheck(cap, name, float(t_eik[j]), first, diff, verdict, media))
    return TracerCheck(tuple(pairs), float(cell_size_m), float(err), float(frequency_hz))
