"""Sionna RT side of ``bench/sionna_room.py``: a worker run by Sionna's own interpreter.

This file imports nothing of CapsuleRT (it runs in a separate virtual environment where
only ``sionna-rt`` and its dependencies are installed). It reads one JSON command per line on
stdin and answers one JSON line on stdout:

* ``{"op": "scene", "meshes": [ply paths], "relative_permittivity": .., "conductivity_s_per_m": ..,
  "thickness_m": .., "frequency_hz": .., "threads": ..}``: load the scene (every mesh one thin
  slab of that material, ITU-R P.2040 as Sionna models walls), set Dr.Jit's thread count.
* ``{"op": "run", "tx_m": [x, y, z], "rx_m": [[x, y, z], ...], "depth": .., "samples": ..,
  "max_paths": ..}``: reflection-only paths (line of sight and specular reflections; no
  refraction, no diffuse, no diffraction), isotropic antennas, polarization V. The answer is
  the wall and CPU (all threads) times of the solver call with every result tensor evaluated
  to numpy (``time_s``, ``cpu_s``), and per receiver its paths: the number of reflections, the absolute delay
  (``normalize_delays`` does not apply to ``Paths.tau``) and the reflection points.
* ``{"op": "quit"}``.
"""

from __future__ import annotations

import json
import sys
import time


def main() -> None:
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    mi.set_variant("llvm_ad_mono_polarized")
    from sionna.rt import PathSolver, PlanarArray, Receiver, Transmitter, load_scene_from_string
    from sionna.rt.constants import InteractionType

    scene, solver = None, PathSolver()
    out = sys.stdout
    sys.stdout = sys.stderr  # anything the libraries print must not mix with the answers
    for line in sys.stdin:
        cmd = json.loads(line)
        if cmd["op"] == "quit":
            break
        if cmd["op"] == "scene":
            dr.set_thread_count(int(cmd["threads"]))
            shapes = "".join(
                f'<shape type="ply" id="mesh-{k}"><string name="filename" value="{path}"/>'
                f'<boolean name="face_normals" value="true"/><ref id="wall" name="bsdf"/></shape>'
                for k, path in enumerate(cmd["meshes"]))
            xml = (f'<scene version="2.1.0"><bsdf type="radio-material" id="wall">'
                   f'<float name="relative_permittivity" value="{cmd["relative_permittivity"]!r}"/>'
                   f'<float name="conductivity" value="{cmd["conductivity_s_per_m"]!r}"/>'
                   f'<float name="thickness" value="{cmd["thickness_m"]!r}"/></bsdf>{shapes}</scene>')
            scene = load_scene_from_string(xml)
            scene.frequency = float(cmd["frequency_hz"])
            scene.tx_array = PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
            scene.rx_array = PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
            answer = {"ok": True, "variant": mi.variant(), "threads": dr.thread_count()}
        elif cmd["op"] == "run":
            for name in list(scene.transmitters) + list(scene.receivers):
                scene.remove(name)
            scene.add(Transmitter(name="tx", position=mi.Point3f(*cmd["tx_m"])))
            for k, p in enumerate(cmd["rx_m"]):
                scene.add(Receiver(name=f"rx{k}", position=mi.Point3f(*p)))
            t0, c0 = time.perf_counter(), time.process_time()
            paths = solver(scene, max_depth=int(cmd["depth"]), max_num_paths_per_src=int(cmd["max_paths"]),
                           samples_per_src=int(cmd["samples"]), synthetic_array=True, los=True,
                           specular_reflection=True, diffuse_reflection=False, refraction=False)
            tau = paths.tau.numpy()  # [num_rx, num_tx, num_paths]
            valid = paths.valid.numpy()
            inter = paths.interactions.numpy()  # [depth, num_rx, num_tx, num_paths]
            verts = paths.vertices.numpy()  # [depth, num_rx, num_tx, num_paths, 3]
            a_re, _a_im = (x.numpy() for x in paths.a)
            elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
            per_rx = []
            for r in range(len(cmd["rx_m"])):
                rows = []
                for p in np.flatnonzero(valid.reshape(len(cmd["rx_m"]), -1)[r]):
                    kinds = inter[:, r, 0, p]
                    n = int(np.count_nonzero(kinds != InteractionType.NONE))
                    if np.any(kinds[:n] != InteractionType.SPECULAR):
                        continue
                    rows.append({"n": n, "delay_s": float(tau[r, 0, p]), "points_m": verts[:n, r, 0, p].tolist()})
                per_rx.append(rows)
            del a_re
            answer = {"ok": True, "time_s": elapsed, "cpu_s": cpu, "paths": per_rx}
        else:
            answer = {"ok": False, "error": f"unknown op {cmd['op']!r}"}
        out.write(json.dumps(answer) + "\n")
        out.flush()


if __name__ == "__main__":
    main()
