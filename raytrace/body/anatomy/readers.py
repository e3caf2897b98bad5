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
XML VTK PolyData (.vtp) is not read by meshio either: it is the XML of an unstructured grid with its
``Polys`` instead of ``Cells``, so it is handed to meshio's XML reader the same way (:func:`_polydata_as_vtu`:
``PolyData`` renamed ``UnstructuredGrid``, ``Polys`` renamed ``Cells`` with a ``types`` array of
``VTK_POLYGON`` added; point and cell data, which the surface does not need, dropped).

A JSON glTF (.gltf) names its buffers: base64 data URIs, or files beside it, which are read only from inside
the manifest's directory (or the uploaded zip: ``root``), by a relative name; absolute paths and URLs are
refused and nothing is fetched. Its JSON and buffers are packed into one .glb that the upload's decoder
checks (byte and triangle caps before decoding) and trimesh decodes.

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

SURFACE_SUFFIXES = (".vtk", ".vtp", ".vtu", ".stl", ".ply", ".obj", ".off", ".glb", ".gltf")
VOLUME_SUFFIXES = (".nii", ".nii.gz")
_MESHIO_FORMATS = {".vtk": "vtk", ".vtp": "vtu", ".vtu": "vtu", ".stl": "stl", ".ply": "ply", ".obj": "obj",
                   ".off": "off"}
_VOLUME_CELLS = ("tetra", "hexahedron", "wedge", "pyramid", "tetra10", "hexahedron20", "hexahedron27")


def suffix_of(name: str) -> str:
    lower = name.lower()
    return ".nii.gz" if lower.endswith(".nii.gz") else Path(lower).suffix


def _fail(reason: str, where: Field) -> PhantomValidationError:
    return PhantomValidationError(reason, field=where)


