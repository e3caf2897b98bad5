"""Surface files -> triangles: legacy and XML VTK, STL, OBJ, OFF through meshio; PLY through trimesh (its
reader is vectorised, meshio's reads binary face lists one by one); glTF/GLB through :mod:`raytrace.body.gltf`
(with its byte and triangle caps checked before decoding).

:func:`read_surface` answers ``(vertices (V, 3) float64, faces (F, 3) int64)`` in the file's own
units and frame; polygons are split into triangles (a fan from their first vertex), every other
cell kind (points, lines) is ignored, and a file that holds no surface at all, or volume cells
(tetrahedra, hexahedra: a volume mesh, not a surface), is refused naming the file.

meshio reads every format here except legacy VTK *POLYDATA* (meshio issue 527: it reads
unstructured grids only). A POLYDATA file is the same text (or big-endian binary) with polygons
instead of cells, so it is handed to meshio's own legacy reader with its ``DATASET`` renamed, its
``POLYGONS`` section renamed ``CELLS`` and a ``CELL_TYPES`` section declaring each cell a
``VTK_POLYGON`` (7) appended (:func:`_polydata_as_grid`); meshio does all the reading. Sections
other than POINTS, POLYGONS and point/cell data (VERTICES, LINES, TRIANGLE_STRIPS) are refused.
XML VTK PolyData (.vtp) is not read by meshio either: the refusal says to export .vtu or legacy .vtk.

Bounds (docs/phantoms.md, "Limits"): a file is refused before it is read when it is larger than
``max_bytes``; once read, when it holds more than ``max_triangles`` triangles (binary STL and
GLB say their counts in their headers, which are checked before anything is decoded).
"""

from __future__ import annotations

import os
import re
import struct
import tempfile
import warnings
from pathlib import Path

import numpy as np

from raytrace.errors import Field, PhantomValidationError

__all__ = ["SURFACE_SUFFIXES", "VOLUME_SUFFIXES", "read_surface", "suffix_of"]

SURFACE_SUFFIXES = (".vtk", ".vtu", ".stl", ".ply", ".obj", ".off", ".glb", ".gltf")
VOLUME_SUFFIXES = (".nii", ".nii.gz")
_MESHIO_FORMATS = {".vtk": "vtk", ".vtu": "vtu", ".stl": "stl", ".ply": "ply", ".obj": "obj", ".off": "off"}
_VOLUME_CELLS = ("tetra", "hexahedron", "wedge", "pyramid", "tetra10", "hexahedron20", "hexahedron27")


def suffix_of(name: str) -> str:
    lower = name.lower()
    return ".nii.gz" if lower.endswith(".nii.gz") else Path(lower).suffix


def _fail(reason: str, where: Field) -> PhantomValidationError:
    return PhantomValidationError(reason, field=where)


