"""CapsuleRT against NVIDIA Sionna RT on the same room, interleaved in one run.

    python -m bench.sionna_room                      # room and room + sphere, 1 / 12 / 64 receivers
    python -m bench.sionna_room --receivers 1,12 --repeat 3 --scenes room
    python -m bench --sionna                         # the same, after the other benchmarks

Scenes (issue 17): the 6 x 5 x 3 m room of concrete (eps_r 5.24, sigma 0.0462 S/m, ITU-R
P.2040) at 3.5 GHz, reflection paths up to ``--depth`` (5) reflections, the room's air one
closed organ inside a 1 m concrete shell for CapsuleRT and the room's six inner faces as 1 m
thin slabs for Sionna (its wall model; a 1 m slab reflects as a half-space within 1e-3);
and the same room with a concrete sphere of ~16k triangles in it. Both tools launch
``--rays`` (1e5) rays and run on ``--threads`` (2) threads: ``TracerConfig(threads=..)``
and ``drjit.set_thread_count``. Sionna runs reflection-only (``refraction=False``),
CapsuleRT as always (it splits every hit into reflected and transmitted rays; only its
reflection-only paths in the room's air are counted).

Completeness, for the room: an exact image-method enumeration
(:func:`tests.raytrace.test_completeness.image_paths`, which shares no code with the tracer)
gives every path; the paths above CapsuleRT's dynamic range (80 dB under the receiver's
strongest) are the reference both tools are counted against (docs/tracer.md, "Dynamic
range"). A tool's path matches an oracle path with the same reflections count, delay within
1 ps and reflection points within 1 mm (Sionna computes in float32).

Timing: each tool is warmed up once per receiver count (kernels compiled, scene built), then
``--repeat`` runs alternate between the two tools (which goes first alternates too) and the
medians are printed. CapsuleRT's time is one ``trace_channel`` call in this process; Sionna's
one ``PathSolver`` call with every result evaluated to numpy, measured inside its worker
process (:mod:`bench.sionna_worker`), so the pipe costs nothing. Both wall time (the ratio the
issue's target is about) and CPU time of all threads (``CPU C/S``: less sensitive to a machine
shared with other work) are printed.

Sionna is not a dependency of CapsuleRT: it is installed into its own virtual environment
(``$CAPSULE_RT_SIONNA_VENV``, default ``bench/.sionna-venv``) with pip on first use. Dr.Jit
needs an LLVM >= 16 shared library (``DRJIT_LIBLLVM_PATH``; Debian: ``apt-get install
libllvm19``). When either is missing the script says why and exits with status 2.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import trimesh

import raytrace as rt
from bench.common import ROOT
from raytrace.body.phantom import Material, Organ, Phantom

F_HZ = 3.5e9
CONCRETE = (5.24, 0.0462)  # eps_r, sigma [S/m] (ITU-R P.2040 concrete at 3.5 GHz)
ROOM_LO, ROOM_HI = np.array([-3.0, -2.5, -1.5]), np.array([3.0, 2.5, 1.5])
TX = np.array([0.7, -0.4, 0.2])
#: the completeness suite's four receivers first, then positions drawn in the room
FIRST_RX = [(-1.3, 1.1, -0.35), (2.1, 1.7, 0.6), (-2.2, -1.6, 0.9), (0.4, 0.9, -1.0)]
SPHERE_CENTRE, SPHERE_RADIUS = np.array([-1.0, -1.1, -0.4]), 0.6
DYNAMIC_RANGE_DB = 80.0
SIONNA_REQUIREMENT = "sionna-rt>=2.2,<2.3"
LLVM_CANDIDATES = ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
                   "/usr/lib/llvm-19/lib/libLLVM.so.19.1", "/usr/lib/x86_64-linux-gnu/libLLVM.so.18.1",
                   "/usr/lib/x86_64-linux-gnu/libLLVM-17.so", "/usr/lib/x86_64-linux-gnu/libLLVM-16.so")
SAME_DELAY_S, SAME_POINT_M = 1e-12, 1e-3


class Unavailable(RuntimeError):
    """Sionna RT cannot run here; the message says why."""


# ------------------------------------------------------------------ Sionna's environment
def sionna_python() -> str:
    """The interpreter of Sionna's virtual environment, created with pip on first use."""
    venv = os.environ.get("CAPSULE_RT_SIONNA_VENV") or os.path.join(ROOT, "bench", ".sionna-venv")
    python = os.path.join(venv, "bin", "python")
    probe = [python, "-c", "import importlib.metadata as m; print(m.version('sionna-rt'))"]
    if os.path.exists(python) and subprocess.run(probe, capture_output=True).returncode == 0:
        return python
    print(f"installing {SIONNA_REQUIREMENT} into {venv} (once; a few minutes)", flush=True)
    steps = [[sys.executable, "-m", "venv", venv],
             [python, "-m", "pip", "install", "--quiet", SIONNA_REQUIREMENT]]
    for cmd in steps:
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise Unavailable(f"`{' '.join(cmd)}` failed: {(proc.stderr or proc.stdout)[-1500:]}")
    return python


