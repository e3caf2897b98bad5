"""The benchmark's inputs: the default torso, its sites, receiver sets."""

from __future__ import annotations

import numpy as np

import raytrace as rt
from raytrace.body.torso import default_torso
from raytrace.spec import Antenna


def torso(resolution: int | None = None):
    return default_torso() if resolution is None else default_torso(resolution)


def capsule_site(phantom) -> str:
    """The first small-intestine capsule site (else the first capsule site)."""
    caps = [n for n, s in phantom.sites.items() if s.kind == "capsule"]
    for name in caps:
        if "intestine" in name:
            return name
    return caps[0]


def sensor_sites(phantom) -> list[str]:
    return [n for n, s in phantom.sites.items() if s.kind == "sensor"]


def receivers(phantom, count: int | None = None) -> list[Antenna]:
    """``count`` receivers: the sensor sites, then copies of them shifted along
    z in 10 mm steps (still in air off the skin of the extruded trunk)."""
    names = sensor_sites(phantom)
    count = len(names) if count is None else count
    out = []
    for k in range(count):
        site = phantom.sites[names[k % len(names)]]
        step = k // len(names)
        dz = 0.01 * ((step + 1) // 2) * (1 if step % 2 else -1)
        out.append(Antenna(position_m=site.position_m + np.array([0.0, 0.0, dz]), name=f"{site.name}+{k}"))
    return out


def transmitter(phantom) -> Antenna:
    site = phantom.sites[capsule_site(phantom)]
    return Antenna(position_m=site.position_m.copy(), name=site.name)


def trace(phantom, tx: Antenna, rx: list[Antenna], frequency_hz: float = 402e6, **knobs) -> rt.ChannelResult:
    """One channel on ``phantom`` (a spec naming it, the object passed along)."""
    spec = rt.ChannelSpec(tx, tuple(rx), phantom=phantom.name, frequency_hz=frequency_hz, **knobs)
    return rt.trace_channel(spec, phantom)
