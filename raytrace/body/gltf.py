"""Phantoms to and from binary glTF 2.0 (.glb) plus a JSON manifest.

Upload contract (``docs/api.md``, "POST /v1/phantoms"): a .glb whose
mesh nodes are named after organs, and a manifest::

    {"name": "my phantom",                     # 1-128 printable characters
     "description": "...",                      # optional
     "units": "m" | "mm",                       # required: unit of the mesh coordinates
     "organs": {"<node name>": {"tissue": "muscle"}
                            | {"relative_permittivity": 50.0, "conductivity_s_per_m": 0.0}},
     "sites": {"<name>": [x, y, z]                                   # in `units`
               | {"kind": "capsule" | "sensor", "position_m": [x, y, z]}},  # metres
     "centrelines": {"gi_tract": {"pieces": [{"organ": "<node name>",      # optional
                                              "points": [[x, y, z], ...]}, ...]}}}   # in `units`

Site kinds: the object form may state ``kind``; without it (and always for
the bare-list form) the kind is inferred only where that is unambiguous: a
site in air is a ``sensor`` (an off-body receiver). A site inside tissue may
be a capsule or a contact sensor worn in the skin, so it must state its kind
(``{"kind": "sensor", "position_m": [...]}``), or the upload is refused. The
object form is always in metres, as its field name says. Every site obeys
the rules of a channel request's antenna (inside the phantom's bounds grown
by half their diagonal, off every organ surface), so a site that uploads is
a site the channel endpoint accepts. Names of organs and sites match
:data:`NAME_PATTERN`; unknown keys anywhere in the manifest are rejected.

Units are checked against the mesh: its largest extent must lie between
:data:`MIN_EXTENT_M` and :data:`MAX_EXTENT_M` once scaled (a body, an organ
phantom, a room-sized test scene), so a millimetre mesh declared in metres,
or the reverse, is refused with a message naming the units.

This module holds the one validator of the manifest; the service's
``Manifest`` model only documents it in the API schema. It is the upload
contract end to end and stays one module (~740 lines) because the manifest's
checks and the mesh's read each other: units against the mesh's extent, sites
against the built phantom's bounds and surfaces, centrelines against the organs'
media, organ names against the .glb's nodes.
Centrelines (``raytrace.body.centreline``; the GI tract is named ``gi_tract``) are
chains of polyline pieces, each inside the organ it names: every point, sampled every
millimetre, must lie in that organ's medium, or the upload is refused naming the piece.

Loading is all-or-nothing: any defect raises
:class:`~raytrace.errors.PhantomValidationError` (or
:class:`~raytrace.errors.UnknownTissueError`, both ``InputError``) whose
``field`` starts with ``manifest`` (the manifest's entries and the organs it
names, e.g. ``("manifest", "organs", "liver")``) or ``mesh`` (the .glb
container, e.g. ``mesh.nodes[3].name``) and whose message says what is
wrong; no partially built phantom escapes.

The .glb is decoded by trimesh, after the container and its JSON chunk have
been checked: the byte cap, every accessor inside its bufferView and the
binary chunk (trimesh reads every accessor), the triangle cap from the
declared counts, the node tree (names, cycles, transforms) — all before any
array is allocated. Materials and images are skipped (no image decompression
bombs), each glTF mesh is one geometry (its primitives merged) under the name
of its node, and node transforms (matrix or TRS, composed down the hierarchy,
winding flipped under a mirroring transform as the glTF spec requires) are
taken from the world matrices the checks computed. Identical vertex positions are then merged so that meshes
exported with split vertices (per-face normals/UVs) can still be watertight.
Validation is :meth:`Phantom.build`'s (watertight, oriented, no surface
crossing itself or another: every edge cast through one Embree scene of
all triangles; nested or disjoint).

Export (:func:`export_glb`) writes one node and one mesh per organ named
after it, float32 positions and uint32 indices, in metres, with the
manifest (:func:`export_manifest`) embedded in ``scenes[0].extras`` for
viewers; it round-trips through :func:`load_phantom`.
"""

from __future__ import annotations

import json
import math
import re
import struct
from typing import Any, Callable, Mapping

import numpy as np
import trimesh

from raytrace.body.centreline import Centreline
from raytrace.body.phantom import AIR_INDEX, Material, Organ, Phantom, Site
from raytrace.errors import Field, InputError, InvalidGeometryError, PhantomValidationError, UnknownTissueError

__all__ = [
    "DEFAULT_MAX_BYTES",
    "DEFAULT_MAX_TRIANGLES",
    "MAX_ORGANS",
    "MAX_SITES",
    "NAME_PATTERN",
    "export_glb",
    "export_manifest",
    "load_phantom",
    "parse_manifest",
    "validate_manifest",
]