def llvm_library() -> str:
    """Dr.Jit's LLVM: ``$DRJIT_LIBLLVM_PATH`` or a known LLVM >= 16 (Debian's default LLVM makes it
    abort with "Cannot select ... fmaximum")."""
    path = os.environ.get("DRJIT_LIBLLVM_PATH")
    if path:
        if not os.path.exists(path):
            raise Unavailable(f"DRJIT_LIBLLVM_PATH={path} does not exist")
        return path
    for path in LLVM_CANDIDATES:
        if os.path.exists(path):
            return path
    raise Unavailable("Dr.Jit needs an LLVM >= 16 shared library: `apt-get install libllvm19` (Debian), "
                      "or set DRJIT_LIBLLVM_PATH")


class SionnaWorker:
    """:mod:`bench.sionna_worker` in Sionna's interpreter: one JSON line per command."""

    def __init__(self, python: str, llvm: str):
        env = dict(os.environ, DRJIT_LIBLLVM_PATH=llvm)
        self.proc = subprocess.Popen([python, os.path.join(ROOT, "bench", "sionna_worker.py")], env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)

    def ask(self, **cmd) -> dict:
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read()[-3000:]
            raise Unavailable(f"the Sionna worker stopped (status {self.proc.wait()}): {err}")
        answer = json.loads(line)
        if not answer.get("ok"):
            raise Unavailable(f"the Sionna worker refused {cmd['op']}: {answer.get('error')}")
        return answer

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write(json.dumps({"op": "quit"}) + "\n")
                self.proc.stdin.flush()
                self.proc.wait(timeout=30)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()


# ------------------------------------------------------------------ scenes
def concrete() -> Material:
    return Material(relative_permittivity=CONCRETE[0], conductivity_s_per_m=CONCRETE[1])


def sphere_mesh() -> trimesh.Trimesh:
    """A UV sphere of 16 128 triangles (64 x 128 segments)."""
    mesh = trimesh.creation.uv_sphere(radius=SPHERE_RADIUS, count=[64, 128])
    mesh.apply_translation(SPHERE_CENTRE)
    return mesh


def capsule_phantom(with_sphere: bool) -> Phantom:
    """The room's air as one organ inside a 1 m concrete shell (its six walls share one
    interaction signature), with a concrete sphere in it when ``with_sphere``."""
    organs = [Organ("walls", concrete(), trimesh.creation.box(bounds=[ROOM_LO - 1.0, ROOM_HI + 1.0])),
              Organ("room", Material(relative_permittivity=1.0, conductivity_s_per_m=0.0),
                    trimesh.creation.box(bounds=[ROOM_LO, ROOM_HI]))]
    if with_sphere:
        organs.append(Organ("sphere", concrete(), sphere_mesh()))
    return Phantom.build("sionna-room-sphere" if with_sphere else "sionna-room", organs)


def sionna_meshes(with_sphere: bool, folder: str) -> list[str]:
    """PLY files of Sionna's scene: the room's inner faces (thin slabs), the sphere."""
    paths = [os.path.join(folder, "room.ply")]
    trimesh.creation.box(bounds=[ROOM_LO, ROOM_HI]).export(paths[0])
    if with_sphere:
        paths.append(os.path.join(folder, "sphere.ply"))
        sphere_mesh().export(paths[1])
    return paths


