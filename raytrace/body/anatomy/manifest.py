"""The build manifest of the anatomy pipeline: read (YAML or JSON), checked strictly, normalised.

The keys and their meaning are documented in ``docs/phantoms.md`` ("The manifest") and, for
machines, in the JSON schema shipped beside this module (``manifest.schema.json``; a test keeps
the two in step). Every defect raises :class:`~raytrace.errors.PhantomValidationError` whose
``field`` is the manifest entry (``("manifest", "organs", "colon", "files", 1)``) and whose
reason says what is wrong; unknown keys are refused everywhere, so a typo never passes silently.

Coordinates in the manifest (explicit sensors, ``transform.origin``) are in the files' units and
frame; thicknesses and heights carry their unit in their name (``thickness_m``, ``height_m``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import PurePosixPath
from typing import Any, Mapping

import yaml

from raytrace.body.gltf import MAX_CONDUCTIVITY_S_PER_M, MAX_PERMITTIVITY, NAME_PATTERN
from raytrace.errors import Field, PhantomValidationError, UnknownTissueError
from raytrace.physics.materials import Material

__all__ = ["BodySpec", "BuildManifest", "LayerSpec", "Options", "OrganSpec", "SensorBelt", "TractSpec",
           "load_manifest", "parse_manifest_text"]

#: Units of the anatomy files, metres per unit.
UNITS = {"m": 1.0, "mm": 1e-3}
#: Axis words of ``transform.axes``: which file axis (and sign) becomes the project's x, y, z.
AXES = {"x": 0, "y": 1, "z": 2}
MAX_ORGANS = 64
MAX_FILES_PER_ORGAN = 64
MAX_LAYERS = 8
MAX_BELTS = 16
MAX_SENSORS_PER_BELT = 64
MAX_TRACTS = 16
MAX_LANDMARKS = 64
MAX_MANIFEST_BYTES = 256 * 1024

#: The keys allowed at each place (manifest.schema.json lists the same; a test keeps them equal).
KEYS = {
    "manifest": {"name", "description", "units", "scale", "transform", "body", "volume", "labels", "organs",
                 "tracts", "journey", "sensors", "options"},
    "transform": {"axes", "origin"},
    "body": {"surface", "label", "layers", "fill", "name", "fill_name"},
    "layer": {"tissue", "relative_permittivity", "conductivity_s_per_m", "thickness_m", "name"},
    "organ": {"file", "files", "label", "tissue", "relative_permittivity", "conductivity_s_per_m", "max_triangles"},
    "tract": {"file", "organ", "reverse", "range", "landmarks"},
    "sensors": {"belts", "points"},
    "belt": {"height_m", "count", "name", "start_deg"},
}


def _fail(reason: str, where: Field) -> PhantomValidationError:
    return PhantomValidationError(reason, field=where)


def _brief(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


@dataclass(frozen=True)
class Options:
    """Tolerances of the checks and repairs (docs/phantoms.md, "Checks and repairs"); every one in metres."""

    #: Vertices closer than this are one vertex (weld).
    weld_m: float = 1e-6
    #: Holes whose boundary loop spans at most this are filled (a fan around the loop's centroid).
    max_hole_m: float = 0.010
    #: A boundary loop of any size is capped when it is planar within this fraction of its span (a cut).
    planar_fraction: float = 0.05
    #: Voxel edge of the remeshing that closes pieces (several shells, crossing caps) into one surface.
    voxel_m: float = 0.001
    #: Overlaps between two organs (or an organ and the body) shallower than this are resolved by clipping.
    overlap_tolerance_m: float = 0.005
    #: Clearance left between a clipped organ and the organ that clipped it.
    clearance_m: float = 0.0003
    #: Grid spacing of the body wall's signed distance field.
    wall_grid_m: float = 0.002
    #: Organs keep at least this much of the fill tissue around them where they push the wall aside.
    organ_margin_m: float = 0.002
    #: The thinnest a generated layer gets where an organ pushes it towards the skin.
    min_layer_m: float = 0.001
    #: Largest distance a decimated surface may move from the surface it simplifies (relaxed: see decimate).
    decimation_error_m: float = 0.0005
    #: Triangle budget of one organ or layer made by marching cubes or remeshing.
    max_triangles_per_surface: int = 60_000
    #: Gaussian smoothing of a labelled volume's masks before marching cubes, in voxels.
    smoothing_voxels: float = 1.0
    #: Tract points closer than this to their organ's surface, or outside it by at most this, are moved to this
    #: depth inside it (a mid-line grazing a collapsed lumen's wall); farther outside is refused.
    tract_clearance_m: float = 0.0005


@dataclass(frozen=True)
class LayerSpec:
    name: str
    material: Material
    thickness_m: float


@dataclass(frozen=True)
class BodySpec:
    files: tuple[str, ...]
    label: int | None
    layers: tuple[LayerSpec, ...]
    fill: Material
    fill_name: str
    name: str


@dataclass(frozen=True)
class OrganSpec:
    name: str
    files: tuple[str, ...]
    label: int | None
    material: Material | None  # None: from the tissue map (label names)
    max_triangles: int | None


@dataclass(frozen=True)
class TractSpec:
    name: str
    file: str
    organ: str
    reverse: bool
    landmarks: dict[str, int]
    #: The file's points used, first and last index (inclusive), before any reversal; None: all of them.
    range: tuple[int, int] | None = None


@dataclass(frozen=True)
class SensorBelt:
    name: str
    height_m: float
    count: int
    start_deg: float


@dataclass(frozen=True)
class BuildManifest:
    name: str
    description: str
    scale: float  # metres per file unit
    units: str | None
    axes: tuple[tuple[int, float], ...]  # project axis i = sign * file axis
    origin: tuple[float, float, float]  # in file units, subtracted before the axes
    body: BodySpec | None
    volume: str | None
    label_names: dict[int, str]
    organs: dict[str, OrganSpec]
    tracts: dict[str, TractSpec]
    #: Tracts joined in this order into the ``gi_tract`` centreline (the capsule's journey); empty: none.
    journey: tuple[str, ...]
    belts: tuple[SensorBelt, ...]
    sensors: dict[str, tuple[float, float, float]]
    options: Options
    raw: dict = field(repr=False, default_factory=dict)

    def files(self) -> list[tuple[str, Field]]:
        """Every file the manifest names, with its manifest entry."""
        out: list[tuple[str, Field]] = []
        if self.body is not None:
            out += [(f, ("manifest", "body", "surface")) for f in self.body.files]
        if self.volume:
            out.append((self.volume, ("manifest", "volume")))
        for organ in self.organs.values():
            out += [(f, ("manifest", "organs", organ.name, "files", i)) for i, f in enumerate(organ.files)]
        out += [(t.file, ("manifest", "tracts", t.name, "file")) for t in self.tracts.values()]
        return out


# ------------------------------------------------------------------ reading
def parse_manifest_text(text: bytes | str, *, filename: str = "manifest") -> Any:
    """YAML or JSON text (JSON is YAML) -> a Python value; refuses what is neither."""
    if isinstance(text, bytes):
        if len(text) > MAX_MANIFEST_BYTES:
            raise _fail(f"{filename} is {len(text)} bytes, over the cap of {MAX_MANIFEST_BYTES}", "manifest")
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise _fail(f"{filename} is not UTF-8 text: {exc}", "manifest") from None
    try:
        if filename.endswith(".json"):
            return json.loads(text)
        return yaml.safe_load(text)
    except RecursionError:
        raise _fail(f"{filename} nests too deeply to be read", "manifest") from None
    except (ValueError, yaml.YAMLError) as exc:
        raise _fail(f"{filename} is not valid {'JSON' if filename.endswith('.json') else 'YAML/JSON'}: "
                    f"{_brief(str(exc))}", "manifest") from None


def load_manifest(data: Any) -> BuildManifest:
    """Check a manifest (already read into Python values) and normalise it (module docstring)."""
    if not isinstance(data, Mapping):
        raise _fail("the manifest must be a mapping (YAML or a JSON object)", "manifest")
    _keys(data, KEYS["manifest"], ("manifest",))
    name = data.get("name")
    if not isinstance(name, str) or not 1 <= len(name) <= 128 or not name.isprintable():
        raise _fail("required: a name of 1-128 printable characters", "manifest.name")
    description = data.get("description", "")
    if not isinstance(description, str) or len(description) > 2000:
        raise _fail("must be a string of at most 2000 characters", "manifest.description")
    units = data.get("units")
    if "scale" in data:
        if units is not None:
            raise _fail("give units or scale, not both", "manifest.scale")
        scale = _positive(data["scale"], "manifest.scale")
    else:
        if units not in UNITS:
            raise _fail(f"required: units 'm' or 'mm' (or scale: metres per unit), got {_brief(units)}",
                        "manifest.units")
        scale = UNITS[units]
    axes, origin = _transform(data.get("transform"))
    options = _options(data.get("options", {}))
    volume = data.get("volume")
    if volume is not None:
        volume = _path(volume, "manifest.volume")
    label_names = _label_names(data.get("labels"))
    body = _body(data.get("body"), volume)
    organs_in = data.get("organs", {})
    if not isinstance(organs_in, Mapping):
        raise _fail("must map organ names to {files | label, tissue}", "manifest.organs")
    if body is None and not organs_in:
        raise _fail("nothing to build: give a body, organs, or both", "manifest")
    if len(organs_in) > MAX_ORGANS:
        raise _fail(f"{len(organs_in)} organs exceed the cap of {MAX_ORGANS}", "manifest.organs")
    organs = {}
    for organ_name, spec in organs_in.items():
        organs[organ_name] = _organ(organ_name, spec, volume, label_names)
    reserved = set()
    if body is not None:
        reserved = {body.name, body.fill_name, *(layer.name for layer in body.layers)}
    clash = sorted(reserved & set(organs))
    if clash:
        raise _fail(f"organ name {clash[0]!r} is taken by the body or one of its layers", ("manifest", "organs",
                                                                                             clash[0]))
    tracts = _tracts(data.get("tracts", {}), organs)
    journey = _journey(data.get("journey", []), tracts)
    belts, sensors = _sensors(data.get("sensors", {}), body)
    return BuildManifest(name=name, description=description, scale=scale, units=units, axes=axes,
                         origin=origin, body=body, volume=volume, label_names=label_names, organs=organs,
                         tracts=tracts, journey=journey, belts=belts, sensors=sensors, options=options,
                         raw=dict(data))


# ------------------------------------------------------------------ pieces
def _keys(spec: Mapping, allowed: set[str], where: tuple) -> None:
    unknown = sorted(str(k) for k in spec if k not in allowed)
    if unknown:
        raise _fail(f"unknown key {_brief(unknown[0])}; allowed: {', '.join(sorted(allowed))}", (*where, unknown[0]))


def _number(value: Any, where: Field) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(f"must be a finite number, got {_brief(value)}", where)
    try:
        out = float(value)
    except OverflowError:
        out = math.inf
    if not math.isfinite(out):
        raise _fail(f"must be a finite number, got {_brief(value)}", where)
    return out


def _positive(value: Any, where: Field) -> float:
    out = _number(value, where)
    if out <= 0:
        raise _fail(f"must be > 0, got {out:g}", where)
    return out


def _int(value: Any, where: Field, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise _fail(f"must be an integer in [{lo}, {hi}], got {_brief(value)}", where)
    return int(value)


def _name(value: Any, where: Field) -> str:
    if not isinstance(value, str) or not NAME_PATTERN.match(value):
        raise _fail(f"name {_brief(value)} must match {NAME_PATTERN.pattern}", where)
    return value


def _path(value: Any, where: Field) -> str:
    """A file name relative to the manifest (or to the root of an uploaded zip)."""
    if not isinstance(value, str) or not value or len(value) > 512 or "\x00" in value:
        raise _fail(f"must be a file name relative to the manifest, got {_brief(value)}", where)
    path = PurePosixPath(value.replace("\\", "/"))
    if path.is_absolute() and not value.startswith("/"):
        raise _fail("must be a relative file name", where)
    return value


def _vec3(value: Any, where: Field) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise _fail(f"must be [x, y, z], got {_brief(value)}", where)
    return tuple(_number(v, where) for v in value)  # type: ignore[return-value]


def _material(spec: Mapping, where: tuple, *, required: bool) -> Material | None:
    """``tissue`` or ``relative_permittivity`` (+ ``conductivity_s_per_m``) of an entry."""
    has_tissue = "tissue" in spec
    has_eps = "relative_permittivity" in spec or "conductivity_s_per_m" in spec
    if has_tissue and has_eps:
        raise _fail("give either tissue or relative_permittivity (+ conductivity_s_per_m), not both",
                    (*where, "relative_permittivity"))
    if has_tissue:
        tissue = spec["tissue"]
        if not isinstance(tissue, str):
            raise _fail(f"must be a tissue name, got {_brief(tissue)}", (*where, "tissue"))
        try:
            return Material(tissue=tissue)
        except UnknownTissueError as exc:
            raise UnknownTissueError(exc.reason, field=(*where, "tissue")) from None
    if has_eps:
        if "relative_permittivity" not in spec:
            raise _fail("required with conductivity_s_per_m", (*where, "relative_permittivity"))
        eps = _number(spec["relative_permittivity"], (*where, "relative_permittivity"))
        sigma = _number(spec.get("conductivity_s_per_m", 0.0), (*where, "conductivity_s_per_m"))
        if not 1.0 <= eps <= MAX_PERMITTIVITY:
            raise _fail(f"must be in [1, {MAX_PERMITTIVITY:g}], got {eps:g}", (*where, "relative_permittivity"))
        if not 0.0 <= sigma <= MAX_CONDUCTIVITY_S_PER_M:
            raise _fail(f"must be in [0, {MAX_CONDUCTIVITY_S_PER_M:g}], got {sigma:g}",
                        (*where, "conductivity_s_per_m"))
        return Material(relative_permittivity=eps, conductivity_s_per_m=sigma)
    if required:
        raise _fail("required: tissue (GET /v1/tissues), or relative_permittivity (+ conductivity_s_per_m)", where)
    return None


def _files(spec: Mapping, where: tuple) -> tuple[str, ...]:
    if "file" in spec and "files" in spec:
        raise _fail("give file or files, not both", (*where, "files"))
    if "file" in spec:
        return (_path(spec["file"], (*where, "file")),)
    files = spec.get("files", [])
    if isinstance(files, str):
        files = [files]
    if not isinstance(files, list) or len(files) > MAX_FILES_PER_ORGAN:
        raise _fail(f"must be a list of at most {MAX_FILES_PER_ORGAN} file names", (*where, "files"))
    return tuple(_path(f, (*where, "files", i)) for i, f in enumerate(files))


def _label(value: Any, where: tuple, volume: str | None, label_names: dict[int, str]) -> int:
    if volume is None:
        raise _fail("a label needs a labelled volume: give `volume: labels.nii.gz` at the top", where)
    if isinstance(value, str):
        matches = [k for k, v in label_names.items() if v == value]
        if not matches:
            raise _fail(f"no label is named {value!r} in `labels` (give the label's number, or name it there)",
                        where)
        return matches[0]
    return _int(value, where, 1, 2**31 - 1)


def _transform(spec: Any) -> tuple[tuple[tuple[int, float], ...], tuple[float, float, float]]:
    if spec is None:
        return ((0, 1.0), (1, 1.0), (2, 1.0)), (0.0, 0.0, 0.0)
    where = ("manifest", "transform")
    if not isinstance(spec, Mapping):
        raise _fail("must be {axes: [..3..], origin: [x, y, z]}", where)
    _keys(spec, KEYS["transform"], where)
    axes_in = spec.get("axes", ["x", "y", "z"])
    if not isinstance(axes_in, list) or len(axes_in) != 3:
        raise _fail("must be three axis words, e.g. [-x, -y, z]: the file axis that becomes the project's x "
                    "(subject's left), y (posterior) and z (up)", (*where, "axes"))
    axes = []
    for i, word in enumerate(axes_in):
        if not isinstance(word, str) or word.lstrip("+-") not in AXES or len(word) > 2:
            raise _fail(f"axis {_brief(word)} must be x, y or z with an optional sign", (*where, "axes", i))
        axes.append((AXES[word.lstrip("+-")], -1.0 if word.startswith("-") else 1.0))
    if len({a for a, _ in axes}) != 3:
        raise _fail("each file axis must appear once", (*where, "axes"))
    origin = _vec3(spec.get("origin", [0.0, 0.0, 0.0]), (*where, "origin"))
    return tuple(axes), origin


def _options(spec: Any) -> Options:
    where = ("manifest", "options")
    if not isinstance(spec, Mapping):
        raise _fail("must be a mapping of option names to values", where)
    defaults = Options()
    allowed = set(Options.__dataclass_fields__)
    _keys(spec, allowed, where)
    values = {}
    for key, value in spec.items():
        default = getattr(defaults, key)
        if isinstance(default, int):
            values[key] = _int(value, (*where, key), 1000, 2_000_000)
        else:
            values[key] = _positive(value, (*where, key))
    opts = Options(**values)
    limits = {"voxel_m": (1e-4, 0.02), "wall_grid_m": (2e-4, 0.02), "max_hole_m": (0.0, 0.2),
              "overlap_tolerance_m": (0.0, 0.05), "planar_fraction": (0.0, 0.5), "smoothing_voxels": (0.0, 4.0),
              "tract_clearance_m": (0.0, 0.01)}
    for key, (lo, hi) in limits.items():
        v = getattr(opts, key)
        if not lo < v <= hi:
            raise _fail(f"must be in ({lo:g}, {hi:g}], got {v:g}", (*where, key))
    return opts


def _label_names(spec: Any) -> dict[int, str]:
    """Label number -> class name: ``labels`` when given, else TotalSegmentator's ``total`` task (v2)."""
    from raytrace.body.anatomy.tissuemap import TOTAL_V2_CLASSES

    if spec is None:
        return dict(TOTAL_V2_CLASSES)
    where = ("manifest", "labels")
    if not isinstance(spec, Mapping):
        raise _fail("must map label numbers to class names (e.g. TotalSegmentator's)", where)
    out = {}
    for key, value in spec.items():
        try:
            number = int(key)
        except (TypeError, ValueError):
            raise _fail(f"label {_brief(key)} must be an integer", (*where, str(key))) from None
        if not isinstance(value, str) or not value:
            raise _fail("must be a class name", (*where, str(key)))
        out[number] = value
    return out


