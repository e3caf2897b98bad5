"""Which contact-sensor positions of the default torso have a direct (refraction-only) path
from every capsule site? The map the torso's sensor sites were chosen from.

Candidates every 15 deg of polar angle (from anterior towards the subject's left) at heights
z = -0.050 ... +0.225 m every 25 mm, 1 mm deep in the skin like the torso's own sensors
(:func:`raytrace.body.torso.contact_point`); each capsule is traced to all of them. A cell shows
how many of the six capsules have a direct path there, ``*`` for all six. A missing pair is a
GO shadow or a near-critical sliver finer than the launch spacing (docs/tracer.md); a site is
safe when its cell is ``*`` at several resolutions and ray counts, not only one.

Usage: .venv/bin/python tools/torso_sensor_reachability.py [resolution [rays]]
(default 48 and 1e5: ~70 s on 2 cores). The direct-path search does not depend on
max_interactions; 2 keeps the shooting cheap.
"""
import sys
import time

import numpy as np

import raytrace as rt
import raytrace.body.torso as T
from raytrace.spec import Antenna

resolution = int(sys.argv[1]) if len(sys.argv) > 1 else T.DEFAULT_RESOLUTION
rays = int(sys.argv[2]) if len(sys.argv) > 2 else 100_000
phantom = T.default_torso(resolution)
heights = [round(float(z), 3) for z in np.arange(-0.050, 0.2251, 0.025)]
polar = range(0, 360, 15)
cells = {(z, deg): T.contact_point(phantom, deg, z) for z in heights for deg in polar}
capsules = {n: s.position_m for n, s in phantom.sites.items() if s.kind == "capsule"}
keys = list(cells)
receivers = [Antenna(cells[k], f"{k[1]}@{k[0]}") for k in keys]
reached = dict.fromkeys(keys, 0)
for name, position in capsules.items():
    t0 = time.time()
    spec = rt.ChannelSpec(Antenna(position, name), tuple(receivers), phantom=phantom.name, rays=rays,
                          max_interactions=2)
    res = rt.trace_channel(spec, phantom)
    for key, prof in zip(keys, res.profiles):
        reached[key] += any(all(i.kind == "refraction" for i in p.interactions) for p in prof.paths)
    print(f"{name}: {time.time() - t0:.1f} s", file=sys.stderr, flush=True)
print(f"resolution {resolution}, {rays} rays; capsules: {', '.join(capsules)}")
print("polar [deg]" + "".join(f"{d:4d}" for d in polar))
for z in heights:
    print(f"z = {z:+.3f} m" + "".join("   *" if reached[(z, d)] == len(capsules) else f"{reached[(z, d)]:4d}"
                                      for d in polar))
