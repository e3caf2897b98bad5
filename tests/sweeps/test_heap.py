"""sweeps.heap: a task's large temporaries reuse the heap even in a worker started with a trim threshold.

The oracle is the kernel's count of minor page faults (``getrusage``), not time: a 1 MiB array
that is a fresh ``mmap`` faults in its 256 pages every time it is allocated; one served from
the heap faults them in once. Measured in a child process started the way Dask's nanny starts
a worker (``MALLOC_TRIM_THRESHOLD_=65536``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.conftest import HANG_GUARD_S

CHILD = r"""
import json, resource
import numpy as np
from sweeps.heap import task_heap, tuned_by_environment

def faults(n=200, size=2**20):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(n):
        a = np.ones(size // 8)   # written, so its pages are touched
        del a
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

out = {"tuned": tuned_by_environment(), "outside": faults()}
with task_heap() as changed:
    out["changed"] = changed
    out["inside"] = faults()
out["after"] = faults()
print(json.dumps(out))
"""


def _child(env_extra: dict) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env.update(env_extra)
    done = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=HANG_GUARD_S,
                          cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_task_heap_reuses_memory_in_a_dask_style_worker_and_restores_its_policy():
    out = _child({"MALLOC_TRIM_THRESHOLD_": "65536"})
    assert out["tuned"] and out["changed"]
    # 200 arrays of 256 pages: ~51 200 faults as fresh mmaps; from the heap, the first one's 256
    # (plus interpreter noise). A factor of 10 separates the two regimes with room on both sides.
    assert out["outside"] > 200 * 256 * 0.8, out
    assert out["inside"] * 10 < out["outside"], out
    # the worker's own policy is back after the task
    assert out["after"] > 200 * 256 * 0.8, out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator")
def test_task_heap_leaves_an_untuned_process_alone():
    out = _child({})
    assert not out["tuned"] and not out["changed"]
    # glibc's dynamic threshold already serves repeated 1 MiB arrays from the heap
    assert out["inside"] * 10 < 200 * 256, out
