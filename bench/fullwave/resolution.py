"""The default torso's mesh resolution trade-off (docs/validation.md, "Mesh resolution of the
default torso"): faceting error of the direct paths against the finest mesh, and time per trace.

    python -m bench.fullwave.resolution [--resolutions 48 96 192] [--rays 100000] [--out FILE.json]

Every capsule site to every sensor site, lossy tissue at 402 MHz, dipole antennas, z-polarised.
Per resolution: the phantom's build time, the all-sensor trace's wall time per capsule (median of
the six, each after the scene is built), and per (capsule, sensor) pair the change of the direct
path's gain [dB] and phase [deg] against the finest resolution (the strongest refraction-only
path; pairs without one at either resolution are counted, not compared). The sites move with
the mesh (contact sensors sit 1 mm under the faceted skin), so a part of each change is the
sensor's own move, as it is for a user changing the resolution.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from raytrace.body.torso import build_torso
from raytrace.solver.tracer import trace_channel
from raytrace.spec import Antenna, ChannelSpec


def direct(profile) -> complex | None:
    """Gain of the strongest refraction-only path of a profile, or None."""
    best = None
    for p in profile.paths:
        if all(i.kind == "refraction" for i in p.interactions) and (best is None or abs(p.gain) > abs(best)):
            best = p.gain
    return best


def measure(resolution: int, rays: int) -> dict:
    t0 = time.perf_counter()
    ph = build_torso(resolution)
    build_s = time.perf_counter() - t0
    capsules = [n for n, s in ph.sites.items() if s.kind == "capsule"]
    sensors = [n for n, s in ph.sites.items() if s.kind == "sensor"]
    gains, times = {}, []
    for k, cap in enumerate(capsules):
        spec = ChannelSpec(Antenna(site=cap, polarization=[0, 0, 1], pattern="dipole"),
                           tuple(Antenna(site=s, name=s, polarization=[0, 0, 1], pattern="dipole") for s in sensors),
                           phantom=ph.name, frequency_hz=402e6, rays=rays)
        if k == 0:
            trace_channel(spec, ph)  # builds the scene
        t0 = time.perf_counter()
        result = trace_channel(spec, ph)
        times.append(time.perf_counter() - t0)
        for s, prof in zip(sensors, result.profiles):
            g = direct(prof)
            gains[f"{cap}->{s}"] = None if g is None else [g.real, g.imag]
    return {"resolution": resolution, "triangles": int(len(ph.mesh.faces)), "build_s": build_s,
            "trace_s": times, "direct_gains": gains}


def compare(runs: list[dict]) -> list[dict]:
    ref = runs[-1]["direct_gains"]
    out = []
    for run in runs:
        d_db, d_deg, missing = [], [], 0
        for pair, g in run["direct_gains"].items():
            r = ref.get(pair)
            if g is None or r is None:
                missing += 1
                continue
            a, b = complex(*g), complex(*r)
            d_db.append(20 * np.log10(abs(a) / abs(b)))
            d_deg.append(np.degrees(np.angle(a / b)))
        d_db, d_deg = np.abs(d_db), np.abs(d_deg)
        out.append({"resolution": run["resolution"], "triangles": run["triangles"], "build_s": run["build_s"],
                    "trace_median_s": float(np.median(run["trace_s"])), "pairs": len(d_db), "missing": missing,
                    "median_db": float(np.median(d_db)), "p90_db": float(np.percentile(d_db, 90)),
                    "max_db": float(d_db.max()), "median_deg": float(np.median(d_deg)),
                    "max_deg": float(d_deg.max())})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.fullwave.resolution", description=__doc__)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[48, 96, 192])
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--out", default="bench/results/fullwave/resolution.json")
    args = ap.parse_args(argv)
    runs = [measure(r, args.rays) for r in sorted(args.resolutions)]
    rows = compare(runs)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"runs": runs, "summary": rows}, indent=2))
    ref = rows[-1]["resolution"]
    print(f"| resolution | triangles | build s | trace s (median) | pairs | |d dB| vs {ref}: median / p90 / max | "
          "|d deg|: median / max |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['resolution']} | {r['triangles']} | {r['build_s']:.1f} | {r['trace_median_s']:.2f} | "
              f"{r['pairs']} (+{r['missing']} without) | {r['median_db']:.2f} / {r['p90_db']:.2f} / "
              f"{r['max_db']:.2f} | {r['median_deg']:.1f} / {r['max_deg']:.1f} |", file=sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
