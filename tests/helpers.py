"""Helpers shared by the tests (not fixtures: plain functions)."""

from __future__ import annotations

import numpy as np

import raytrace as rt


def trace(phantom: rt.Phantom, transmitter: rt.Antenna, receivers, frequency_hz: float, *, band=None, budget=None,
          **knobs) -> rt.ChannelResult:
    """``rt.trace_channel`` on a hand-built phantom: the spec names it, the object is passed.
    ``band`` may be a :class:`raytrace.Band` or an array of frequencies."""
    if band is not None and not isinstance(band, rt.Band):
        band = rt.Band(frequencies_hz=np.asarray(band, float))
    spec = rt.ChannelSpec(transmitter, tuple(receivers), phantom=phantom.name, frequency_hz=frequency_hz, band=band,
                          **knobs)
    return rt.trace_channel(spec, phantom, budget=budget)