def read_surface(path: Path, where: Field, *, max_bytes: int, max_triangles: int,
                 root: Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of one surface file (module docstring); every refusal names ``path`` and ``where``. ``root``:
    the directory a JSON glTF's buffer files must lie in (default: the glTF's own)."""
    path = Path(path)
    label = path.name
    suffix = suffix_of(label)
    if suffix not in SURFACE_SUFFIXES:
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
        return _read_gltf(path, where, max_bytes=max_bytes, max_triangles=max_triangles, root=root)
    data = path.read_bytes()
    if suffix == ".stl":
        _check_binary_stl(data, label, where, max_triangles)
    if suffix == ".ply":
        return _read_ply(data, label, where, max_triangles)
    if suffix == ".vtk" and re.search(rb"^DATASET\s+POLYDATA", data[:4096], re.M | re.I):
        data = _polydata_as_grid(data, label, where)
    if suffix in (".vtp", ".vtu"):
        data = _xml_vtk(data, suffix, label, where, max_triangles)
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


_RAW_MARK = b"@@capsule-rt-raw-appended-data@@"


def _xml_vtk(data: bytes, suffix: str, label: str, where: Field, max_triangles: int) -> bytes:
    """An XML VTK file checked from its header (cells against the triangle cap, no document type), and a
    ``.vtp`` turned into the ``.vtu`` meshio reads (module docstring). Raw appended data (binary after the
    XML's ``_`` marker, which is not XML) is set aside while the XML around it is parsed, and put back."""
    from xml.etree import ElementTree as ET

    raw = None
    text = data
    opening = re.search(rb"<AppendedData[^>]*>", data)
    if opening is not None and re.search(rb'encoding\s*=\s*"raw"', opening.group(0)):
        end = data.rfind(b"</AppendedData>")
        if end < opening.end():
            raise _fail(f"{label} is not a readable {suffix} surface mesh: its AppendedData is not closed", where)
        raw, text = data[opening.end():end], data[:opening.end()] + _RAW_MARK + data[end:]
    if b"<!DOCTYPE" in text or b"<!ENTITY" in text:  # no entity expansion (base64 and ASCII data hold no '<')
        raise _fail(f"{label}: XML VTK with a document type declaration is not read", where)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise _fail(f"{label} is not a readable {suffix} surface mesh: {exc}", where) from None
    kind = "PolyData" if suffix == ".vtp" else "UnstructuredGrid"
    grid = root.find(kind)
    if root.tag != "VTKFile" or root.get("type") != kind or grid is None:
        raise _fail(f"{label} is not XML VTK {kind} ({suffix}): its VTKFile type is {root.get('type')!r}", where)
    cells = 0
    try:
        for piece in grid.findall("Piece"):
            cells += int(piece.get("NumberOfPolys" if suffix == ".vtp" else "NumberOfCells", "0"))
            if suffix == ".vtp":
                _piece_as_cells(piece, label, where)
    except ValueError:
        raise _fail(f"{label} is not a readable {suffix} surface mesh: a Piece's counts are not integers",
                    where) from None
    if cells > max_triangles:
        raise _fail(f"{label} declares {cells} cells, over the cap of {max_triangles} triangles", where)
    # VTK 9 writes version 2.x, which meshio refuses; the 2.x changes are to polyhedron cells (refused as
    # volume cells anyway) and ghost arrays, so a surface's arrays read the same as 1.0's.
    newer = re.fullmatch(r"2\.\d+", root.get("version", "")) is not None
    if suffix == ".vtu" and not newer:
        return data
    if newer:
        root.set("version", "1.0")
    if suffix == ".vtp":
        if not cells:
            raise _fail(f"{label} holds no polygons (Polys): not a surface mesh", where)
        for extra in grid.findall("FieldData"):  # e.g. a time value or strings: not needed
            grid.remove(extra)
        root.set("type", "UnstructuredGrid")
        grid.tag = "UnstructuredGrid"
    out = ET.tostring(root)
    return out if raw is None else out.replace(_RAW_MARK, raw, 1)


def _piece_as_cells(piece, label: str, where: Field) -> None:
    """One ``Piece`` of XML PolyData as one of an unstructured grid of polygons: ``Polys`` become ``Cells`` with
    a ``types`` array (``VTK_POLYGON``, 7, each); vertices and lines (no surface), point and cell data (not
    needed) are dropped; triangle strips are refused."""
    from xml.etree import ElementTree as ET

    if int(piece.get("NumberOfStrips", "0")):
        raise _fail(f"{label}: triangle strips are not read; export polygons (e.g. ParaView's Triangulate filter)",
                    where)
    count = int(piece.get("NumberOfPolys", "0"))
    for key in ("NumberOfVerts", "NumberOfLines", "NumberOfStrips", "NumberOfPolys"):
        piece.attrib.pop(key, None)
    piece.set("NumberOfCells", str(count))
    for child in list(piece):
        if child.tag in ("Verts", "Lines", "Strips", "PointData", "CellData"):
            piece.remove(child)
    polys = piece.find("Polys")
    if polys is None:
        polys = ET.SubElement(piece, "Polys")
        for name in ("connectivity", "offsets"):
            ET.SubElement(polys, "DataArray", type="Int64", Name=name, format="ascii").text = " "
    polys.tag = "Cells"
    ET.SubElement(polys, "DataArray", type="UInt8", Name="types", format="ascii").text = " ".join(["7"] * count) or " "


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


def gltf_buffer_files(path: Path, root: Path, where: Field, *, max_bytes: int) -> list[Path]:
    """The files a JSON glTF's buffers name, each resolved and checked (:func:`_buffer_file`): what the build
    counts against its byte caps, and the files an upload must hold, before anything is decoded."""
    from raytrace.body import gltf

    if path.stat().st_size > max_bytes:
        raise _fail(f"{path.name} is {path.stat().st_size} bytes, over the cap of {max_bytes} bytes per file", where)
    try:
        document = gltf.gltf_document(path.read_bytes())
    except PhantomValidationError as exc:
        raise _fail(f"{path.name}: {exc.reason}", where) from None
    buffers = document.get("buffers", [])
    out = []
    for i, buffer in enumerate(buffers if isinstance(buffers, list) else []):
        uri = buffer.get("uri") if isinstance(buffer, dict) else None
        if isinstance(uri, str) and not uri.startswith("data:"):
            out.append(_buffer_file(path, uri, root, where, i))
    return out


def _buffer_file(path: Path, uri: str, root: Path, where: Field, index: int) -> Path:
    """The file a glTF buffer's ``uri`` names: a relative reference (percent-decoded) resolved beside the glTF,
    which must stay inside ``root`` (the manifest's directory, or the uploaded zip) and exist. Absolute paths
    and URLs of any scheme are refused: nothing is ever fetched."""
    from urllib.parse import unquote, urlsplit

    what = f"{path.name}: buffer {index}'s uri {uri[:80]!r}"
    parts = urlsplit(uri)
    name = unquote(parts.path)
    if parts.scheme or parts.netloc or parts.query or not name or name.startswith(("/", "\\")):
        raise _fail(f"{what} is not a file beside the glTF: a buffer is a relative file name or a base64 data URI "
                    "(URLs and absolute paths are never read)", where)
    target = (path.parent / name).resolve()
    base = Path(root).resolve()
    if target != base and base not in target.parents:
        raise _fail(f"{what} leads outside the manifest's directory (an upload's files stay inside it)", where)
    if not target.is_file():
        raise _fail(f"{what}: no such file beside the glTF", where)
    return target


def _read_gltf(path: Path, where: Field, *, max_bytes: int, max_triangles: int,
               root: Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every mesh node of a glTF/GLB file joined into one surface (node transforms applied). A JSON glTF's
    external buffers are read from files beside it inside ``root`` (:func:`_buffer_file`), each only once its
    size is known to fit the byte cap."""
    from raytrace.body import gltf

    base = Path(root) if root is not None else path.parent

    def buffer(index: int, uri: str) -> bytes:
        target = _buffer_file(path, uri, base, where, index)
        if target.stat().st_size > max_bytes:
            raise _fail(f"{path.name}: buffer {index} ({target.name}) is {target.stat().st_size} bytes, over the "
                        f"cap of {max_bytes}", where)
        return target.read_bytes()

    try:
        decoded = gltf.read_meshes(path.read_bytes(), max_bytes=max_bytes, max_triangles=max_triangles,
                                   binary=path.suffix.lower() == ".glb", buffer=buffer)
    except PhantomValidationError as exc:
        if exc.field == where:  # already about the file (a buffer's reference)
            raise
        raise _fail(f"{path.name}: {exc.reason} ({exc.field})", where) from None
    if not decoded:
        raise _fail(f"{path.name} holds no mesh node: not a surface mesh", where)
    vertices, faces, start = [], [], 0
    for v, f, _ in decoded.values():
        vertices.append(v)
        faces.append(f + start)
        start += len(v)
    out_v, out_f = np.concatenate(vertices), np.concatenate(faces)
    _check(out_v, out_f, path.name, where, max_triangles)
    return out_v, out_f
