"""The guards of the numba/Embree boundary (raytrace/engine): the Embree version checked at load,
the library found in every embreex wheel layout, NUMBA_DISABLE_JIT=1 running the kernels as
Python through ctypes, the on-disk cache keyed on the engine's sources, `make clean` clearing it,
numba's private option confined to raytrace/engine/jit.py and pinned, and numba, llvmlite and
ctypes imported nowhere in raytrace/ but the engine. Each test fails if its guard is removed."""

from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest
from packaging.requirements import Requirement

from raytrace.engine import embree

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "raytrace"


# ------------------------------------------------------------------ Embree version at load
class _FakeEmbree:
    """Stands in for a ctypes library: the device calls Embree's version check makes."""

    def __init__(self, major: int, minor: int, patch: int):
        values = {0: major * 10_000 + minor * 100 + patch, 1: major, 2: minor, 3: patch}
        self.released = []
        self.rtcNewDevice = lambda config: 0x1000
        self.rtcGetDeviceProperty = lambda device, prop: values[prop]
        self.rtcReleaseDevice = lambda device: self.released.append(device)


def test_the_loaded_embree_is_version_4():
    """The library the kernels call reports Embree 4.x (read from a device, not from a file
    name), and the check reads the same version again."""
    assert embree.VERSION[0] == 4
    import ctypes

    assert embree.check_version(ctypes.CDLL(embree.LIBRARY_PATH), embree.LIBRARY_PATH) == embree.VERSION


@pytest.mark.parametrize("version", [(3, 13, 5), (5, 0, 0)])
def test_another_major_version_is_refused_naming_found_and_expected(version):
    fake = _FakeEmbree(*version)
    with pytest.raises(ImportError) as err:
        embree.check_version(fake, "/opt/lib/libembree.so")
    message = str(err.value)
    assert ".".join(map(str, version)) in message and "Embree 4.x expected" in message
    assert "/opt/lib/libembree.so" in message
    assert fake.released == [0x1000]  # the device is released either way
    assert embree.check_version(_FakeEmbree(4, 4, 0), "x") == (4, 4, 0)


def test_loading_checks_the_version_before_the_kernels_can_call_in(monkeypatch):
    """The module's loader refuses an Embree 3 library before llvmlite makes its symbols
    visible to compiled code."""
    loaded = []
    monkeypatch.setattr(embree, "library_path", lambda: "/fake/libembree4.so.4")
    monkeypatch.setattr(embree.ctypes, "CDLL", lambda path: _FakeEmbree(3, 13, 5))
    monkeypatch.setattr(embree.llvmlite.binding, "load_library_permanently", loaded.append)
    with pytest.raises(ImportError, match="found Embree 3.13.5"):
        embree._load()
    assert loaded == []