def receiver_positions(count: int) -> np.ndarray:
    """The suite's four receivers, then seeded uniform positions at least 0.3 m inside the walls,
    0.5 m from the transmitter and 0.3 m outside the sphere."""
    rng = np.random.default_rng(17)
    out = [np.array(p) for p in FIRST_RX]
    while len(out) < count:
        p = rng.uniform(ROOM_LO + 0.3, ROOM_HI - 0.3)
        if np.linalg.norm(p - TX) > 0.5 and np.linalg.norm(p - SPHERE_CENTRE) > SPHERE_RADIUS + 0.3:
            out.append(p)
    return np.array(out[:count])


# ------------------------------------------------------------------ the oracle and the matching
def oracle_paths(rx: np.ndarray, depth: int) -> list[list[dict]]:
    """Per receiver, the image-method paths of the empty room (tests/raytrace/test_completeness.py,
    written independently of the tracer) above the dynamic range."""
    from tests.raytrace.test_completeness import box_faces, image_paths

    faces = box_faces(ROOM_LO, ROOM_HI)
    z = np.array([0.0, 0.0, 1.0])
    out = []
    for r in rx:
        paths = image_paths(faces, TX, r, depth, *CONCRETE, z, z)
        top = max(abs(p["gain"]) for p in paths)
        floor = top * 10 ** (-(DYNAMIC_RANGE_DB - 0.01) / 20)
        out.append([{"n": len(p["points"]) - 2, "delay_s": p["delay_s"],
                     "points_m": np.array(p["points"][1:-1]).reshape(-1, 3)} for p in paths if abs(p["gain"]) >= floor])
    return out


def capsule_paths(result: rt.ChannelResult) -> list[list[dict]]:
    """Each receiver's reflection-only paths that stay in the room's air."""
    out = []
    for prof in result.profiles:
        out.append([{"n": len(p.interactions), "delay_s": p.delay_s,
                     "points_m": np.array([i.point_m for i in p.interactions]).reshape(-1, 3)}
                    for p in prof.paths if all(i.kind == "reflection" for i in p.interactions)
                    and all(s.medium == "room" for s in p.segments)])
    return out


def matched(found: list[list[dict]], oracle: list[list[dict]]) -> int:
    """Oracle paths found (each counted once): same reflection count, delay within 1 ps, points within 1 mm."""
    hits = 0
    for ours, ref in zip(found, oracle):
        for o in ref:
            hits += any(p["n"] == o["n"] and abs(p["delay_s"] - o["delay_s"]) < SAME_DELAY_S
                        and np.allclose(np.reshape(p["points_m"], (-1, 3)), o["points_m"], atol=SAME_POINT_M)
                        for p in ours)
    return hits


# ------------------------------------------------------------------ the run
def run_capsule(phantom: Phantom, rx: np.ndarray, args) -> tuple[float, float, list[list[dict]]]:
    z = np.array([0.0, 0.0, 1.0])
    spec = rt.ChannelSpec(rt.Antenna(TX, polarization=z), tuple(rt.Antenna(r, polarization=z) for r in rx),
                          phantom=phantom.name, frequency_hz=F_HZ, rays=args.rays, max_interactions=args.depth,
                          dynamic_range_db=DYNAMIC_RANGE_DB, near_field=False)
    config = rt.TracerConfig(threads=args.threads)
    t0, c0 = time.perf_counter(), time.process_time()
    result = rt.trace_channel(spec, phantom, config=config)
    return time.perf_counter() - t0, time.process_time() - c0, capsule_paths(result)


def run_sionna(worker: SionnaWorker, rx: np.ndarray, args) -> tuple[float, float, list[list[dict]]]:
    ans = worker.ask(op="run", tx_m=TX.tolist(), rx_m=rx.tolist(), depth=args.depth, samples=args.rays,
                     max_paths=args.max_paths)
    return ans["time_s"], ans["cpu_s"], ans["paths"]