_LAYER_NAMES = (("skin", "skin"), ("fat", "subcutaneous_fat"), ("muscle", "muscle_wall"))


def _body(spec: Any, volume: str | None) -> BodySpec | None:
    if spec is None:
        return None
    where = ("manifest", "body")
    if not isinstance(spec, Mapping):
        raise _fail("must be {surface: file | label: N, layers: [...], fill: tissue}", where)
    _keys(spec, KEYS["body"], where)
    files: tuple[str, ...] = ()
    label = None
    if "surface" in spec:
        raw = spec["surface"]
        raw = [raw] if isinstance(raw, str) else raw
        if not isinstance(raw, list) or not raw or len(raw) > MAX_FILES_PER_ORGAN:
            raise _fail("must name the body surface's file(s)", (*where, "surface"))
        files = tuple(_path(f, (*where, "surface", i)) for i, f in enumerate(raw))
    if "label" in spec:
        if files:
            raise _fail("give surface or label, not both", (*where, "label"))
        label = _label(spec["label"], (*where, "label"), volume, {})
    if not files and label is None:
        raise _fail("required: surface (file) or label (of the volume)", (*where, "surface"))
    layers_in = spec.get("layers", [])
    if not isinstance(layers_in, list) or len(layers_in) > MAX_LAYERS:
        raise _fail(f"must be a list of at most {MAX_LAYERS} layers, outermost first", (*where, "layers"))
    layers = []
    used: set[str] = set()
    for i, layer in enumerate(layers_in):
        lw = (*where, "layers", i)
        if not isinstance(layer, Mapping):
            raise _fail("must be {tissue, thickness_m}", lw)
        _keys(layer, KEYS["layer"], lw)
        material = _material(layer, lw, required=True)
        if "thickness_m" not in layer:
            raise _fail("required: the layer's thickness in metres", (*lw, "thickness_m"))
        thickness = _positive(layer["thickness_m"], (*lw, "thickness_m"))
        if thickness > 0.1:
            raise _fail(f"{thickness:g} m is no body-wall layer (at most 0.1 m); thickness_m is in metres",
                        (*lw, "thickness_m"))
        if "name" in layer:
            name = _name(layer["name"], (*lw, "name"))
        else:
            tissue = material.tissue or ""
            name = next((n for key, n in _LAYER_NAMES if key in tissue), f"layer_{i}")
            if name in used:
                name = f"{name}_{i}"
        if name in used:
            raise _fail(f"layer name {name!r} is used twice", (*lw, "name"))
        used.add(name)
        layers.append(LayerSpec(name, material, thickness))
    fill_spec = spec.get("fill", "muscle")
    fw = (*where, "fill")
    fill = _material(fill_spec if isinstance(fill_spec, Mapping) else {"tissue": fill_spec}, fw, required=True)
    body_name = _name(spec.get("name", layers[0].name if layers else "body"), (*where, "name"))
    if layers and body_name != layers[0].name:
        raise _fail("with layers, the body is the outermost layer: name it there", (*where, "name"))
    fill_name = _name(spec.get("fill_name", "body_fill" if layers else body_name), (*where, "fill_name"))
    if fill_name in used and layers:
        raise _fail(f"fill name {fill_name!r} is a layer's", (*where, "fill_name"))
    return BodySpec(files=files, label=label, layers=tuple(layers), fill=fill, fill_name=fill_name, name=body_name)