DEFAULT_MAX_BYTES = 64 * 2**20
DEFAULT_MAX_TRIANGLES = 2_000_000
MAX_ORGANS = 256
MAX_SITES = 1024
MAX_CENTRELINES = 16
MAX_NAME_CHARS = 128
MAX_DESCRIPTION_CHARS = 2000
MAX_PERMITTIVITY = 1000.0
MAX_CONDUCTIVITY_S_PER_M = 1000.0
#: Organ, site (and mesh node) names: also what a channel request may name as a ``site``.
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
UNITS = {"m": 1.0, "mm": 1e-3}
#: Largest extent of an uploaded mesh, in metres after applying ``units``: below a
#: centimetre no body nor test scene exists; beyond 20 m neither (a room of a few metres,
#: how users compare with other ray tracers, stays valid).
MIN_EXTENT_M = 0.01
MAX_EXTENT_M = 20.0

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_DTYPES = {5121: np.dtype("<u1"), 5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
_TRIANGLES = 4


def _fail(reason: str, field: Field) -> PhantomValidationError:
    return PhantomValidationError(reason, field=field)


def _brief(value: Any) -> str:
    """A short repr of a user value for a message (never echo a megabyte back)."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


# ================================================================ manifest
def parse_manifest(text: bytes | str) -> Any:
    """The manifest's JSON text -> Python value. Refuses (``field`` "manifest") text that is
    not UTF-8 JSON, nests too deeply for the parser, or holds an integer too long to read."""
    try:
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        return json.loads(text)
    except UnicodeDecodeError as exc:
        raise _fail(f"the manifest is not UTF-8 text: {exc}", "manifest") from None
    except RecursionError:
        raise _fail("the manifest nests too deeply to be parsed", "manifest") from None
    except ValueError as exc:  # JSONDecodeError, and Python's limit on the digits of an integer
        raise _fail(f"the manifest is not valid JSON: {_brief(str(exc))}", "manifest") from None


def validate_manifest(manifest: Any) -> dict:
    """Check a manifest strictly and return a normalised copy.

    Normalised form: ``{"name", "description", "units", "organs": {name:
    Material}, "sites": {name: (kind | None, position_in_units | None,
    position_m | None)}}``.
    """
    if not isinstance(manifest, Mapping):
        raise _fail("the manifest must be a JSON object", "manifest")
    allowed = {"name", "description", "units", "organs", "sites", "centrelines"}
    unknown = sorted(str(k) for k in set(manifest) - allowed)
    if unknown:
        raise _fail(f"unknown key {_brief(unknown[0])}; allowed: {', '.join(sorted(allowed))}",
                    ("manifest", unknown[0]))
    name = manifest.get("name")
    if not isinstance(name, str) or not 1 <= len(name) <= MAX_NAME_CHARS or not name.isprintable():
        raise _fail(f"required: a name of 1-{MAX_NAME_CHARS} printable characters", "manifest.name")
    description = manifest.get("description", "")
    if not isinstance(description, str) or len(description) > MAX_DESCRIPTION_CHARS:
        raise _fail(f"must be a string of at most {MAX_DESCRIPTION_CHARS} characters", "manifest.description")
    if "units" not in manifest:
        raise _fail("required: the unit of the mesh coordinates, 'm' or 'mm'", "manifest.units")
    units = manifest["units"]
    if not isinstance(units, str) or units not in UNITS:
        raise _fail(f"must be 'm' or 'mm', got {_brief(units)}", "manifest.units")

    organs_in = manifest.get("organs")
    if not isinstance(organs_in, Mapping) or not organs_in:
        raise _fail("required: a non-empty object mapping mesh node names to media", "manifest.organs")
    if len(organs_in) > MAX_ORGANS:
        raise _fail(f"{len(organs_in)} organs exceed the cap of {MAX_ORGANS}", "manifest.organs")
    organs: dict[str, Material] = {}
    for organ_name, spec in organs_in.items():
        where = ("manifest", "organs", organ_name)
        _check_name(organ_name, where)
        organs[organ_name] = _material(spec, where)

    sites_in = manifest.get("sites", {})
    if not isinstance(sites_in, Mapping):
        raise _fail("must be an object mapping site names to positions", "manifest.sites")
    if len(sites_in) > MAX_SITES:
        raise _fail(f"{len(sites_in)} sites exceed the cap of {MAX_SITES}", "manifest.sites")
    sites: dict[str, tuple[str | None, np.ndarray | None, np.ndarray | None]] = {}
    for site_name, spec in sites_in.items():
        where = ("manifest", "sites", site_name)
        _check_name(site_name, where)
        if isinstance(spec, Mapping):
            extra = sorted(str(k) for k in set(spec) - {"kind", "position_m"})
            if extra:
                raise _fail(f"unknown key {_brief(extra[0])}; allowed: kind, position_m", (*where, extra[0]))
            kind = spec.get("kind")
            if kind is not None and kind not in ("capsule", "sensor"):
                raise _fail(f"must be 'capsule' or 'sensor', got {_brief(kind)}", (*where, "kind"))
            if "position_m" not in spec:
                raise _fail("required: [x, y, z] in metres", (*where, "position_m"))
            sites[site_name] = (kind, None, _vec3(spec["position_m"], (*where, "position_m")))
        else:
            sites[site_name] = (None, _vec3(spec, where), None)
    return {"name": name, "description": description, "units": units, "organs": organs, "sites": sites,
            "centrelines": _centrelines(manifest.get("centrelines", {}), UNITS[units])}


def _centrelines(spec: Any, scale: float) -> dict[str, Centreline]:
    if not isinstance(spec, Mapping):
        raise _fail("must be an object mapping centreline names to {pieces}", "manifest.centrelines")
    if len(spec) > MAX_CENTRELINES:
        raise _fail(f"{len(spec)} centrelines exceed the cap of {MAX_CENTRELINES}", "manifest.centrelines")
    out = {}
    for name, line in spec.items():
        where = f"manifest.centrelines.{name}"
        _check_name(name, where)
        try:
            out[name] = Centreline.from_dict(line, field=where, scale=scale, points_key="points")
        except InputError as exc:
            raise _fail(exc.reason, exc.field) from None
    return out


def _check_name(name: Any, where: Field) -> None:
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise _fail(f"name {_brief(name)} must match {NAME_PATTERN.pattern}", where)


def _number(value: Any, where: Field) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(f"must be a finite number, got {_brief(value)}", where)
    try:
        out = float(value)
    except OverflowError:  # an integer beyond the float range
        out = math.inf
    if not math.isfinite(out):
        raise _fail(f"must be a finite number, got {_brief(value)}", where)
    return out


def _vec3(value: Any, where: Field) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise _fail(f"must be [x, y, z] (three numbers), got {_brief(value)}", where)
    return np.array([_number(v, where) for v in value])


def _material(spec: Any, where: tuple) -> Material:
    if not isinstance(spec, Mapping):
        raise _fail('must be {"tissue": name} or {"relative_permittivity": x, '
                    '"conductivity_s_per_m": y}', where)
    keys = {str(k) for k in spec}
    if "tissue" in keys:
        if keys != {"tissue"}:
            extra = sorted(keys - {"tissue"})[0]
            raise _fail("give either tissue or relative_permittivity (+ conductivity_s_per_m), not both",
                        (*where, extra))
        tissue = spec["tissue"]
        if not isinstance(tissue, str):
            raise _fail(f"must be a tissue name (string), got {_brief(tissue)}", (*where, "tissue"))
        try:
            return Material(tissue=tissue)
        except UnknownTissueError as exc:
            raise UnknownTissueError(exc.reason, field=(*where, "tissue")) from None
    extra = sorted(keys - {"relative_permittivity", "conductivity_s_per_m"})
    if extra:
        raise _fail(f"unknown key {_brief(extra[0])}", (*where, extra[0]))
    if "relative_permittivity" not in keys:
        raise _fail("required: tissue, or relative_permittivity (+ conductivity_s_per_m)", where)
    eps = _number(spec["relative_permittivity"], (*where, "relative_permittivity"))
    sigma = _number(spec.get("conductivity_s_per_m", 0.0), (*where, "conductivity_s_per_m"))
    if not 1.0 <= eps <= MAX_PERMITTIVITY:
        raise _fail(f"must be in [1, {MAX_PERMITTIVITY:g}], got {eps:g}", (*where, "relative_permittivity"))
    if not 0.0 <= sigma <= MAX_CONDUCTIVITY_S_PER_M:
        raise _fail(f"must be in [0, {MAX_CONDUCTIVITY_S_PER_M:g}], got {sigma:g}",
                    (*where, "conductivity_s_per_m"))
    return Material(relative_permittivity=eps, conductivity_s_per_m=sigma)


# ================================================================ GLB decode
def _split_glb(data: bytes) -> tuple[dict, bytes]:
    """GLB container -> (JSON document, BIN chunk). Every length is checked."""
    if len(data) < 20:
        raise _fail(f"not a binary glTF: {len(data)} bytes is shorter than the 20-byte header", "mesh")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != _GLB_MAGIC:
        raise _fail("not a binary glTF (.glb): bad magic bytes", "mesh")
    if version != 2:
        raise _fail(f"glTF container version {version} is not supported (need 2)", "mesh")
    if length != len(data):
        raise _fail(f"truncated or padded .glb: header says {length} bytes, got {len(data)}", "mesh")
    offset = 12
    chunks: list[tuple[int, bytes]] = []
    while offset < length:
        if offset + 8 > length:
            raise _fail("truncated chunk header", "mesh")
        chunk_len, chunk_type = struct.unpack_from("<II", data, offset)
        start = offset + 8
        if start + chunk_len > length:
            raise _fail(f"chunk of {chunk_len} bytes runs past the end of the file", "mesh")
        chunks.append((chunk_type, data[start:start + chunk_len]))
        offset = start + chunk_len
    if not chunks or chunks[0][0] != _CHUNK_JSON:
        raise _fail("the first chunk must be the JSON chunk", "mesh")
    try:
        document = json.loads(chunks[0][1].decode("utf-8"))
    except RecursionError:
        raise _fail("the JSON chunk nests too deeply to be parsed", "mesh") from None
    except ValueError as exc:  # bad UTF-8 or JSON, or an integer with too many digits
        raise _fail(f"the JSON chunk is not valid JSON: {_brief(str(exc))}", "mesh") from None
    if not isinstance(document, dict):
        raise _fail("the JSON chunk must be an object", "mesh")
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == _CHUNK_BIN else b""
    return document, binary


def _list(document: dict, key: str) -> list:
    value = document.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise _fail(f"glTF '{key}' must be an array of objects", f"mesh.{key}")
    return value


def _index(value: Any, size: int, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < size:
        raise _fail(f"index {value!r} out of range (0..{size - 1})", where)
    return value


class _Reader:
    """Bounds-checked accessor reads from the BIN chunk."""

    def __init__(self, document: dict, binary: bytes) -> None:
        self.accessors = _list(document, "accessors")
        self.views = _list(document, "bufferViews")
        buffers = _list(document, "buffers")
        for i, buffer in enumerate(buffers):
            if "uri" in buffer:
                raise _fail("external or data-URI buffers are not accepted; embed geometry in the "
                            ".glb binary chunk", f"mesh.buffers[{i}]")
        if buffers:
            declared = buffers[0].get("byteLength")
            if not isinstance(declared, int) or declared > len(binary):
                raise _fail(f"buffer 0 declares {declared!r} bytes, the binary chunk has {len(binary)}",
                            "mesh.buffers[0]")
        self.binary = binary

    def count(self, index: int, where: str) -> int:
        accessor = self.accessors[_index(index, len(self.accessors), where)]
        count = accessor.get("count")
        if isinstance(count, bool) or not isinstance(count, int) or count < 0:
            raise _fail(f"accessor count {count!r} is invalid", where)
        return count

    def check(self, index: int, where: str, *, type_: str | None = None,
              component_types: tuple[int, ...] | None = None) -> None:
        """Bounds-check one accessor against its bufferView and the binary chunk (no data is decoded): what
        trimesh's decoder will read must lie inside the file."""
        accessor = self.accessors[_index(index, len(self.accessors), where)]
        if "sparse" in accessor:
            raise _fail("sparse accessors are not supported", where)
        kind, component = accessor.get("type"), accessor.get("componentType")
        if not isinstance(kind, str) or kind not in _COMPONENTS or isinstance(component, bool) or \
                not isinstance(component, int) or component not in _DTYPES:
            raise _fail(f"accessor type {accessor.get('type')!r}/{accessor.get('componentType')!r} is not supported",
                        where)
        if (type_ is not None and accessor.get("type") != type_) or \
                (component_types is not None and accessor.get("componentType") not in component_types):
            raise _fail(f"accessor must be {type_} of componentType {component_types}, got "
                        f"{accessor.get('type')!r}/{accessor.get('componentType')!r}", where)
        if accessor.get("normalized", False):
            raise _fail("normalized accessors are not supported", where)
        count = self.count(index, where)
        dtype = _DTYPES[accessor["componentType"]]
        element = dtype.itemsize * _COMPONENTS[accessor["type"]]
        if "bufferView" not in accessor:
            raise _fail("accessor without a bufferView", where)
        view = self.views[_index(accessor["bufferView"], len(self.views), f"{where}.bufferView")]
        if view.get("buffer", 0) != 0:
            raise _fail("only buffer 0 (the .glb binary chunk) is accepted", f"{where}.bufferView")
        view_offset = view.get("byteOffset", 0)
        view_length = view.get("byteLength")
        stride = view.get("byteStride", element)
        acc_offset = accessor.get("byteOffset", 0)
        for value, what in ((view_offset, "byteOffset"), (view_length, "byteLength"),
                            (stride, "byteStride"), (acc_offset, "accessor byteOffset")):
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise _fail(f"bufferView {what} {value!r} is invalid", where)
        if stride < element:
            raise _fail(f"byteStride {stride} is smaller than the element size {element}", where)
        if view_offset + view_length > len(self.binary):
            raise _fail("bufferView runs past the end of the binary chunk", where)
        if count and acc_offset + stride * (count - 1) + element > view_length:
            raise _fail(f"accessor needs {acc_offset + stride * (count - 1) + element} bytes, its bufferView has "
                        f"{view_length}", where)


def _node_matrix(node: dict, where: str) -> np.ndarray:
    if "matrix" in node:
        m = node["matrix"]
        if not isinstance(m, list) or len(m) != 16:
            raise _fail("matrix must have 16 numbers", where)
        matrix = np.array([_number(v, f"{where}.matrix") for v in m]).reshape(4, 4).T  # column-major
        if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0]):
            raise _fail("matrix must be affine (last row 0, 0, 0, 1)", f"{where}.matrix")
        return matrix
    translation = np.array([_number(v, f"{where}.translation") for v in node.get("translation", [0, 0, 0])])
    rotation = np.array([_number(v, f"{where}.rotation") for v in node.get("rotation", [0, 0, 0, 1])])
    scale = np.array([_number(v, f"{where}.scale") for v in node.get("scale", [1, 1, 1])])
    if translation.shape != (3,) or rotation.shape != (4,) or scale.shape != (3,):
        raise _fail("translation/rotation/scale must have 3/4/3 numbers", where)
    norm = np.linalg.norm(rotation)
    if not 0.9 < norm < 1.1:
        raise _fail("rotation must be a unit quaternion [x, y, z, w]", f"{where}.rotation")
    x, y, z, w = rotation / norm
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    matrix = np.eye(4)
    matrix[:3, :3] = r * scale[None, :]
    matrix[:3, 3] = translation
    return matrix


