"""The built-in ``abdomen-ct`` phantom: one real patient's abdomen, built from vendored CT-derived surfaces by the
anatomy pipeline (docs/phantoms.md, "The built-in CT abdomen").

Source
------
Model EdinGCA_3D_00090 of the Edinburgh Gut Cell Atlas (GCA-Models, commit a9f22b6), licensed CC BY 4.0:
A. Burger, R. A. Baldock, D. J. Adams, S. Din, I. Papatheodorou, M. Glinka, B. Hill, D. Houghton, M. Sharghi,
M. Wicks, M. J. Arends, "Towards a clinically-based common coordinate framework for the human gut cell atlas:
the gut models", BMC Medical Informatics and Decision Making 23, 36 (2023), doi:10.1186/s12911-023-02111-9.
The files used are vendored unchanged in ``raytrace/body/data/abdomen-ct/`` with the licence and
``ATTRIBUTION.md``; what this project made of them (the phantom: a generated body wall, organs cut apart,
repaired and decimated, sites) is described there and in docs/phantoms.md.

What it is
----------
``raytrace/body/data/abdomen-ct/manifest.yaml`` through :func:`raytrace.body.anatomy.build_phantom`, the one
pipeline of uploads and the CLI: the body surface with a generated skin (2 mm), subcutaneous fat (15 mm)
and muscle wall (10 mm) over a muscle-like visceral fill (``visceral_cavity``, as the default torso's);
the oesophagus, the stomach, the small intestine (duodenum to ileum) and the large intestine (caecum to
anus) as separate organs; the mid-lines as the capsule's journey (centreline ``gi_tract``: oesophagus ->
stomach -> duodenum -> jejunum -> ileum -> caecum -> colon -> rectum) with the model's landmarks and the
midpoints of its regions as capsule sites; contact sensors on the skin. Frame: the project's, metres
(x subject's left, y posterior, z up; origin on the body's mid-line at the scan's lowest slice).

Built once, cached on disk
--------------------------
The build takes about a minute of CPU. :func:`abdomen_ct` loads the built phantom from the cache
directory (:func:`cache_dir`: ``$CAPSULE_RT_CACHE_DIR``, else ``$XDG_CACHE_HOME/capsule-rt``, else
``~/.cache/capsule-rt``), under a key that hashes every vendored file, the pipeline's and the phantom
model's source code and the versions of the libraries whose output it depends on (:func:`source_key`), so
any change rebuilds it and nothing stale is ever loaded. A missing entry is built (under a file lock,
so concurrent processes build it once) and written atomically. ``make run`` / ``make test`` build it at
install time (``python -m raytrace.body.abdomen``), so a server's first start only loads it.
Loading re-creates the phantom from the cached float64 arrays through :meth:`Phantom.build` without the
crossing test (the build passed every check on these very arrays) and keeps the sites' media the build
established; a freshly built phantom is the cached one reloaded, so both give the same numbers.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import json
import os
import shutil
import sys
import tempfile
import time
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np
import trimesh

from raytrace.body.centreline import Centreline
from raytrace.body.phantom import Organ, Phantom, Site
from raytrace.physics.materials import Material

__all__ = ["ABDOMEN_NAME", "DATA_DIR", "abdomen_ct", "build", "cache_dir", "cached_path", "source_key"]

ABDOMEN_NAME = "abdomen-ct"
#: The vendored source files, their licence, attribution and the build manifest.
DATA_DIR = Path(__file__).resolve().parent / "data" / ABDOMEN_NAME
MANIFEST = DATA_DIR / "manifest.yaml"
#: Bumped when the cache's own format changes (its readers below).
CACHE_FORMAT = 3
#: Source code whose change changes the built phantom (hashed into the cache key).
_CODE = ("anatomy/*.py", "anatomy/*.json", "phantom.py", "centreline.py", "selfintersect.py", "abdomen.py")
#: Libraries whose output the build depends on (their versions are hashed into the key).
_LIBRARIES = ("numpy", "scipy", "trimesh", "manifold3d", "fast-simplification", "scikit-image", "scikit-fmm",
              "meshio", "embreex")


def cache_dir() -> Path:
    """Where built phantoms are kept (module docstring)."""
    explicit = os.environ.get("CAPSULE_RT_CACHE_DIR")
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "capsule-rt"


def _data_files() -> list[Path]:
    return sorted(p for p in DATA_DIR.rglob("*") if p.is_file() and not p.name.startswith("."))


@functools.cache
def source_key() -> str:
    """sha256 (first 16 hex digits) of every vendored file, the pipeline's code and the libraries' versions."""
    digest = hashlib.sha256(f"format {CACHE_FORMAT}\n".encode())
    for path in _data_files():
        digest.update(path.relative_to(DATA_DIR).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    here = Path(__file__).resolve().parent
    for pattern in _CODE:
        for path in sorted(here.glob(pattern)):
            digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    for name in _LIBRARIES:
        try:
            version = importlib_metadata.version(name)
        except importlib_metadata.PackageNotFoundError:
            version = "absent"
        digest.update(f"{name}=={version}\n".encode())
    return digest.hexdigest()[:16]


def cached_path() -> Path:
    """The cache entry of the current sources (it may not exist yet)."""
    return cache_dir() / "phantoms" / f"{ABDOMEN_NAME}-{source_key()}"


def build(progress=None):
    """Build the phantom from the vendored files through the anatomy pipeline: a
    :class:`raytrace.body.anatomy.BuildResult` (the phantom and the build report)."""
    import yaml

    from raytrace.body.anatomy import build_phantom

    manifest = yaml.safe_load(MANIFEST.read_text())
    return build_phantom(manifest, DATA_DIR, progress=progress)


# ----------------------------------------------------------------------------- cache: write and read
def _write(phantom: Phantom, report: dict, target: Path) -> None:
    """The phantom's arrays (float64) and everything else as JSON, into ``target`` atomically."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}-", dir=target.parent))
    try:
        arrays = {}
        organs = []
        for i, organ in enumerate(phantom.organs):
            arrays[f"v{i}"] = np.asarray(organ.mesh.vertices, np.float64)
            arrays[f"f{i}"] = np.asarray(organ.mesh.faces, np.int64)
            m = organ.material
            organs.append({"name": organ.name, "tissue": m.tissue,
                           "relative_permittivity": None if m.tissue else m.relative_permittivity,
                           "conductivity_s_per_m": None if m.tissue else m.conductivity_s_per_m,
                           "crease_angle_deg": organ.crease_angle_deg})
        for name, line in phantom.centrelines.items():
            for k, piece in enumerate(line.pieces):
                arrays[f"c:{name}:{k}"] = np.asarray(piece.points_m, np.float64)
        with open(tmp / "arrays.npz", "wb") as fh:
            np.savez(fh, **arrays)  # type: ignore[arg-type]  # numpy's stub takes **kwds for allow_pickle
        meta = {
            "format": CACHE_FORMAT, "key": source_key(), "name": phantom.name, "description": phantom.description,
            "organs": organs, "parent": [int(i) for i in phantom.parent],
            "sites": {n: {"kind": s.kind, "position_m": [float(x) for x in s.position_m], "medium": s.medium}
                      for n, s in phantom.sites.items()},
            "centrelines": {n: [p.organ for p in line.pieces] for n, line in phantom.centrelines.items()},
            "metadata": phantom.metadata,
        }
        (tmp / "phantom.json").write_text(json.dumps(meta, indent=1, default=float))
        (tmp / "report.json").write_text(json.dumps(report, indent=1, default=float))
        from raytrace.body.anatomy import markdown_report

        (tmp / "report.md").write_text(markdown_report(report))
        for path in tmp.iterdir():
            with open(path, "rb") as fh:
                os.fsync(fh.fileno())
        try:
            os.rename(tmp, target)
        except OSError:  # another process wrote the same entry first: identical content, keep theirs
            if not (target / "phantom.json").exists():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _read(path: Path) -> Phantom:
    meta = json.loads((path / "phantom.json").read_text())
    if meta.get("format") != CACHE_FORMAT:
        raise ValueError(f"{path}: cache format {meta.get('format')!r}, expected {CACHE_FORMAT}")
    with np.load(path / "arrays.npz") as arrays:
        organs = []
        for i, spec in enumerate(meta["organs"]):
            material = (Material(tissue=spec["tissue"]) if spec["tissue"] else
                        Material(relative_permittivity=spec["relative_permittivity"],
                                 conductivity_s_per_m=spec["conductivity_s_per_m"]))
            mesh = trimesh.Trimesh(arrays[f"v{i}"], arrays[f"f{i}"], process=False, validate=False)
            organs.append(Organ(spec["name"], material, mesh, spec["crease_angle_deg"]))
        lines = {name: Centreline([(organ, arrays[f"c:{name}:{k}"]) for k, organ in enumerate(pieces)])
                 for name, pieces in meta["centrelines"].items()}
    phantom = Phantom.build(meta["name"], organs, description=meta["description"], check_crossings=False)
    if phantom.parent.tolist() != meta["parent"]:  # the same organs, bit for bit: the same containment
        raise ValueError(f"{path}: the containment tree rebuilt from the cache differs from the build's")
    # the sites were placed and checked by the build (the same organs, bit for bit): their media are kept
    phantom.sites.update({n: Site(n, s["kind"], np.array(s["position_m"], float), s["medium"])
                          for n, s in meta["sites"].items()})
    phantom.centrelines.update(lines)
    phantom.metadata.update(meta["metadata"])
    phantom.metadata.update({"cache": str(path), "cache_key": meta["key"]})
    return phantom


