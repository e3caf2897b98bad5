"""The README's promises: exactly two commands in its first code block, and
its Python example runs as written."""

from __future__ import annotations

import re
from pathlib import Path

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


def test_python_example_runs(capsys) -> None:
    (block,) = _blocks("python")
    exec(compile(block, "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert "refraction" in out  # the direct path to the belt sensor is printed
    assert "TOAResult" in out or "distance_m" in out