def _mesh_nodes(document: dict) -> list[tuple[str, int, np.ndarray, str]]:
    """(node name, mesh index, world matrix, field) of every mesh node in the default scene."""
    nodes = _list(document, "nodes")
    meshes = _list(document, "meshes")
    scenes = _list(document, "scenes")
    for i, node in enumerate(nodes):
        if "skin" in node or "weights" in node:
            raise _fail("skinned / morphed nodes are not supported", f"mesh.nodes[{i}]")
        children = node.get("children", [])
        if not isinstance(children, list):
            raise _fail("children must be an array", f"mesh.nodes[{i}].children")
        for c in children:
            _index(c, len(nodes), f"mesh.nodes[{i}].children")
    if scenes:
        scene_index = _index(document.get("scene", 0), len(scenes), "mesh.scene")
        roots = scenes[scene_index].get("nodes", [])
        if not isinstance(roots, list):
            raise _fail("scene nodes must be an array", f"mesh.scenes[{scene_index}].nodes")
    else:  # no scene: every node that is nobody's child
        child_set = {c for n in nodes for c in n.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in child_set]
    out: list[tuple[str, int, np.ndarray, str]] = []
    visited: set[int] = set()
    # Depth-first in document order (a stack of reversed lists).
    stack = [(_index(r, len(nodes), "mesh.scenes.nodes"), np.eye(4)) for r in reversed(roots)]
    while stack:
        i, parent = stack.pop()
        where = f"mesh.nodes[{i}]"
        if i in visited:
            raise _fail("node is reachable twice (a cycle or a node with two parents)", where)
        visited.add(i)
        node = nodes[i]
        world = parent @ _node_matrix(node, where)
        if "mesh" in node:
            mesh_index = _index(node["mesh"], len(meshes), f"{where}.mesh")
            name = node.get("name")
            if not isinstance(name, str) or not NAME_PATTERN.match(name):
                raise _fail(f"mesh node name {name!r} must match {NAME_PATTERN.pattern} (it names "
                            "the organ in the manifest)", f"{where}.name")
            out.append((name, mesh_index, world, where))
        stack.extend((c, world) for c in reversed(node.get("children", [])))
    names = [n for n, *_ in out]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise _fail(f"mesh node name {duplicates[0]!r} is used by more than one node", "mesh.nodes")
    return out


