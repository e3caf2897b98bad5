"""The typed client and ``capsule-rt --help`` stay light (issue 37): ``import service.client`` loads
neither numba, embreex nor the tracer (``raytrace``), and ``capsule-rt --help`` loads neither numba nor
matplotlib. Read off ``sys.modules`` in a fresh interpreter (never by timing)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.conftest import HANG_GUARD_S

PROBE = """
import json, sys
{code}
print(json.dumps(sorted({{name.split(".")[0] for name in sys.modules}})))
"""


def _loaded(code: str) -> set[str]:
    """The top-level packages in ``sys.modules`` after running ``code`` in a fresh interpreter (it
    inherits PYTHONPATH, so the tree under test is the one imported)."""
    out = subprocess.run([sys.executable, "-c", PROBE.format(code=code)], capture_output=True, text=True,
                         timeout=HANG_GUARD_S, check=True)
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


def test_the_probe_sees_a_heavy_import():
    """The check can fail: importing the tracer's front door shows numba and embreex."""
    assert {"raytrace", "numba", "embreex"} <= _loaded("import raytrace")


def test_the_typed_client_loads_no_tracer():
    loaded = _loaded("import service.client")
    assert {"httpx", "pydantic", "service"} <= loaded
    assert not loaded & {"numba", "embreex", "raytrace", "llvmlite", "matplotlib"}, sorted(loaded)


@pytest.mark.parametrize("argv", [["--help"], ["channel", "--help"], ["track", "--help"]])
def test_capsule_rt_help_loads_no_numba_nor_matplotlib(argv):
    code = (f"from service.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
            "sys.stdout.flush()")
    loaded = _loaded(code)
    assert "service" in loaded
    assert not loaded & {"numba", "matplotlib", "embreex", "raytrace"}, sorted(loaded)


def test_the_deferred_commands_still_build_in_full():
    """``capsule-rt plot --help`` and ``experiment --help`` list their choices (they load what they need)."""
    from service.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name in ("plot", "experiment"):
        kind = next(a for a in sub.choices[name]._actions if a.dest in ("kind", "name"))
        assert kind.choices, name
