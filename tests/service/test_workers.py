"""service.workers: what the next runner reaps is exactly the recorded workers that still run (issue 34,
item 5; the end-to-end case, a SIGKILLed server's pool, is tests/e2e/test_orphans.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from service.workers import reap, start_time
from tests.conftest import HANG_GUARD_S

pytestmark = pytest.mark.skipif(start_time(1) is None, reason="Linux /proc")


def _sleeper() -> subprocess.Popen:
    # a process group of its own, as a registered worker leads one (with a child of its own in it)
    child = "subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])"
    return subprocess.Popen([sys.executable, "-c", f"import subprocess, sys, time; {child}; time.sleep(600)"],
                            start_new_session=True)


def test_reap_kills_a_recorded_worker_and_its_group_but_never_a_recycled_pid(tmp_path):
    records = tmp_path / ".jobs-workers"
    records.mkdir()
    worker, stranger = _sleeper(), _sleeper()
    try:
        (records / str(worker.pid)).write_text(str(start_time(worker.pid)))
        (records / str(stranger.pid)).write_text(str(start_time(stranger.pid) - 1))  # the pid, recycled
        (records / ".123.tmp").write_text("half")
        assert reap(records) == [worker.pid]
        assert worker.wait(timeout=HANG_GUARD_S) == -9  # a hang guard only: SIGKILL is immediate
        assert stranger.poll() is None
        assert list(records.iterdir()) == []
        assert reap(records) == []
    finally:
        for p in (worker, stranger):  # their whole groups: the sleepers' own children too
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.wait()