def _primitives(mesh: dict, where: str) -> list[dict]:
    primitives = mesh.get("primitives")
    if not isinstance(primitives, list) or not primitives or not all(isinstance(p, dict) for p in primitives):
        raise _fail("mesh needs a non-empty primitives array", f"{where}.primitives")
    for k, p in enumerate(primitives):
        if p.get("mode", _TRIANGLES) != _TRIANGLES:
            raise _fail(f"primitive mode {p.get('mode')!r} is not supported: only triangles (4)",
                        f"{where}.primitives[{k}].mode")
        if "targets" in p:
            raise _fail("morph targets are not supported", f"{where}.primitives[{k}]")
        attributes = p.get("attributes")
        if not isinstance(attributes, dict) or "POSITION" not in attributes:
            raise _fail("primitive has no POSITION attribute", f"{where}.primitives[{k}]")
        ext = p.get("extensions", {})
        if isinstance(ext, dict) and ext:
            raise _fail(f"primitive extension(s) {sorted(ext)} are not supported",
                        f"{where}.primitives[{k}].extensions")
    return primitives


def _decode(data: bytes, *, max_bytes: int, max_triangles: int) -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
    """node name -> (vertices (V, 3) float64 in file units, faces (F, 3), node field).

    Everything the decoder will touch is checked first, from the container and its JSON chunk alone: the
    byte cap, every accessor inside its bufferView and the binary chunk, the triangle cap from the declared
    counts, the node tree, names and transforms. trimesh then decodes the file (materials and images
    skipped, no processing), one mesh per glTF mesh; each mesh node's vertices are taken through its world
    transform from trimesh's scene graph (winding reversed under a mirroring transform, as glTF requires)."""
    import io

    if len(data) > max_bytes:
        raise _fail(f"the .glb is {len(data)} bytes, over the cap of {max_bytes}", "mesh")
    document, binary = _split_glb(data)
    required = document.get("extensionsRequired", [])
    if required:
        raise _fail(f"required glTF extension(s) {required} are not supported "
                    "(e.g. Draco/meshopt compression): export uncompressed", "mesh.extensionsRequired")
    reader = _Reader(document, binary)
    meshes = _list(document, "meshes")
    nodes = _mesh_nodes(document)
    total = 0
    for name, mesh_index, _, where in nodes:
        for k, p in enumerate(_primitives(meshes[mesh_index], f"mesh.meshes[{mesh_index}]")):
            pw = f"mesh.meshes[{mesh_index}].primitives[{k}]"
            n = reader.count(p["indices"], f"{pw}.indices") if "indices" in p else \
                reader.count(p["attributes"]["POSITION"], f"{pw}.attributes.POSITION")
            if n % 3:
                raise _fail(f"{n} indices is not a multiple of 3 (triangles)", pw)
            total += n // 3
    if total > max_triangles:
        raise _fail(f"{total} triangles exceed the cap of {max_triangles}", "mesh")
    for name, mesh_index, _, where in nodes:
        for k, p in enumerate(meshes[mesh_index]["primitives"]):
            pw = f"mesh.meshes[{mesh_index}].primitives[{k}]"
            reader.check(p["attributes"]["POSITION"], f"{pw}.attributes.POSITION", type_="VEC3",
                         component_types=(5126,))
            if "indices" in p:
                reader.check(p["indices"], f"{pw}.indices", type_="SCALAR", component_types=(5121, 5123, 5125))
    for k in range(len(reader.accessors)):  # trimesh decodes every accessor: all must lie inside the file
        reader.check(k, f"mesh.accessors[{k}]")
    for i, image in enumerate(_list(document, "images")):
        if "uri" in image:
            raise _fail("external or data-URI images are not accepted", f"mesh.images[{i}]")
    try:
        scene = trimesh.load(io.BytesIO(data), file_type="glb", force="scene", process=False,
                             merge_primitives=True, skip_materials=True)
    except Exception as exc:  # trimesh raises ValueError, KeyError, IndexError... on what passed the checks
        raise _fail(f"the .glb cannot be decoded: {_brief(str(exc) or type(exc).__name__)}", "mesh") from None
    out: dict[str, tuple[np.ndarray, np.ndarray, str]] = {}
    for name, mesh_index, world, where in nodes:
        mw = f"mesh.meshes[{mesh_index}]"
        try:
            _, geometry_name = scene.graph[name]
            geometry = scene.geometry[geometry_name]
        except (KeyError, ValueError, TypeError):
            raise _fail(f"mesh node {name!r} was not decoded (no triangles?)", where) from None
        vertices = np.asarray(geometry.vertices, float)
        faces = np.asarray(geometry.faces, np.int64)
        if not np.isfinite(vertices).all():
            raise _fail("non-finite vertex coordinates", f"{mw}.primitives[0].attributes.POSITION")
        if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise _fail(f"index {int(faces.max())} out of range of {len(vertices)} vertices",
                        f"{mw}.primitives[0].indices")
        vertices = vertices @ world[:3, :3].T + world[:3, 3]
        if np.linalg.det(world[:3, :3]) < 0:  # mirroring transform: glTF flips the winding
            faces = faces[:, ::-1]
        out[name] = (vertices, faces, where)
    return out


