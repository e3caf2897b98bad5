"""``schemathesis run --checks all`` on every operation of a live server (issue 25's acceptance).

The CLI, as a user runs it, against a uvicorn subprocess (``capsule-rt serve``) with small limits
(2000 rays, 3 interactions, 4 receivers, 11 band points, 20 trials, 64 KiB uploads, sweeps of two
traces one at a time) and a 5 s deadline, which its served ``/openapi.json`` states, so generated
requests stay cheap. Every check (``--checks all``): no 5xx, declared status codes, content
types, headers and bodies conforming, schema-valid data accepted and schema-invalid data refused,
OPTIONS/405 per the contract (``unsupported_method``, ``allow_header_conformance``), missing
required headers. The phases: examples, fuzzing, stateful (links between operations: the phantoms'
and sweeps' ids; ``use_after_free`` and ``ensure_resource_availability`` run there). The server has
no API keys, so ``ignored_auth`` has no security scheme to test; with keys the keyed writes are
covered by tests/service/test_job_keys.py, tests/e2e/test_hardening.py and
tests/service/test_hardening.py.

No response time decides anything (issue 34, item 11: on a loaded 2-core machine a model-based fix took
14 s and a render 26 s to answer their 504, and a 10 s limit failed the run): ``max_response_time``, which
``--checks all`` turns on with a 10 s default limit and cannot exclude, gets the hang guard's limit, as
``--request-timeout`` does: both only catch a hang (tests.conftest.HANG_GUARD_S). That the
server stops work at its deadline, or when a client leaves, is tested with injected clocks and held
work (tests/service/test_ranging_budget.py, test_track_budget.py, test_saturation.py).

The failures the hooks (``tests/schemathesis_hooks.py``) forgive are the documented 422s of rules
JSON Schema cannot state, 413s to oversized schema-invalid bodies, and the documented 503 (saturated)
and 504 (deadline) of a bounded server; everything else fails the
test. Examples per operation are bounded (``-n``) and the coverage phase is left out so the run fits
CI (about 1 min on a quiet machine); ``CAPSULE_RT_FUZZ_EXAMPLES=20
CAPSULE_RT_FUZZ_PHASES=examples,coverage,fuzzing,stateful`` is the full audit (about 6 min on two quiet cores).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

import httpx
import pytest

from tests.conftest import HANG_GUARD_S, REPO, free_port, wait_ready

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

SMALL_LIMITS = {
    "CAPSULE_RT_MAX_RAYS": "2000",
    "CAPSULE_RT_MAX_INTERACTIONS": "3",
    "CAPSULE_RT_MAX_RECEIVERS": "4",
    "CAPSULE_RT_MAX_BAND_POINTS": "11",
    "CAPSULE_RT_MAX_TRIALS": "20",
    "CAPSULE_RT_MAX_UPLOAD_BYTES": "65536",
    "CAPSULE_RT_MAX_CONCURRENCY": "2",
    "CAPSULE_RT_MAX_QUEUE": "64",
    "CAPSULE_RT_SWEEP_MAX_QUEUE": "1",
    "CAPSULE_RT_SWEEP_MAX_TRACES": "2",
    "CAPSULE_RT_SWEEP_WORKERS": "1",
    "CAPSULE_RT_REQUEST_DEADLINE_S": "5",
}


@pytest.fixture(scope="module")
def small_server(tmp_path_factory):
    """A live server of its own (also in the client container: its small limits keep the run short)."""
    port = free_port()
    data_dir = tmp_path_factory.mktemp("fuzz-data")
    log_path = tmp_path_factory.mktemp("fuzz-log") / "server.log"
    env = {**os.environ, "CAPSULE_RT_DATA_DIR": str(data_dir), "CAPSULE_RT_LOG_LEVEL": "warning", **SMALL_LIMITS}
    env.pop("CAPSULE_RT_API_KEYS", None)
    with open(log_path, "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "service.cli", "serve", "--host", "127.0.0.1", "--port",
                                 str(port)], cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        wait_ready(url, proc=proc)
        yield url, log_path
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()


def test_schemathesis_all_checks_on_every_operation_finds_nothing(small_server, tmp_path):
    url, log_path = small_server
    schema = httpx.get(f"{url}/openapi.json", timeout=HANG_GUARD_S).json()
    operations = sum(1 for item in schema["paths"].values() for method in item
                     if method in ("get", "put", "post", "delete", "patch"))
    examples = os.environ.get("CAPSULE_RT_FUZZ_EXAMPLES", "5")
    # the coverage phase (boundary values of every schema, ~6 min here) only on request: CI runs the others
    phases = os.environ.get("CAPSULE_RT_FUZZ_PHASES", "examples,fuzzing,stateful")
    env = {**os.environ, "SCHEMATHESIS_HOOKS": "tests.schemathesis_hooks",
           "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "schemathesis.cli", "run", f"{url}/openapi.json", "--checks", "all",
           "--max-response-time", str(int(HANG_GUARD_S)),
           "--phases", phases, "--max-examples", examples, "--workers", "1", "--generation-deterministic",
           "--request-timeout", str(int(HANG_GUARD_S)), "--no-color", "--output-truncate", "true",
           "--report", "junit", "--report-dir", str(tmp_path)]
    # run from a scratch directory: schemathesis keeps a crash cache under ./.schemathesis
    # a hang guard for the whole run (a few minutes on a loaded machine), as pytest's own (pyproject.toml)
    run = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=3 * HANG_GUARD_S)
    out = run.stdout + run.stderr
    tested = re.search(r"Tested:\s+(\d+)", out)
    # every operation was exercised (a schema that failed to load, or an operation filtered out, fails here)
    assert tested is not None and int(tested.group(1)) == operations, out[-3000:]
    assert run.returncode == 0, (f"schemathesis found failures (exit {run.returncode}):\n{out[-12000:]}\n"
                                 f"server log tail:\n{log_path.read_text(errors='replace')[-3000:]}")