def _organ(name: Any, spec: Any, volume: str | None, label_names: dict[int, str]) -> OrganSpec:
    where = ("manifest", "organs", str(name))
    _name(name, where)
    if not isinstance(spec, Mapping):
        raise _fail("must be {files: [...] | label: N, tissue: name}", where)
    _keys(spec, KEYS["organ"], where)
    files = _files(spec, where)
    label = None
    if "label" in spec:
        if files:
            raise _fail("give files or label, not both", (*where, "label"))
        label = _label(spec["label"], (*where, "label"), volume, label_names)
    if not files and label is None:
        raise _fail("required: files (surface meshes) or label (of the volume)", (*where, "files"))
    material = _material(spec, where, required=label is None)
    max_tri = None
    if "max_triangles" in spec:
        max_tri = _int(spec["max_triangles"], (*where, "max_triangles"), 100, 2_000_000)
    return OrganSpec(name=name, files=files, label=label, material=material, max_triangles=max_tri)


def _tracts(spec: Any, organs: dict[str, OrganSpec]) -> dict[str, TractSpec]:
    where = ("manifest", "tracts")
    if not isinstance(spec, Mapping) or len(spec) > MAX_TRACTS:
        raise _fail(f"must map at most {MAX_TRACTS} tract names to {{file, organ}}", where)
    out = {}
    for name, tract in spec.items():
        tw = (*where, str(name))
        _name(name, tw)
        if not isinstance(tract, Mapping):
            raise _fail("must be {file, organ, reverse, landmarks}", tw)
        _keys(tract, KEYS["tract"], tw)
        if "file" not in tract:
            raise _fail("required: the centreline file (JSON {points: [...]} or CSV x,y,z)", (*tw, "file"))
        organ = tract.get("organ")
        if organ not in organs:
            raise _fail(f"must name one of the organs ({', '.join(organs) or 'none'}), got {_brief(organ)}",
                        (*tw, "organ"))
        reverse = tract.get("reverse", False)
        if not isinstance(reverse, bool):
            raise _fail("must be true or false", (*tw, "reverse"))
        marks = tract.get("landmarks", {})
        if not isinstance(marks, Mapping) or len(marks) > MAX_LANDMARKS:
            raise _fail(f"must map at most {MAX_LANDMARKS} landmark names to point indices", (*tw, "landmarks"))
        span = None
        if "range" in tract:
            raw = tract["range"]
            if not isinstance(raw, list) or len(raw) != 2:
                raise _fail(f"must be [first, last]: the indices of the file's first and last points used, got "
                            f"{_brief(raw)}", (*tw, "range"))
            first, last = (_int(v, (*tw, "range", k), 0, 10**7) for k, v in enumerate(raw))
            if last <= first:
                raise _fail(f"the last point ({last}) must come after the first ({first})", (*tw, "range"))
            span = (first, last)
        landmarks = {}
        for mark, index in marks.items():
            _name(mark, (*tw, "landmarks", str(mark)))
            landmarks[mark] = _int(index, (*tw, "landmarks", mark), 0, 10**7)
            if span is not None and not span[0] <= landmarks[mark] <= span[1]:
                raise _fail(f"landmark {mark!r} is point {landmarks[mark]}, outside the tract's range "
                            f"[{span[0]}, {span[1]}]", (*tw, "landmarks", mark))
        out[name] = TractSpec(name, _path(tract["file"], (*tw, "file")), organ, reverse, landmarks, span)
    return out