def read_meshes(data: bytes, *, max_bytes: int = DEFAULT_MAX_BYTES, max_triangles: int = DEFAULT_MAX_TRIANGLES,
                binary: bool = True, buffer: Callable[[int, str], bytes] | None = None,
                ) -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
    """Mesh nodes of a glTF (for the anatomy pipeline, ``raytrace.body.anatomy.readers``): node name ->
    (vertices in file units with the node transforms applied, faces, node field). Same caps and checks
    as an upload's .glb. A JSON glTF (``binary=False``) is first packed into a .glb (:func:`pack_gltf`), its
    external buffers read through ``buffer`` (index, URI -> bytes; the caller decides where a URI may lead)."""
    if not binary:
        data = pack_gltf(data, buffer, max_bytes=max_bytes)
    return _decode(bytes(data), max_bytes=max_bytes, max_triangles=max_triangles)


#: What a JSON glTF's data URI of a buffer may say before its base64 payload (glTF 2.0 section 3.6.1.1).
_DATA_URI = re.compile(r"^data:(application/octet-stream|application/gltf-buffer)?;base64,")
#: Keys of a JSON glTF that only materials and images use: dropped when it is packed (the reader skips
#: materials; their images would be more files to read).
_APPEARANCE = ("materials", "textures", "images", "samplers")


