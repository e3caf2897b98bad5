"""Which contact-sensor positions on the CT abdomen's skin have a direct (refraction-only) path from which
capsule sites? The map the ``abdomen-ct`` belts were chosen from (docs/phantoms.md, "The built-in CT abdomen").

Candidates every 15 deg of polar angle (from anterior towards the subject's left) on rings at heights every
``--step`` mm above the body's lowest point, placed as the pipeline places a belt's sensors
(:func:`raytrace.body.anatomy.sensors.belt_positions`: 1 mm under the skin surface); each capsule site is
traced to all of them. A cell shows how many capsule sites have a direct path there; the last lines list,
per capsule site, how many of the phantom's own sensor sites it reaches directly (each needs >= 8).

Usage: python tools/abdomen_sensor_reachability.py [--rays 100000] [--step 30] [--low 100] [--high 400]
(~25 traces of ~260 receivers; minutes on 2 cores). The direct-path search does not depend on
max_interactions; 2 keeps the shooting cheap.
"""
import argparse
import sys
import time

import numpy as np

import raytrace as rt
from raytrace.body.abdomen import abdomen_ct
from raytrace.body.anatomy.manifest import SensorBelt
from raytrace.body.anatomy.sensors import belt_positions
from raytrace.spec import Antenna


def direct(profile) -> bool:
    return any(all(i.kind == "refraction" for i in p.interactions) for p in profile.paths)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--step", type=float, default=30.0, help="mm between candidate rings")
    ap.add_argument("--low", type=float, default=100.0, help="lowest ring, mm above the body's lowest point")
    ap.add_argument("--high", type=float, default=400.0, help="highest ring, mm above the body's lowest point")
    args = ap.parse_args()
    phantom = abdomen_ct()
    skin = phantom.organs[phantom.organ_index("skin")].mesh
    heights = np.arange(args.low, args.high + 1e-9, args.step) / 1e3
    cells = {}
    for h in heights:
        ring = belt_positions(skin, SensorBelt(f"h{h * 1e3:.0f}", float(h), 24, 0.0), 0)
        for name, p in ring.items():
            cells[(round(float(h), 3), int(name.rsplit("_", 1)[1]))] = p
    keys = list(cells)
    capsules = {n: s.position_m for n, s in phantom.sites.items() if s.kind == "capsule"}
    sensors = [n for n, s in phantom.sites.items() if s.kind == "sensor"]
    reached = dict.fromkeys(keys, 0)
    own = {}
    receivers = [Antenna(cells[k], f"{k[1]}@{k[0]}") for k in keys] + [Antenna(site=n) for n in sensors]
    for name, position in capsules.items():
        t0 = time.time()
        spec = rt.ChannelSpec(Antenna(position, name), tuple(receivers), phantom=phantom.name, rays=args.rays,
                              max_interactions=2)
        res = rt.trace_channel(spec, phantom)
        for key, prof in zip(keys, res.profiles[:len(keys)]):
            reached[key] += direct(prof)
        own[name] = sum(direct(p) for p in res.profiles[len(keys):])
        print(f"{name}: {time.time() - t0:.1f} s, {own[name]} of {len(sensors)} own sensors direct",
              file=sys.stderr, flush=True)
    print(f"{args.rays} rays; {len(capsules)} capsule sites: {', '.join(capsules)}")
    print("height [m]  polar [deg]" + "".join(f"{d:4d}" for d in range(0, 360, 15)))
    for h in heights:
        h = round(float(h), 3)
        print(f"{h:10.3f}             " + "".join("   *" if reached[(h, d)] == len(capsules)
                                                  else f"{reached[(h, d)]:4d}" for d in range(0, 360, 15)))
    print("direct paths to the phantom's own sensor sites per capsule site: "
          + ", ".join(f"{n} {c}" for n, c in own.items()))


if __name__ == "__main__":
    main()