def _journey(spec: Any, tracts: dict[str, TractSpec]) -> tuple[str, ...]:
    """Tract names, each once, joined in this order into the ``gi_tract`` centreline."""
    from raytrace.body.centreline import GI_TRACT

    where = ("manifest", "journey")
    if not isinstance(spec, list) or len(spec) > MAX_TRACTS:
        raise _fail(f"must be a list of at most {MAX_TRACTS} tract names, in the order the capsule passes them",
                    where)
    for i, name in enumerate(spec):
        if name not in tracts:
            raise _fail(f"must name one of the tracts ({', '.join(tracts) or 'none'}), got {_brief(name)}",
                        (*where, i))
    if len(set(spec)) != len(spec):
        raise _fail("each tract may appear once", where)
    if spec and GI_TRACT in tracts:
        raise _fail(f"a journey is the {GI_TRACT!r} centreline: no tract may have that name then",
                    ("manifest", "tracts", GI_TRACT))
    return tuple(spec)


def _sensors(spec: Any, body: BodySpec | None) -> tuple[tuple[SensorBelt, ...], dict]:
    where = ("manifest", "sensors")
    if not isinstance(spec, Mapping):
        raise _fail("must be {belts: [...], points: {name: [x, y, z]}}", where)
    _keys(spec, KEYS["sensors"], where)
    belts_in = spec.get("belts", [])
    if not isinstance(belts_in, list) or len(belts_in) > MAX_BELTS:
        raise _fail(f"must be a list of at most {MAX_BELTS} belts", (*where, "belts"))
    if belts_in and body is None:
        raise _fail("belts lie on the skin: give a body", (*where, "belts"))
    belts = []
    for i, belt in enumerate(belts_in):
        bw = (*where, "belts", i)
        if not isinstance(belt, Mapping):
            raise _fail("must be {height_m, count}", bw)
        _keys(belt, KEYS["belt"], bw)
        if "height_m" not in belt:
            raise _fail("required: height above the body's lowest point, in metres", (*bw, "height_m"))
        height = _number(belt["height_m"], (*bw, "height_m"))
        if height < 0:
            raise _fail(f"must be >= 0, got {height:g}", (*bw, "height_m"))
        count = _int(belt.get("count", 8), (*bw, "count"), 1, MAX_SENSORS_PER_BELT)
        name = _name(belt.get("name", f"belt{i + 1}"), (*bw, "name"))
        start = _number(belt.get("start_deg", 0.0), (*bw, "start_deg"))
        belts.append(SensorBelt(name, height, count, start))
    if len({b.name for b in belts}) != len(belts):
        raise _fail("belt names must be unique", (*where, "belts"))
    points_in = spec.get("points", {})
    if not isinstance(points_in, Mapping):
        raise _fail("must map sensor names to [x, y, z] (in the files' units and frame)", (*where, "points"))
    points = {}
    for name, point in points_in.items():
        _name(name, (*where, "points", str(name)))
        points[name] = _vec3(point, (*where, "points", name))
    return tuple(belts), points
