"""Which contact-sensor positions of the default torso have a direct (refraction-only) path
from every capsule site? A map for choosing sensor sites.

Candidates every 15 deg of polar angle (from anterior towards the subject's left) at the belt
(z = 0) and upper (z = 0.155 m) heights, 1 mm deep in the skin like the torso's own sensors;
each capsule is traced to all of them (1e5 rays; the direct-path search does not depend on
max_interactions, 4 keeps the shooting cheap). "." marks a pair without a direct path at that
ray count (a GO shadow, or a near-critical sliver finer than the launch spacing; see
docs/tracer.md). Usage: .venv/bin/python tools/torso_sensor_reachability.py  (~40 s)
"""
import time

import raytrace.torso as T
from raytrace.paths import Antenna
from raytrace.tracer import trace_channel

p = T.default_torso()
skin = p.organs[p.organ_index("skin")].mesh
heights = (0.0, T._UPPER_Z_M)
cands = {(z, deg): T._contact_point(skin, float(deg), z) for z in heights for deg in range(0, 360, 15)}
caps = {n: s.position_m for n, s in p.sites.items() if s.kind == "capsule"}
rx = [Antenna(v, f"{deg}@{z}") for (z, deg), v in cands.items()]
direct = {}
for c, pos in caps.items():
    t0 = time.time()
    res = trace_channel(p, Antenna(pos, c), rx, 402e6, rays=100_000, max_interactions=4)
    for key, prof in zip(cands, res.profiles):
        direct[(c, key)] = any(all(i.kind == "refraction" for i in pa.interactions) for pa in prof.paths)
    print(f"{c}: {time.time() - t0:.1f} s", flush=True)
print("columns:", " ".join(caps))
for z in heights:
    print(f"z = {z} m")
    for deg in range(0, 360, 15):
        marks = " ".join("X" if direct[(c, (z, deg))] else "." for c in caps)
        print(f"  polar {deg:3d} deg: {marks}   without: {[c for c in caps if not direct[(c, (z, deg))]]}")