def data_uri_bytes(uri: str, where: str) -> bytes | None:
    """The payload of a base64 data URI (None when ``uri`` is not a data URI)."""
    import base64
    import binascii

    if not uri.startswith("data:"):
        return None
    match = _DATA_URI.match(uri)
    if match is None:
        raise _fail("a data URI of a buffer must be base64 application/octet-stream or application/gltf-buffer",
                    where)
    try:
        return base64.b64decode(uri[match.end():], validate=True)
    except (binascii.Error, ValueError):
        raise _fail("the data URI is not valid base64", where) from None


def gltf_document(text: bytes) -> dict:
    """The JSON document of a .gltf, checked to be an object."""
    try:
        document = json.loads(bytes(text).decode("utf-8"))
    except RecursionError:
        raise _fail("the glTF JSON nests too deeply to be parsed", "mesh") from None
    except ValueError as exc:
        raise _fail(f"not a glTF: the JSON is not valid: {_brief(str(exc))}", "mesh") from None
    if not isinstance(document, dict):
        raise _fail("not a glTF: the JSON must be an object", "mesh")
    return document


def pack_gltf(text: bytes, buffer: Callable[[int, str], bytes] | None, *, max_bytes: int) -> bytes:
    """A JSON glTF and its buffers as one .glb, which :func:`_decode` then checks and decodes like an upload.

    Each buffer's ``uri`` is a base64 data URI (decoded here) or a reference that ``buffer(index, uri)``
    resolves (the anatomy pipeline allows only files beside the glTF, inside the manifest's directory or the
    uploaded zip; never a URL); without ``buffer`` only data URIs are accepted. Buffers are laid one after the
    other (each at a 4-byte boundary) into the binary chunk and every bufferView moved to its buffer's place
    there; materials, textures, images and samplers are dropped (never read). Bytes are counted against
    ``max_bytes`` as each buffer arrives, before the next is read."""
    document = gltf_document(text)
    required = document.get("extensionsRequired", [])
    if required:
        raise _fail(f"required glTF extension(s) {required} are not supported "
                    "(e.g. Draco/meshopt compression): export uncompressed", "mesh.extensionsRequired")
    buffers = _list(document, "buffers")
    chunks: list[bytes] = []
    starts: list[int] = []
    total = len(text)
    for i, entry in enumerate(buffers):
        where = f"mesh.buffers[{i}]"
        length = entry.get("byteLength")
        if isinstance(length, bool) or not isinstance(length, int) or length < 0:
            raise _fail(f"byteLength {length!r} is invalid", where)
        uri = entry.get("uri")
        if not isinstance(uri, str):
            raise _fail("a buffer of a JSON glTF needs a uri (a data URI or a file beside it)", where)
        total += length
        if total > max_bytes:
            raise _fail(f"the glTF and its buffers hold more than {max_bytes} bytes, the cap", where)
        payload = data_uri_bytes(uri, f"{where}.uri")
        if payload is None:
            if buffer is None:
                raise _fail("external buffers are not accepted here: embed them as data URIs", f"{where}.uri")
            payload = buffer(i, uri)
        if len(payload) < length:
            raise _fail(f"buffer {i} declares {length} bytes, its data has {len(payload)}", where)
        starts.append(sum(len(c) for c in chunks))
        chunks.append(payload[:length] + b"\0" * (-length % 4))
    views = _list(document, "bufferViews")
    for k, view in enumerate(views):
        if not buffers:
            raise _fail("a bufferView but no buffer", f"mesh.bufferViews[{k}]")
        index = _index(view.get("buffer", 0), len(buffers), f"mesh.bufferViews[{k}].buffer")
        offset, size = view.get("byteOffset", 0), view.get("byteLength")
        for value, what in ((offset, "byteOffset"), (size, "byteLength")):
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise _fail(f"{what} {value!r} is invalid", f"mesh.bufferViews[{k}]")
        if offset + size > buffers[index]["byteLength"]:
            raise _fail("bufferView runs past the end of its buffer", f"mesh.bufferViews[{k}]")
        view["buffer"] = 0
        view["byteOffset"] = starts[index] + offset
    binary = b"".join(chunks)
    document["buffers"] = [{"byteLength": len(binary)}] if binary else []
    for key in _APPEARANCE:
        document.pop(key, None)
    for mesh in _list(document, "meshes"):
        for primitive in mesh.get("primitives", []) if isinstance(mesh.get("primitives"), list) else []:
            if isinstance(primitive, dict):
                primitive.pop("material", None)
    payload = json.dumps(document, separators=(",", ":")).encode()
    payload += b" " * (-len(payload) % 4)
    length = 12 + 8 + len(payload) + (8 + len(binary) if binary else 0)
    out = struct.pack("<4sII", _GLB_MAGIC, 2, length) + struct.pack("<II", len(payload), _CHUNK_JSON) + payload
    if binary:
        out += struct.pack("<II", len(binary), _CHUNK_BIN) + binary
    return out


