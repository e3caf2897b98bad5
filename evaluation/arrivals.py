"""Earlier arrivals than the tracer's paths, stated per link in the profile (docs/validation.md,
"Head waves").

Geometric optics builds refraction and reflection paths; a wave that runs along a fast layer and
leaves it at the critical angle (a head wave: along the subcutaneous fat, n ~ 3.4 against ~ 7.9 in
muscle at 402 MHz) is no such path, and in some torso links it arrives nanoseconds before every
traced one (docs/localization.md, "Eikonal check of the tracer"). The eikonal first arrival ``T``
(Fermat's minimum over every continuous path in the body, scikit-fmm on the phantom's voxels,
:func:`evaluation.fields.sensor_fields`) knows it. :func:`annotate` compares it with each profile's
earliest traced path and, where ``T`` is earlier by more than the grid's stated error, says so in
the profile: ``first_arrival_s`` (``T``), ``earlier_arrival_s`` (how much earlier than the first
traced path) and the validity flag ``earlier_arrival``. Times are phase delays (``Re n``, the
paths' ``delay_s``), as in :func:`evaluation.tracer_check.check_tracer`. The amplitude of such an
arrival is not modelled: where it matters is where the profile says so.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from evaluation.fields import DEFAULT_CELL_SIZE_M, sensor_fields
from raytrace import Phantom
from raytrace.results import ChannelResult

#: Validity flag of a profile whose link has an earlier (untraced) arrival.
FLAG = "earlier_arrival"


def annotate(result: ChannelResult, phantom: Phantom, cell_size_m: float = DEFAULT_CELL_SIZE_M) -> ChannelResult:
    """``result`` with every profile's ``first_arrival_s`` (the eikonal arrival at its receiver from
    the transmitter) and, where that is earlier than the profile's first traced path by more than the
    eikonal grid's stated error (or the profile has no path), ``earlier_arrival_s`` and the flag
    ``earlier_arrival`` (module docstring). One eikonal field per receiver (cached per phantom,
    receiver, frequency and cell size), evaluated at the transmitter (reciprocity)."""
    rx = np.array([p.position_m for p in result.profiles], float).reshape(-1, 3)
    fields = sensor_fields(phantom, rx, result.frequency_hz, cell_size_m, delay_kind="phase")
    t_eik, _ = fields.evaluate(np.asarray(result.transmitter_position_m, float))
    error = float(fields.discretisation_error_s)
    profiles = []
    for prof, t in zip(result.profiles, t_eik):
        t = float(t)
        first = prof.first_path_delay_s
        lead = None if first is None else first - t
        if lead is not None and lead <= error:
            profiles.append(dataclasses.replace(prof, first_arrival_s=t))
            continue
        flags = prof.validity + (() if FLAG in prof.validity else (FLAG,))
        profiles.append(dataclasses.replace(prof, first_arrival_s=t, earlier_arrival_s=lead, validity=flags))
    return dataclasses.replace(result, profiles=tuple(profiles))
