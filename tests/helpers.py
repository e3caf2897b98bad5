"""Helpers shared by the tests (not fixtures: plain functions)."""

from __future__ import annotations

import numpy as np

import raytrace as rt


def trace(phantom: rt.Phantom, transmitter: rt.Antenna, receivers, frequency_hz: float, *, band=None, budget=None,
          near_field: bool = False, **knobs) -> rt.ChannelResult:
    """``rt.trace_channel`` on a hand-built phantom: the spec names it, the object is passed.
    ``band`` may be a :class:`raytrace.Band` or an array of frequencies. ``near_field`` is off
    here (the spec's default is on): the geometric-optics oracles these tests use (Friis,
    Fresnel, ray tubes) are far-field closed forms; the near-field tests turn it on."""
    if band is not None and not isinstance(band, rt.Band):
        band = rt.Band(frequencies_hz=np.asarray(band, float))
    spec = rt.ChannelSpec(transmitter, tuple(receivers), phantom=phantom.name, frequency_hz=frequency_hz, band=band,
                          near_field=near_field, **knobs)
    return rt.trace_channel(spec, phantom, budget=budget)
