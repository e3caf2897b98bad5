"""TracerConfig (raytrace/config.py): the tracer's tuning constants in one frozen, validated
record that reaches every place a constant is used; its thread count defaults to the CPUs the
process may use; the service builds it from its settings."""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
import shutil
import subprocess
import sys

import numpy as np
import pytest

import raytrace as rt
from raytrace.body.library import half_space
from raytrace.engine.scene import scene_for
from raytrace.solver import refine
from raytrace.solver.config import TracerConfig
from raytrace.solver.media import MediaTable


def test_the_default_thread_count_is_the_cpus_this_process_may_use():
    """Oracle: the process's affinity mask, narrowed to one CPU by taskset in a child process
    (the default is computed when the config is made, not when the module is imported)."""
    if hasattr(os, "sched_getaffinity"):
        assert TracerConfig().threads == len(os.sched_getaffinity(0))
    if shutil.which("taskset") is None:
        pytest.skip("taskset (util-linux) is not installed")
    out = subprocess.run(["taskset", "-c", "0", sys.executable, "-c",
                          "from raytrace.solver.config import TracerConfig; print(TracerConfig().threads)"],
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "1"


def test_a_config_is_frozen_pickles_and_refuses_bad_values_by_name():
    config = TracerConfig(threads=3, launch_batch=5_000)
    assert pickle.loads(pickle.dumps(config)) == config
    assert json.loads(json.dumps(dataclasses.asdict(config)))["launch_batch"] == 5_000
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.threads = 4
    for bad, match in (({"threads": 0}, "threads: expected an int >= 1"),
                       ({"threads": 2.0}, "threads: expected an int"),
                       ({"max_iterations": True}, "max_iterations: expected an int"),
                       ({"miss_tolerance_m": 0.0}, "miss_tolerance_m: expected a finite number > 0"),
                       ({"zoom_miss_m": float("nan")}, "zoom_miss_m: expected a finite number"),
                       ({"curvature_margin": -1.0}, "curvature_margin: expected a finite number >= 0"),
                       ({"stall_factor": 1.5}, "stall_factor: must be at most 1"),
                       ({"max_live_rays": 10_000}, "max_live_rays: must exceed launch_batch")):
        with pytest.raises(ValueError, match=match):
            TracerConfig(**bad)
    assert TracerConfig(curvature_margin=0.0, line_search_growth=0).curvature_margin == 0.0


def test_no_tuning_constant_is_left_in_the_solver_or_the_engine():
    """The constants TracerConfig replaced are gone from the modules (a module constant and a
    config field of one meaning would be two truths)."""
    from raytrace.solver import direct, sbr, tracer

    gone = {sbr: ["LAUNCH_BATCH", "MAX_LIVE_RAYS", "SHOOT_THREADS", "RECEPTION_FACTOR", "CURVATURE_MARGIN",
                  "CHUNK_RAYS"],
            direct: ["MAX_EVENTS", "SEEDS_PER_RECEIVER", "BATCH", "WALK_THREADS", "GRID", "ZOOM_LEVELS", "ZOOM_MISS_M"],
            refine: ["MISS_TOLERANCE_M", "MAX_STEP_RAD", "MAX_ITERATIONS", "STALL_WINDOW", "STALL_FACTOR",
                     "LINE_SEARCH_HALVINGS", "LINE_SEARCH_GROWTH", "NEWTON_CHUNK"],
            tracer: ["THREADS", "SEEDS_PER_SIGNATURE", "SEED_SEPARATION", "DUPLICATE_ANGLE_RAD"]}
    for module, names in gone.items():
        assert [n for n in names if hasattr(module, n)] == [], module.__name__


def _oblique_seed():
    """The half-space's direct path to a receiver in air 3 mm off the normal through the
    transmitter: the straight launch (2 deg, inside the ~7 deg escape cone; refracted ~8 times
    wider) misses it by centimetres and needs several Newton iterations."""
    phantom = half_space()
    media = MediaTable.build(phantom, np.array([402e6]))
    scene = scene_for(phantom, ~media.face_transparent)
    tx = np.asarray(phantom.sites["tx"].position_m, float)
    rx = np.array([[0.003, -0.05, 0.0]])
    launch = (rx - tx) / np.linalg.norm(rx - tx)
    args = (scene, media, tx, 0, rx, launch, np.full((1, 1), refine.encode(0, 1, 0)), np.ones(1, np.int64))
    return args


def test_newtons_settings_reach_the_kernel():
    """The config's Newton settings are the kernel's: with the default the oblique direct path
    converges to 1e-9 m; one iteration, or a step capped at 1e-6 rad, cannot get there."""
    args = _oblique_seed()
    assert refine.refine(*args).converged.all()
    assert refine.refine(*args, config=TracerConfig()).converged.all()
    assert not refine.refine(*args, config=TracerConfig(max_iterations=1)).converged.any()
    assert not refine.refine(*args, config=TracerConfig(max_step_rad=1e-6)).converged.any()
    loose = refine.refine(*args, config=TracerConfig(miss_tolerance_m=1e-3))
    assert loose.converged.all() and loose.segments < refine.refine(*args).segments


def test_trace_channel_takes_a_config_and_threads_do_not_change_the_answer():
    """One thread or two: the same paths (the tracer merges its workers' results in a fixed
    order); a config that gives Newton one iteration finds fewer paths (the config reaches
    every refinement)."""
    spec = rt.ChannelSpec(rt.Antenna(site="tx"), (rt.Antenna(site="rx_oblique"), rt.Antenna(site="rx_normal")),
                          phantom="half-space", rays=4000, max_interactions=3)
    phantom = half_space()
    one = rt.trace_channel(spec, phantom, config=TracerConfig(threads=1))
    two = rt.trace_channel(spec, phantom, config=TracerConfig(threads=2))
    delays = [[p.delay_s for p in profile.paths] for profile in one.profiles]
    assert delays == [[p.delay_s for p in profile.paths] for profile in two.profiles] and all(delays)
    starved = rt.trace_channel(spec, phantom, config=TracerConfig(max_iterations=1))
    assert starved.stats.paths_found < one.stats.paths_found


def test_the_service_builds_its_config_from_its_settings(monkeypatch):
    from pydantic import ValidationError

    from service.settings import Settings

    monkeypatch.setenv("CAPSULE_RT_TRACER_THREADS", "3")
    monkeypatch.setenv("CAPSULE_RT_TRACER_LAUNCH_BATCH", "20000")
    config = Settings().tracer_config()
    assert (config.threads, config.launch_batch, config.max_live_rays) == (3, 20_000, TracerConfig().max_live_rays)
    monkeypatch.delenv("CAPSULE_RT_TRACER_THREADS")
    assert Settings().tracer_config().threads == TracerConfig().threads
    monkeypatch.setenv("CAPSULE_RT_TRACER_MAX_LIVE_RAYS", "15000")  # below the launch batch
    with pytest.raises(ValidationError, match="max_live_rays"):
        Settings()