# ------------------------------------------------------------------ the library in each wheel layout
def _touch(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return path


@pytest.mark.parametrize("platform, library, decoys", [
    ("linux", "embreex.libs/libembree4-4aef3270.so.4", ["embreex.libs/libtbb-dcf63f8c.so.12"]),
    ("darwin", "embreex/.dylibs/libembree4.4.dylib", ["embreex/.dylibs/libtbb.12.dylib"]),
    ("win32", "embreex.libs/embree4.dll", ["embreex.libs/tbb12.dll", "embreex.libs/.load-order-embreex-4.4.0"]),
])
def test_the_library_is_found_in_each_wheel_layout(tmp_path, platform, library, decoys):
    """auditwheel (Linux), delocate (macOS) and delvewheel (Windows) put the Embree library in
    different places beside the embreex package: each is found, its neighbours are not taken."""
    _touch(tmp_path / "embreex" / "__init__.py")
    for decoy in decoys:
        _touch(tmp_path / decoy)
    expected = _touch(tmp_path / library)
    assert Path(embree.library_path(tmp_path, platform)) == expected


def test_the_system_library_is_the_fallback_and_its_absence_names_the_places_searched(tmp_path, monkeypatch):
    _touch(tmp_path / "embreex" / "__init__.py")
    system = {"embree4": "libembree4.so.4"}
    monkeypatch.setattr(embree.ctypes.util, "find_library", system.get)
    assert embree.library_path(tmp_path, "linux") == "libembree4.so.4"
    monkeypatch.setattr(embree.ctypes.util, "find_library", lambda name: None)
    with pytest.raises(ImportError) as err:
        embree.library_path(tmp_path, "darwin")
    assert str(tmp_path / "embreex/.dylibs/libembree4*.dylib") in str(err.value)


# ------------------------------------------------------------------ NUMBA_DISABLE_JIT=1
_PYTHON_MODE = textwrap.dedent("""
    import json, sys
    import numpy as np
    from raytrace.engine import embree, kernels
    from raytrace.body.library import half_space
    from raytrace.engine.scene import scene_for
    from raytrace.solver import refine
    from raytrace.solver.media import MediaTable

    compiled = hasattr(kernels.follow, "signatures")
    square = embree.EmbreeScene(np.array([[-1, -1, 0.5], [1, -1, 0.5], [1, 1, 0.5], [-1, 1, 0.5]], np.float32),
                                np.array([[0, 1, 2], [0, 2, 3]]))
    hits = square.intersect(np.array([[0.2, 0.3, 0.0], [0.5, -0.4, 0.0], [3.0, 0.0, 0.0]]),
                            np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]))
    phantom = half_space()
    media = MediaTable.build(phantom, np.array([402e6]))
    scene = scene_for(phantom, ~media.face_transparent)
    tx = np.asarray(phantom.sites["tx"].position_m, float)
    rx = np.array([0.003, -0.05, 0.002])  # in air, a few degrees off the normal through tx
    d = np.array([[0.05, -1.0, 0.02], [-0.03, -1.0, 0.0], [0.0, -1.0, 0.4]])  # the last one totally reflected
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    code = refine.encode(0, 1, 0)  # leaving the muscle block into air
    run = refine.follow(scene, media, tx, 0, d, np.full((3, 1), code), np.ones(3, np.int64),
                        tangents=refine.tangent_basis(d))
    direct = (rx - tx) / np.linalg.norm(rx - tx)
    newton = refine.refine(scene, media, tx, 0, rx[None, :], direct[None, :], np.full((1, 1), code),
                           np.ones(1, np.int64))
    print(json.dumps({"compiled": compiled, "prim": hits.prim.tolist(), "tfar": hits.tfar.tolist(),
                      "ok": run.ok.tolist(), "point": run.last_point.tolist(), "d_dir": run.d_dir.tolist(),
                      "converged": newton.converged.tolist(), "dirs": newton.dirs.tolist(),
                      "tube": newton.tube_m2_per_sr.tolist()}))
""")


def _run(script: str, env: dict | None = None, cwd: Path = ROOT) -> dict:
    out = subprocess.run([sys.executable, "-c", script], cwd=cwd, env={**os.environ, **(env or {})},
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_with_the_jit_disabled_the_kernels_run_as_python_and_call_embree_through_ctypes():
    """NUMBA_DISABLE_JIT=1 (for pdb or coverage inside a kernel): the kernels are the Python
    functions and Embree is called through ctypes, so a ray that hits reports its hit. Oracle:
    the compiled kernels on the same inputs. Tolerance: the same IEEE operations in the same
    order give the same doubles; 1e-12 relative leaves room for libm's last bit."""
    python = _run(_PYTHON_MODE, {"NUMBA_DISABLE_JIT": "1"})
    jit = _run(_PYTHON_MODE, {"NUMBA_DISABLE_JIT": "0"})
    assert not python["compiled"] and jit["compiled"]
    assert python["prim"] == jit["prim"] and python["prim"][:2] != [-1, -1] and python["prim"][2] == -1
    assert python["tfar"][:2] == pytest.approx([0.5, 0.5], rel=1e-6)
    assert python["ok"] == jit["ok"] == [True, True, False]
    assert jit["converged"] == [True] == python["converged"]
    for key in ("point", "d_dir", "dirs", "tube"):
        np.testing.assert_allclose(python[key], jit[key], rtol=1e-12, atol=1e-15)


# ------------------------------------------------------------------ the cache keyed on the engine's sources
_PROBE = textwrap.dedent('''
    """A kernel in one engine module that calls a compiled function of another (test only)."""
    from raytrace.engine import embree
    from raytrace.engine.jit import kernel


    @kernel
    def first_hit(handle, base, ox, oy, oz, dx, dy, dz):
        return embree.intersect(handle, embree.ALL, base, embree.ray_hit(), ox, oy, oz, dx, dy, dz)[0]
''')

_CALL_PROBE = textwrap.dedent("""
    import json
    import numpy as np
    from raytrace.engine import embree, probe
    square = embree.EmbreeScene(np.array([[-1, -1, 0.5], [1, -1, 0.5], [1, 1, 0.5], [-1, 1, 0.5]], np.float32),
                                np.array([[0, 1, 2], [0, 2, 3]]))
    args = (square.handle, square.base, np.float32(0.2), np.float32(0.3), np.float32(0.0), np.float32(0.0),
            np.float32(0.0), np.float32(1.0))
    probe.first_hit(*args)
    print(json.dumps({"prim": int(probe.first_hit(*args)), "hits": probe.first_hit.stats.cache_hits.total(),
                      "misses": probe.first_hit.stats.cache_misses.total()}))
""")


@pytest.mark.slow
def test_an_edit_of_the_binding_recompiles_the_kernels_that_call_it(tmp_path):
    """A copy of the package with a probe kernel in one engine module calling
    ``embree.intersect``: compiled and cached by a first process, loaded from the cache by a
    second, recompiled by a third after ``embree.py`` is edited (every ray now misses) although
    the probe's own file is unchanged. numba alone stamps a cache with its kernel's file only,
    and the third process would run the stale machine code (a hit)."""
    shutil.copytree(PACKAGE, tmp_path / "raytrace", ignore=shutil.ignore_patterns("__pycache__"))
    engine = tmp_path / "raytrace" / "engine"
    (engine / "probe.py").write_text(_PROBE)
    env = {"PYTHONPATH": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    first = _run(_CALL_PROBE, env, cwd=tmp_path)
    again = _run(_CALL_PROBE, env, cwd=tmp_path)
    assert first["prim"] in (0, 1) and again["prim"] == first["prim"]
    assert first["misses"] >= 1 and again["hits"] >= 1 and again["misses"] == 0  # the cache works
    binding = engine / "embree.py"
    source = binding.read_text()
    assert source.count("if words[18] == _RTC_INVALID_ID:") == 1
    binding.write_text(source.replace("if words[18] == _RTC_INVALID_ID:", "if True:  # edited: every ray misses"))
    edited = _run(_CALL_PROBE, env, cwd=tmp_path)
    assert edited["prim"] == -1 and edited["misses"] >= 1


def test_make_clean_removes_the_compiled_kernels(tmp_path):
    """`make clean` removes numba's cache files (and bytecode) from the source tree, so the next
    process compiles from the sources."""
    shutil.copy(ROOT / "Makefile", tmp_path / "Makefile")
    cache = tmp_path / "raytrace" / "engine" / "__pycache__"
    files = [_touch(cache / "kernels.follow-123.py311.nbi"), _touch(cache / "kernels.follow-123.py311.1.nbc"),
             _touch(cache / "embree.cpython-311.pyc")]
    kept = _touch(tmp_path / "raytrace" / "engine" / "kernels.py")
    subprocess.run(["make", "clean", "VENV=venv-that-does-not-exist"], cwd=tmp_path, check=True, capture_output=True)
    assert not any(f.exists() for f in files) and kept.exists()


# ------------------------------------------------------------------ numba's private option, pinned; the import boundary
def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_only_the_engine_imports_numba_llvmlite_or_ctypes():
    outside = {str(p.relative_to(ROOT)): _imports(p) & {"numba", "llvmlite", "ctypes"}
               for p in PACKAGE.rglob("*.py") if "engine" not in p.relative_to(PACKAGE).parts}
    assert len(outside) > 20  # every other module of the package was read
    assert {name: found for name, found in outside.items() if found} == {}


def test_numbas_private_option_and_internals_are_used_in_jit_py_only():
    users = {p.name for p in PACKAGE.rglob("*.py") if "_nrt" in p.read_text() or "numba.core" in p.read_text()}
    assert users == {"jit.py"}
    from numba.core.registry import CPUDispatcher

    from raytrace.engine import kernels

    compiled = [d for d in vars(kernels).values() if isinstance(d, CPUDispatcher)]
    assert compiled and all(d.targetoptions.get("_nrt") is not True for d in compiled)


def test_numba_is_pinned_to_the_tested_minor_release():
    """``_nrt`` and the cache's source stamp are numba internals: pyproject allows only the numba
    (and llvmlite) minor release they were tested with, and the installed one is in it."""
    from importlib.metadata import version

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    pins = {Requirement(r).name: Requirement(r).specifier for r in project}
    for name in ("numba", "llvmlite"):
        spec = pins[name]
        assert any(s.operator == "<" for s in spec) and any(s.operator == ">=" for s in spec), spec
        assert version(name) in spec
        major, minor = (int(x) for x in version(name).split(".")[:2])
        assert f"{major}.{minor + 1}.0" not in spec  # the next minor release is not allowed untested