# ================================================================ load
def load_phantom(
    glb_bytes: bytes,
    manifest: Mapping[str, Any],
    *,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_triangles: int = DEFAULT_MAX_TRIANGLES,
    check_crossings: bool = True,
) -> Phantom:
    """Validate an upload (.glb + manifest) and build its :class:`Phantom` (see module doc)."""
    if not isinstance(glb_bytes, (bytes, bytearray, memoryview)):
        raise _fail("the mesh must be the bytes of a .glb file", "mesh")
    spec = validate_manifest(manifest)
    scale = UNITS[spec["units"]]
    decoded = _decode(bytes(glb_bytes), max_bytes=max_bytes, max_triangles=max_triangles)
    missing = [n for n in spec["organs"] if n not in decoded]
    if missing:
        raise _fail(f"organ {missing[0]!r} is in the manifest but the .glb has no mesh node of "
                    f"that name (mesh nodes: {', '.join(sorted(decoded)) or 'none'})",
                    ("manifest", "organs", missing[0]))
    extra = [n for n in decoded if n not in spec["organs"]]
    if extra:
        raise _fail(f"mesh node {extra[0]!r} ({decoded[extra[0]][2]}) is not named in the "
                    "manifest's organs; every mesh node must be an organ", "manifest.organs")
    _check_extent(decoded, spec["units"])
    organs = []
    for name, material in spec["organs"].items():
        vertices, faces, _ = decoded[name]
        # process=True merges identical positions (split vertices of exporters).
        mesh = trimesh.Trimesh(vertices * scale, faces, process=True, validate=False)
        organs.append(Organ(name, material, mesh))
    try:
        phantom = Phantom.build(spec["name"], organs, sites={}, description=spec["description"],
                                max_triangles=max_triangles, check_crossings=check_crossings)
    except PhantomValidationError as exc:  # Phantom.build names "organs.<name>": the manifest's organs
        field = exc.field
        if isinstance(field, str) and (field == "organs" or field.startswith("organs.")):
            field = ("manifest", *field.split(".", 1))
        raise PhantomValidationError(exc.reason, field=field) from None
    _add_sites(phantom, spec["sites"], scale)
    for name, line in spec["centrelines"].items():
        line.check_inside(phantom, field=f"manifest.centrelines.{name}")
        phantom.centrelines[name] = line
    phantom.metadata.update({"source": "upload", "units": spec["units"]})
    return phantom