def read_surface(path: Path, where: Field, *, max_bytes: int, max_triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of one surface file (module docstring); every refusal names ``path`` and ``where``."""
    path = Path(path)
    label = path.name
    suffix = suffix_of(label)
    if suffix not in SURFACE_SUFFIXES:
        if suffix == ".vtp":
            raise _fail(f"{label}: XML VTK PolyData (.vtp) is not readable here (meshio reads .vtu and legacy "
                        ".vtk): export the surface as .vtk, .vtu, .stl, .ply, .obj, .off or .glb", where)
        raise _fail(f"{label}: unknown surface format {suffix or '(no suffix)'}; give one of "
                    f"{', '.join(SURFACE_SUFFIXES)}", where)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise _fail(f"{label}: cannot be read ({exc.strerror or exc})", where) from None
    if size > max_bytes:
        raise _fail(f"{label} is {size} bytes, over the cap of {max_bytes} bytes per file", where)
    if size == 0:
        raise _fail(f"{label} is empty: not a surface mesh", where)
    if suffix in (".glb", ".gltf"):
        return _read_gltf(path, where, max_bytes=max_bytes, max_triangles=max_triangles)
    data = path.read_bytes()
    if suffix == ".stl":
        _check_binary_stl(data, label, where, max_triangles)
    if suffix == ".ply":
        return _read_ply(data, label, where, max_triangles)
    if suffix == ".vtk" and re.search(rb"^DATASET\s+POLYDATA", data[:4096], re.M | re.I):
        data = _polydata_as_grid(data, label, where)
    mesh = _meshio_read(data, _MESHIO_FORMATS[suffix], suffix, label, where)
    vertices = np.asarray(mesh.points, dtype=float)
    if vertices.ndim != 2 or vertices.shape[1] not in (2, 3):
        raise _fail(f"{label}: points are not 3-D coordinates", where)
    if vertices.shape[1] == 2:
        raise _fail(f"{label}: a 2-D mesh, not a surface in space", where)
    pieces = []
    for block in mesh.cells:
        kind, cells = block.type, np.asarray(block.data)
        if kind in _VOLUME_CELLS:
            raise _fail(f"{label} holds volume cells ({kind}): export the organ's boundary surface instead", where)
        if kind.startswith("triangle") and cells.ndim == 2:
            pieces.append(cells[:, :3])
        elif kind.startswith(("quad", "polygon")) and cells.ndim == 2 and cells.shape[1] >= 3:
            k = cells.shape[1]  # fan from the first corner: (0, i, i + 1)
            pieces.extend(cells[:, [0, i, i + 1]] for i in range(1, k - 1))
    if not pieces:
        kinds = ", ".join(sorted({b.type for b in mesh.cells})) or "nothing"
        raise _fail(f"{label} holds no surface triangles or polygons (it holds {kinds}): not a surface mesh", where)
    faces = np.concatenate(pieces).astype(np.int64)
    _check(vertices, faces, label, where, max_triangles)
    return vertices, faces


def _check(vertices: np.ndarray, faces: np.ndarray, label: str, where: Field, max_triangles: int) -> None:
    if len(faces) > max_triangles:
        raise _fail(f"{label} holds {len(faces)} triangles, over the cap of {max_triangles}", where)
    if not np.isfinite(vertices).all():
        raise _fail(f"{label} has non-finite vertex coordinates", where)
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise _fail(f"{label} has a triangle index outside its {len(vertices)} vertices", where)


def _read_ply(data: bytes, label: str, where: Field, max_triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """PLY through trimesh's reader (vectorised; meshio's reads binary face lists one face at a time), after
    the face count its header declares is checked against the cap."""
    import io

    import trimesh
    from trimesh.exchange.ply import load_ply

    header = data[:data.find(b"end_header")] if b"end_header" in data[:65536] else b""
    if not data.startswith(b"ply") or not header:
        raise _fail(f"{label} is not a readable .ply surface mesh: no 'ply' ... 'end_header' header", where)
    match = re.search(rb"^element\s+face\s+(\d+)", header, re.M)
    if match and int(match.group(1)) > max_triangles:
        raise _fail(f"{label} declares {int(match.group(1))} faces, over the cap of {max_triangles}", where)
    try:  # trimesh's PLY reader itself: the arrays, without a mesh or a scene made (and copied) around them
        loaded = load_ply(io.BytesIO(data), skip_materials=True)
        vertices = np.asarray(loaded.get("vertices"), float)
        faces = loaded.get("faces")
        faces = np.zeros((0, 3), np.int64) if faces is None else np.asarray(faces)
        if faces.dtype == object or faces.ndim != 2:  # polygons of several sizes: trimesh triangulates them
            mesh = trimesh.load(io.BytesIO(data), file_type="ply", process=False, force="mesh")
            vertices, faces = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
        faces = faces.astype(np.int64, copy=False)
    except Exception as exc:  # trimesh raises ValueError, KeyError, IndexError... on a broken file
        raise _fail(f"{label} is not a readable .ply surface mesh: {str(exc)[:200] or type(exc).__name__}",
                    where) from None
    if faces.ndim == 2 and faces.shape[1] > 3:  # quads, polygons of one size: fans from their first corner
        faces = np.concatenate([faces[:, [0, i, i + 1]] for i in range(1, faces.shape[1] - 1)])
    if vertices.ndim != 2 or vertices.shape[1:] != (3,) or faces.ndim != 2 or faces.shape[1:] != (3,) or \
            not len(faces):
        raise _fail(f"{label} holds no surface triangles: not a surface mesh", where)
    _check(vertices, faces, label, where, max_triangles)
    return vertices, faces


def _check_binary_stl(data: bytes, label: str, where: Field, max_triangles: int) -> None:
    """A binary STL states its triangle count at byte 80 and is 84 + 50 bytes per triangle: both checked
    before meshio reads the file (an ASCII STL starts with ``solid`` and holds ``facet``: bounded by its size)."""
    if data[:5].lower() == b"solid" and b"facet" in data[:4096]:
        return
    count = struct.unpack_from("<I", data, 80)[0] if len(data) >= 84 else -1
    if count < 0 or len(data) != 84 + 50 * count:
        raise _fail(f"{label} is not a readable .stl surface mesh: neither ASCII ('solid ... facet') nor binary "
                    "(84 bytes + 50 per triangle)", where)
    if count > max_triangles:
        raise _fail(f"{label} declares {count} triangles, over the cap of {max_triangles}", where)


def _meshio_read(data: bytes, fmt: str, suffix: str, label: str, where: Field):
    import importlib

    # meshio's format module's own reader: meshio.read() prints and calls sys.exit(1) on a file it
    # cannot read (meshio 5.3), which must never end a server. Its readers need a real file
    # (numpy.fromfile): a private temporary copy.
    reader = importlib.import_module(f"meshio.{fmt}").read
    with tempfile.TemporaryDirectory(prefix="capsule-rt-read-") as tmp:
        path = os.path.join(tmp, "surface" + suffix)
        with open(path, "wb") as fh:
            fh.write(data)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return reader(path)
        except (Exception, SystemExit) as exc:  # meshio raises ReadError, ValueError, IndexError... on a broken file
            reason = str(exc).strip() or type(exc).__name__
            raise _fail(f"{label} is not a readable {suffix} surface mesh: {reason[:200]}", where) from None


_POLYGONS = re.compile(rb"^[ \t]*POLYGONS[ \t]+(\d+)[ \t]+(\d+)[ \t]*\r?$", re.M)
_OTHER = re.compile(rb"^[ \t]*(VERTICES|LINES|TRIANGLE_STRIPS)[ \t]+(\d+)", re.M)


def _polydata_as_grid(data: bytes, label: str, where: Field) -> bytes:
    """Legacy POLYDATA -> the same file as an UNSTRUCTURED_GRID of polygons, for meshio (module doc)."""
    header = data[:256]
    binary = re.search(rb"^BINARY\s*$", header, re.M) is not None
    polygons = list(_POLYGONS.finditer(data))
    other = _OTHER.search(data) if not binary else None
    if other is not None and int(other.group(2)) > 0:
        raise _fail(f"{label}: POLYDATA with {other.group(1).decode()} is not supported; keep only the "
                    "surface polygons (POLYGONS)", where)
    if len(polygons) != 1:
        raise _fail(f"{label}: a POLYDATA file needs exactly one POLYGONS section", where)
    match = polygons[0]
    count = int(match.group(1))
    if b"5.1" in data.split(b"\n", 1)[0]:  # 5.1 files count offsets (cells + 1)
        count -= 1
    out = data[:match.start()] + b"CELLS" + data[match.start() + match.group(0).index(b"POLYGONS") + 8:]
    out = re.sub(rb"DATASET\s+POLYDATA", b"DATASET UNSTRUCTURED_GRID", out, count=1, flags=re.I)
    if binary:
        types = b"\nCELL_TYPES %d\n" % count + np.full(count, 7, ">i4").tobytes() + b"\n"
    else:
        types = b"\nCELL_TYPES %d\n" % count + b"7\n" * count
    return out + types


def _read_gltf(path: Path, where: Field, *, max_bytes: int, max_triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """Every mesh node of a glTF/GLB file joined into one surface (node transforms applied)."""
    from raytrace.body import gltf

    try:
        decoded = gltf.read_meshes(path.read_bytes(), max_bytes=max_bytes, max_triangles=max_triangles,
                                   binary=path.suffix.lower() == ".glb")
    except PhantomValidationError as exc:
        raise _fail(f"{path.name}: {exc.reason} ({exc.field})", where) from None
    if not decoded:
        raise _fail(f"{path.name} holds no mesh node: not a surface mesh", where)
    vertices, faces, base = [], [], 0
    for v, f, _ in decoded.values():
        vertices.append(v)
        faces.append(f + base)
        base += len(v)
    out_v, out_f = np.concatenate(vertices), np.concatenate(faces)
    _check(out_v, out_f, path.name, where, max_triangles)
    return out_v, out_f