@contextlib.contextmanager
def _lock(path: Path):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def ensure_built(progress=None, *, log=None) -> Path:
    """The cache entry of the current sources, built first when missing (module docstring)."""
    target = cached_path()
    if (target / "phantom.json").exists():
        return target
    with _lock(target.parent / f".{target.name}.lock"):
        if (target / "phantom.json").exists():  # built by another process while this one waited
            return target
        if log is not None:
            log(f"building the {ABDOMEN_NAME} phantom from {DATA_DIR} (once; cached in {target})")
        result = build(progress)
        _write(result.phantom, result.report, target)
    return target


@functools.cache
def abdomen_ct() -> Phantom:
    """The ``abdomen-ct`` phantom, built once per process (from the disk cache when there; module docstring).
    Treat it as immutable: it is shared between callers."""
    return _read(ensure_built())


def main(argv: list[str] | None = None) -> int:
    """``python -m raytrace.body.abdomen [--load] [--report]``: build (or find) the cached phantom and say where;
    ``--load`` also loads it (and times that), ``--report`` prints the build report."""
    argv = list(sys.argv[1:] if argv is None else argv)
    t0, c0 = time.perf_counter(), time.process_time()
    existed = (cached_path() / "phantom.json").exists()
    path = ensure_built(lambda f, msg: print(f"[{time.perf_counter() - t0:7.1f} s] {f:4.0%} {msg}", flush=True),
                        log=print)
    t1, c1 = time.perf_counter(), time.process_time()
    if existed and "--load" not in argv:  # what `make run` asks before serving: only that it is there
        print(f"{ABDOMEN_NAME}: cached in {path}")
    else:
        phantom = _read(path)
        t2, c2 = time.perf_counter(), time.process_time()
        what = "found" if existed else f"built in {t1 - t0:.0f} s ({c1 - c0:.0f} s CPU)"
        print(f"{ABDOMEN_NAME}: {what}: {path}; {phantom.triangle_count} triangles, {len(phantom.organs)} organs, "
              f"{len(phantom.sites)} sites; loaded in {t2 - t1:.2f} s ({c2 - c1:.2f} s CPU)")
    if "--report" in argv:
        print((path / "report.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