def _check_extent(decoded: dict, units: str) -> None:
    """Refuse a mesh whose size, read in ``units``, is no body or test scene (module doc)."""
    lo = np.min([v.min(axis=0) for v, _, _ in decoded.values() if len(v)], axis=0)
    hi = np.max([v.max(axis=0) for v, _, _ in decoded.values() if len(v)], axis=0)
    extent_m = float(np.max(hi - lo)) * UNITS[units]
    if MIN_EXTENT_M <= extent_m <= MAX_EXTENT_M:
        return
    hint = ""
    for other, scale in UNITS.items():
        if other != units and MIN_EXTENT_M <= extent_m / UNITS[units] * scale <= MAX_EXTENT_M:
            hint = f"; if the coordinates are in {'metres' if other == 'm' else 'millimetres'}, declare units {other!r}"
    raise _fail(f"with units {units!r} the mesh spans {extent_m:.3g} m along its largest axis, outside "
                f"{MIN_EXTENT_M:g}-{MAX_EXTENT_M:g} m (no body or test scene has that size){hint}",
                "manifest.units")


def _add_sites(phantom: Phantom, sites: dict, scale: float) -> None:
    for name, (kind, in_units, in_metres) in sites.items():
        where = ("manifest", "sites", name)
        point = in_metres if in_metres is not None else in_units * scale
        try:  # the rules of a channel request's antenna: within bounds, off every surface
            medium = phantom.antenna_medium(point, field=where)
        except InvalidGeometryError as exc:
            raise PhantomValidationError(exc.reason, field=exc.field) from None
        if kind is None:
            if medium != AIR_INDEX:
                raise _fail(f"the site lies inside {phantom.medium_name(medium)!r}, where it may be a capsule "
                            'or a contact sensor: give its kind, {"kind": "capsule" | "sensor", '
                            '"position_m": [x, y, z]} (position in metres); only a site in air is '
                            "taken as a sensor without one", where)
            kind = "sensor"
        phantom.sites[name] = Site(name, kind, np.array(point, dtype=float), phantom.medium_name(medium))


# ================================================================ export
def export_manifest(phantom: Phantom) -> dict:
    """The manifest that, with :func:`export_glb`, reloads ``phantom`` (units m,
    sites in the object form with their kinds)."""
    organs = {}
    for organ in phantom.organs:
        m = organ.material
        organs[organ.name] = (
            {"tissue": m.tissue} if m.tissue is not None
            else {"relative_permittivity": float(m.relative_permittivity),
                  "conductivity_s_per_m": float(m.conductivity_s_per_m)}
        )
    manifest = {
        "name": phantom.name,
        "units": "m",
        "organs": organs,
        "sites": {
            name: {"kind": site.kind, "position_m": [float(x) for x in site.position_m]}
            for name, site in phantom.sites.items()
        },
    }
    if phantom.centrelines:
        manifest["centrelines"] = {
            # 0.1 um: far below any geometry, and a real tract's manifest stays under the upload's manifest cap
            name: {"pieces": [{"organ": p.organ, "points": np.round(p.points_m, 7).tolist()} for p in line.pieces]}
            for name, line in phantom.centrelines.items()}
    if phantom.description:
        manifest["description"] = phantom.description[:2000]
    return manifest


def export_glb(phantom: Phantom) -> bytes:
    """The phantom as a .glb: one node + mesh per organ named after it, metres."""
    chunks: list[bytes] = []
    offset = 0
    accessors, views, meshes, nodes = [], [], [], []

    def add_view(payload: bytes) -> int:
        nonlocal offset
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(payload)})
        chunks.append(payload)
        offset += len(payload)
        return len(views) - 1

    for organ in phantom.organs:
        vertices = np.asarray(organ.mesh.vertices, dtype="<f4")
        faces = np.asarray(organ.mesh.faces, dtype="<u4")
        v_view = add_view(vertices.tobytes())
        accessors.append({"bufferView": v_view, "componentType": 5126, "count": len(vertices),
                          "type": "VEC3", "min": vertices.min(axis=0).astype(float).tolist(),
                          "max": vertices.max(axis=0).astype(float).tolist()})
        f_view = add_view(faces.tobytes())
        accessors.append({"bufferView": f_view, "componentType": 5125, "count": faces.size,
                          "type": "SCALAR"})
        meshes.append({"name": organ.name, "primitives": [
            {"attributes": {"POSITION": len(accessors) - 2}, "indices": len(accessors) - 1,
             "mode": _TRIANGLES}]})
        nodes.append({"name": organ.name, "mesh": len(meshes) - 1,
                      "extras": {"medium": organ.material.label}})
    binary = b"".join(chunks)
    document = {
        "asset": {"version": "2.0", "generator": "CapsuleRT raytrace.body.gltf"},
        "scene": 0,
        "scenes": [{"name": phantom.name, "nodes": list(range(len(nodes))),
                    "extras": {"capsule_rt_manifest": export_manifest(phantom)}}],
        "nodes": nodes,
        "meshes": meshes,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(binary)}],
    }
    json_bytes = json.dumps(document, separators=(",", ":")).encode("utf-8")
    json_bytes += b" " * (-len(json_bytes) % 4)
    binary += b"\x00" * (-len(binary) % 4)
    total = 12 + 8 + len(json_bytes) + 8 + len(binary)
    return b"".join([
        struct.pack("<4sII", _GLB_MAGIC, 2, total),
        struct.pack("<II", len(json_bytes), _CHUNK_JSON), json_bytes,
        struct.pack("<II", len(binary), _CHUNK_BIN), binary,
    ])