def compare(scene: str, worker: SionnaWorker, args, folder: str) -> list[dict]:
    with_sphere = scene == "sphere"
    phantom = capsule_phantom(with_sphere)
    worker.ask(op="scene", meshes=sionna_meshes(with_sphere, folder), relative_permittivity=CONCRETE[0],
               conductivity_s_per_m=CONCRETE[1], thickness_m=1.0, frequency_hz=F_HZ, threads=args.threads)
    rows = []
    for count in args.receivers:
        rx = receiver_positions(count)
        oracle = None if with_sphere else oracle_paths(rx, args.depth)
        run_capsule(phantom, rx, args)  # warm-up: scene, kernels
        run_sionna(worker, rx, args)
        gc.freeze()
        times = {"capsule": [], "sionna": []}
        cpu = {"capsule": [], "sionna": []}
        found = {}
        for rep in range(args.repeat):
            order = ("capsule", "sionna") if rep % 2 == 0 else ("sionna", "capsule")
            for tool in order:
                t, c, paths = run_capsule(phantom, rx, args) if tool == "capsule" else run_sionna(worker, rx, args)
                times[tool].append(t)
                cpu[tool].append(c)
                found[tool] = paths
        row = {"scene": scene, "receivers": count, "depth": args.depth, "rays": args.rays,
               "threads": args.threads, "repeat": args.repeat,
               "capsule_s": float(np.median(times["capsule"])), "sionna_s": float(np.median(times["sionna"])),
               "capsule_times_s": times["capsule"], "sionna_times_s": times["sionna"],
               "capsule_cpu_s": float(np.median(cpu["capsule"])), "sionna_cpu_s": float(np.median(cpu["sionna"])),
               "capsule_paths": sum(len(p) for p in found["capsule"]),
               "sionna_paths": sum(len(p) for p in found["sionna"])}
        row["ratio"] = row["capsule_s"] / row["sionna_s"]
        row["cpu_ratio"] = row["capsule_cpu_s"] / row["sionna_cpu_s"]
        if oracle is not None:
            row["oracle_paths"] = sum(len(o) for o in oracle)
            row["capsule_found"] = matched(found["capsule"], oracle)
            row["sionna_found"] = matched(found["sionna"], oracle)
        rows.append(row)
        print_row(row)
    return rows


def print_row(row: dict) -> None:
    oracle = (f"{row['capsule_found']:>5} / {row['sionna_found']:>5} of {row['oracle_paths']:>5}"
              if "oracle_paths" in row else f"{'(no oracle)':>23}")
    print(f"{row['scene']:<7} {row['receivers']:>4} {row['capsule_s']:>10.3f} {row['sionna_s']:>9.3f} "
          f"{row['ratio']:>9.2f} {row['cpu_ratio']:>9.2f}  {oracle}  "
          f"{row['capsule_paths']:>6} / {row['sionna_paths']:<6}", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--receivers", default="1,12,64", help="receiver counts, comma separated")
    ap.add_argument("--scenes", default="room,sphere", help="room and/or sphere (the room with a sphere in it)")
    ap.add_argument("--depth", type=int, default=5, help="reflections at most")
    ap.add_argument("--rays", type=int, default=100_000, help="launch directions of both tools")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5, help="timed runs per tool and receiver count")
    ap.add_argument("--max-paths", type=int, default=1_000_000, help="Sionna's max_num_paths_per_src")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results", "sionna_room.json"))
    args = ap.parse_args(argv)
    args.receivers = [int(k) for k in args.receivers.split(",")]
    scenes = args.scenes.split(",")
    try:
        llvm = llvm_library()  # first: a missing LLVM is reported before anything is installed
        worker = SionnaWorker(sionna_python(), llvm)
    except Unavailable as exc:
        print(f"bench.sionna_room: Sionna RT is not available: {exc}", file=sys.stderr)
        return 2
    rows = []
    try:
        print(f"depth {args.depth}, {args.rays} rays, {args.threads} threads, medians of {args.repeat} interleaved "
              f"runs; found: oracle paths above {DYNAMIC_RANGE_DB:.0f} dB (CapsuleRT / Sionna)")
        print(f"{'scene':<7} {'rx':>4} {'CapsuleRT s':>10} {'Sionna s':>9} {'Caps/Sion':>9} {'CPU C/S':>9}  "
              f"{'found CapsuleRT / Sionna':>23}  paths C / S")
        with tempfile.TemporaryDirectory() as folder:
            for scene in scenes:
                rows += compare(scene, worker, args, folder)
    except Unavailable as exc:
        print(f"bench.sionna_room: Sionna RT failed: {exc}", file=sys.stderr)
        return 2
    finally:
        worker.close()
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump({"rows": rows, "argv": sys.argv[1:]}, fh, indent=1)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
