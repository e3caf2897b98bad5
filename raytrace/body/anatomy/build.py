"""The anatomy pipeline: a manifest and its files -> a validated :class:`Phantom` and its build report.

One code path for the CLI (``capsule-rt phantom build``), the HTTP API (``POST /v1/phantoms`` with a zip,
run as a job) and the built-in phantoms made from files (docs/phantoms.md). In order:

1. **manifest** (:mod:`.manifest`) and **limits** (:class:`Limits`): every file named is found (inside
   the directory it must stay in, for uploads), its size, a volume's voxel count and the grids' cells are
   checked, and the memory the build will need is estimated, all before any mesh is decoded;
2. **surfaces**: each organ's files are read (:mod:`.readers`) or its label meshed (:mod:`.volume`),
   mapped to metres in the project frame (x subject's left, y posterior, z up: ``units``/``scale`` then
   ``transform``), repaired and closed (:mod:`.repair`), decimated to its budget (:mod:`.decimate`);
   tissues of labels without one come from the tissue map (:mod:`.tissuemap`);
3. **overlaps** between organs resolved or refused (:mod:`.overlap`);
4. **body wall** (:mod:`.wall`) under the body surface, and the organs clipped to its inner solid where they
   come too close to the skin (without layers: to the body itself);
5. **phantom**: :meth:`Phantom.build` checks everything again (closed, outward, nested, no crossings), then
   the sensors (:mod:`.sensors`) and the tracts with their landmarks (:mod:`.tracts`) are placed and
   checked to lie where they claim;
6. **report** (:func:`markdown_report`): per organ and layer, triangles, volume, repairs; tracts, sensors.

Nothing is stored here: callers write the phantom only once it has been built whole.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import trimesh

from raytrace.body.anatomy import tissuemap
from raytrace.body.anatomy.decimate import decimate
from raytrace.body.anatomy.manifest import BuildManifest, Options, load_manifest
from raytrace.body.anatomy.overlap import clip_inside, crossing_pairs, resolve_overlaps
from raytrace.body.anatomy.readers import gltf_buffer_files, read_surface, suffix_of
from raytrace.body.anatomy.repair import repair_surface, union_of
from raytrace.body.anatomy.sensors import belt_positions
from raytrace.body.anatomy.tracts import build_tract, read_points
from raytrace.body.anatomy.volume import LabelVolume, label_surface, open_volume
from raytrace.body.anatomy.wall import generate_wall
from raytrace.body.centreline import GI_TRACT, Centreline
from raytrace.body.phantom import AIR_INDEX, Organ, Phantom, Site, Surfaces
from raytrace.body.topology import ClosedEdges
from raytrace.errors import Field, InvalidGeometryError, PhantomValidationError
from raytrace.physics.materials import Material

__all__ = ["BuildResult", "Limits", "build_phantom", "check_limits", "markdown_report"]

Progress = Callable[[float, str], None]


@dataclass(frozen=True)
class Limits:
    """Bounds checked before work (docs/phantoms.md, "Limits"). The service passes its settings'."""

    max_file_bytes: int = 512 * 2**20
    max_total_bytes: int = 2 * 2**30
    max_input_triangles: int = 8_000_000
    max_voxels: int = 512 * 2**20
    max_grid_cells: int = 60_000_000
    max_output_triangles: int = 2_000_000
    max_memory_bytes: int = 3 * 2**30


@dataclass
class BuildResult:
    phantom: Phantom
    report: dict[str, Any]


@dataclass
class _Context:
    manifest: BuildManifest
    root: Path
    confine: bool
    limits: Limits
    progress: Progress
    volume: LabelVolume | None = None
    timings: dict[str, float] = field(default_factory=dict)
    #: id of a surface as its repairs left it -> its closed edges (handed to the phantom's checks)
    edges: dict[int, ClosedEdges] = field(default_factory=dict)


def _fail(reason: str, where: Field) -> PhantomValidationError:
    return PhantomValidationError(reason, field=where)


def _resolve(ctx: _Context, name: str, where: Field) -> Path:
    path = (ctx.root / name).resolve() if not Path(name).is_absolute() else Path(name).resolve()
    if ctx.confine:
        root = ctx.root.resolve()
        if Path(name).is_absolute() or (path != root and root not in path.parents):
            raise _fail(f"{name}: a file of an upload must lie inside it (a relative name without '..')", where)
    if not path.is_file():
        raise _fail(f"{name}: no such file (next to the manifest)", where)
    return path


def check_limits(manifest: BuildManifest, root: Path, limits: Limits, *, confine: bool = False) -> dict[str, Any]:
    """Everything checkable before decoding a mesh (module docstring, step 1); the estimates it made."""
    ctx = _Context(manifest, Path(root), confine, limits, lambda f, m: None)
    return _plan(ctx)


def _plan(ctx: _Context) -> dict[str, Any]:
    m, limits = ctx.manifest, ctx.limits
    total = 0
    for name, where in m.files():
        path = _resolve(ctx, name, where)
        size = path.stat().st_size
        if size > limits.max_file_bytes:
            raise _fail(f"{name} is {size} bytes, over the cap of {limits.max_file_bytes} bytes per file", where)
        total += size
        if suffix_of(name) == ".gltf":  # its buffer files count too (and an upload must hold them)
            for buffer in gltf_buffer_files(path, ctx.root, where, max_bytes=limits.max_file_bytes):
                total += buffer.stat().st_size
    if total > limits.max_total_bytes:
        raise _fail(f"the files hold {total} bytes, over the cap of {limits.max_total_bytes}", "manifest")
    voxels = 0
    if m.volume:
        ctx.volume = open_volume(_resolve(ctx, m.volume, ("manifest", "volume")), ("manifest", "volume"),
                                 scale_m_per_unit=m.scale, max_bytes=limits.max_file_bytes,
                                 max_voxels=limits.max_voxels)
        voxels = int(np.prod(ctx.volume.shape))
    # memory: decoded meshes (~ 40 bytes per file byte of text, at most), labels (int32 + masks),
    # and the wall's grid (a few float32 fields and masks: ~ 40 bytes per cell)
    wall_cells = 0
    if m.body is not None and m.body.layers and m.body.files:
        wall_cells = -1  # known once the body is read (the grid is checked then, before any field is made)
    estimate = 12 * total + 10 * voxels
    if estimate > limits.max_memory_bytes:
        raise _fail(f"the build would need about {estimate / 2**20:.0f} MiB, over the bound of "
                    f"{limits.max_memory_bytes / 2**20:.0f} MiB: fewer or smaller files", "manifest")
    return {"file_bytes": total, "voxels": voxels, "memory_estimate_bytes": estimate, "wall_cells": wall_cells}


def _to_metres(m: BuildManifest) -> tuple[Callable[[np.ndarray], np.ndarray], bool]:
    """The map from file coordinates to the project frame in metres, and whether it mirrors."""
    axes, origin = m.axes, np.asarray(m.origin, float)
    matrix = np.zeros((3, 3))
    for i, (axis, sign) in enumerate(axes):
        matrix[i, axis] = sign
    mirrors = np.linalg.det(matrix) < 0

    def to_m(points: np.ndarray) -> np.ndarray:
        return ((np.asarray(points, float) - origin) @ matrix.T) * m.scale

    return to_m, bool(mirrors)


def _surface(ctx: _Context, name: str, files: tuple[str, ...], label: int | None, where: Field, budget: int,
             triangles_left: list[int]) -> tuple[trimesh.Trimesh, list[str], str, list[trimesh.Trimesh]]:
    """One organ's (or the body's) closed surface in metres, its repairs, its source and its files' closed
    surfaces (:attr:`raytrace.body.anatomy.repair.Repaired.pieces`)."""
    m = ctx.manifest
    to_m, mirrors = _to_metres(m)
    options = m.options
    notes: list[str] = []
    counts: list[int] | None = None
    if label is not None:
        assert ctx.volume is not None
        mesh, notes = label_surface(ctx.volume, label, where, name, options)
        vertices, faces = to_m(mesh.vertices), np.asarray(mesh.faces)
        source = f"label {label} of {ctx.volume.name}"
    else:
        all_v, all_f, base = [], [], 0
        for i, f in enumerate(files):
            fw = (*where, i) if isinstance(where, tuple) and len(files) > 1 else where
            v, t = read_surface(_resolve(ctx, f, fw), fw, max_bytes=ctx.limits.max_file_bytes,
                                max_triangles=triangles_left[0], root=ctx.root)
            triangles_left[0] -= len(t)
            all_v.append(v)
            all_f.append(t + base)
            base += len(v)
        vertices, faces = to_m(np.concatenate(all_v)), np.concatenate(all_f)
        counts = [len(t) for t in all_f]
        source = ", ".join(files)
    if mirrors:
        faces = faces[:, ::-1]
    repaired = repair_surface(vertices, faces, where, f"{name} ({source})", options, budget=budget,
                              max_cells=ctx.limits.max_grid_cells, check_crossings=False, pieces=counts)
    mesh = repaired.mesh
    notes += repaired.repairs
    if repaired.edges is not None:
        ctx.edges[id(mesh)] = repaired.edges
    if len(mesh.faces) > budget and not repaired.remeshed:  # a remeshed surface was decimated from its voxels
        before = len(mesh.faces)
        mesh, error = decimate(mesh, budget, options.decimation_error_m)
        if len(mesh.faces) < before:
            over = f", over the budget of {budget}: no fewer kept it closed" if len(mesh.faces) > budget else ""
            notes.append(f"decimated {before} -> {len(mesh.faces)} triangles (within {error * 1e3:.3g} mm{over})")
        else:
            notes.append(f"kept {before} triangles, over the budget of {budget}: no decimation within "
                         f"decimation_error_m kept the surface closed and two-manifold")
    return mesh, notes, source, repaired.pieces


def _material(ctx: _Context, name: str, material: Material | None, label: int | None) -> tuple[Material, str | None]:
    if material is not None:
        return material, None
    class_name = ctx.manifest.label_names.get(label or -1)
    tissue = tissuemap.tissue_for(class_name) if class_name else None
    if tissue is None:
        what = f"class {class_name!r}" if class_name else "no class name (give it in `labels`)"
        raise _fail(f"organ {name!r} (label {label}, {what}) has no tissue in the built-in map of TotalSegmentator "
                    "classes: give its tissue", ("manifest", "organs", name, "tissue"))
    return Material(tissue=tissue), f"tissue {tissue} from the map of TotalSegmentator class {class_name!r}"


def build_phantom(manifest: Any, root: Path, *, limits: Limits = Limits(), confine: bool = False,
                  progress: Progress | None = None) -> BuildResult:
    """Build the phantom a manifest describes (module docstring). ``manifest``: the manifest's Python value
    (as read by :func:`raytrace.body.anatomy.manifest.parse_manifest_text`) or a :class:`BuildManifest`;
    ``root``: the directory its file names are relative to; ``confine``: refuse names leaving ``root``."""
    m = manifest if isinstance(manifest, BuildManifest) else load_manifest(manifest)
    ctx = _Context(m, Path(root), confine, limits, progress or (lambda f, msg: None))
    clock = time.perf_counter()
    ctx.progress(0.0, "checking the manifest and the files' sizes")
    plan = _plan(ctx)
    options: Options = m.options
    triangles_left = [limits.max_input_triangles]
    organ_meshes: dict[str, trimesh.Trimesh] = {}
    organ_notes: dict[str, list[str]] = {}
    organ_source: dict[str, str] = {}
    organ_pieces: dict[str, list[trimesh.Trimesh]] = {}
    fields: dict[str, Field] = {}
    materials: dict[str, Material] = {}
    n_steps = len(m.organs) + (1 if m.body else 0) + 3
    step = 0
    body_mesh = body_notes = None
    if m.body is not None:
        ctx.progress(step / n_steps, "reading the body surface")
        body_mesh, body_notes, body_source, _ = _surface(ctx, m.body.name, m.body.files, m.body.label,
                                                      ("manifest", "body", "surface"), options.max_triangles_per_surface
                                                      * 4, triangles_left)
        step += 1
    for name, spec in m.organs.items():
        ctx.progress(step / n_steps, f"reading organ {name}")
        where = ("manifest", "organs", name, "files" if spec.files else "label")
        budget = spec.max_triangles or options.max_triangles_per_surface
        mesh, notes, source, pieces = _surface(ctx, name, spec.files, spec.label, where, budget, triangles_left)
        material, note = _material(ctx, name, spec.material, spec.label)
        if note:
            notes.insert(0, note)
        organ_meshes[name], organ_notes[name], organ_source[name] = mesh, notes, source
        organ_pieces[name] = pieces
        materials[name] = material
        fields[name] = ("manifest", "organs", name)
        step += 1
    ctx.timings["surfaces_s"] = time.perf_counter() - clock
    ctx.progress(step / n_steps, "resolving overlaps between organs")
    names = list(organ_meshes)
    # the body first, then the organs: the order of the phantom when the body has no generated layers, so
    # that the scene and checks made here serve Phantom.build too when nothing changes in between
    offset = 1 if body_mesh is not None else 0
    labels = ([m.body.name] if m.body is not None else []) + names  # type: ignore[union-attr]
    everything = ([body_mesh] if body_mesh is not None else []) + [organ_meshes[n] for n in names]
    try:
        checked: Surfaces | None = crossing_pairs(everything, labels, [ctx.edges.get(id(x)) for x in everything])
    except PhantomValidationError as exc:
        raise _fail(exc.reason, _manifest_field(exc.field, fields, m)) from None
    assert checked is not None
    crossing = checked.crossings
    for i, j in sorted(crossing):  # surfaces crossing themselves after their repairs: voxel union (step 5)
        if i != j:
            continue
        label = labels[i]
        surface_field: Field = fields.get(label, ("manifest", "body", "surface"))
        mesh, note = union_of(everything[i], surface_field, label, options, budget=options.max_triangles_per_surface,
                              max_cells=limits.max_grid_cells, pieces=organ_pieces.get(label))
        if i >= offset:
            organ_meshes[label] = mesh
            organ_notes[label].append(note)
        else:
            body_mesh = mesh
            body_notes.append(note)  # type: ignore[union-attr]
    organ_crossing: set[tuple[int, int]] | None
    body_crossing: set[int] = set()
    if any(i == j for i, j in crossing):
        organ_crossing, checked = None, None  # the remeshed surfaces are new: let the overlap step test again
    else:
        organ_crossing = {(i - offset, j - offset) for i, j in crossing if i >= offset}
        body_crossing = {j - offset for i, j in crossing if i < offset}
    organ_meshes, overlap_notes = resolve_overlaps(organ_meshes, fields, options.overlap_tolerance_m,
                                                   options.clearance_m, organ_crossing)
    for name, notes in overlap_notes.items():
        organ_notes[name] += notes
    step += 1
    organs: list[Organ] = []
    layers_report = []
    if m.body is not None:
        assert body_mesh is not None
        first_material = m.body.layers[0].material if m.body.layers else m.body.fill
        organs.append(Organ(m.body.name, first_material, body_mesh))
        _check_inside_body(organ_meshes, body_mesh, fields, m.body.name, options,
                           None if checked is None else body_crossing)
        if len(m.body.layers) >= 1:
            ctx.progress(step / n_steps, "generating the body wall")
            t0 = time.perf_counter()
            wall = generate_wall(body_mesh, list(organ_meshes.values()), m.body.layers, m.body.fill, m.body.fill_name,
                                 options, max_cells=limits.max_grid_cells, where=("manifest", "body", "layers"),
                                 progress=lambda msg: ctx.progress(step / n_steps, msg))
            ctx.timings["wall_s"] = time.perf_counter() - t0
            for layer in wall.layers:
                organs.append(Organ(layer.name, layer.material, layer.mesh))
            container, what = wall.clip, f"the inner solid of the body wall ({wall.layers[-1].name})"
            layers_report = [_layer_report(m.body.layers[0].name, m.body.layers[0].material, 0.0,
                                           m.body.layers[0].thickness_m, body_mesh)]
            for k, layer in enumerate(wall.layers):
                thickness = m.body.layers[k + 1].thickness_m if k + 1 < len(m.body.layers) else None
                layers_report.append(_layer_report(layer.name, layer.material, layer.depth_m, thickness, layer.mesh,
                                                   layer))
            plan["wall_cells"] = wall.grid.cells
            plan["wall_grid_shape"] = list(wall.grid.shape)
        else:
            container = _inset(body_mesh, options.clearance_m)
            what = f"the body surface pulled in by {options.clearance_m * 1e3:g} mm"
        if container is not None:
            for name in list(organ_meshes):
                clipped, note = clip_inside(organ_meshes[name], container, what)
                if note:
                    if not len(clipped.faces):
                        raise _fail(f"organ {name!r}: {note}", fields[name])
                    organ_meshes[name] = clipped
                    organ_notes[name].append(note)
        step += 1
    for name, mesh in organ_meshes.items():
        organs.append(Organ(name, materials[name], mesh))
    total = sum(len(o.mesh.faces) for o in organs)
    if total > limits.max_output_triangles:
        raise _fail(f"the phantom would have {total} triangles, over the cap of {limits.max_output_triangles}: "
                    "lower max_triangles of the organs or options.max_triangles_per_surface", "manifest")
    ctx.progress(step / n_steps, f"checking the phantom ({total} triangles)")
    t0 = time.perf_counter()
    sensors = _sensor_positions(m, body_mesh)
    try:
        phantom = Phantom.build(m.name, organs, sites={n: ("sensor", p.tolist()) for n, p in sensors.items()},
                                description=m.description or f"Built from {len(organs)} surfaces by the anatomy "
                                "pipeline (docs/phantoms.md).", max_triangles=limits.max_output_triangles,
                                checked=checked)
    except PhantomValidationError as exc:
        raise PhantomValidationError(exc.reason, field=_manifest_field(exc.field, fields, m)) from None
    ctx.timings["phantom_build_s"] = time.perf_counter() - t0
    sensor_report = _check_sensors(phantom, sensors, m)
    tracts_report = []
    built_tracts = {}
    for tract_spec in m.tracts.values():
        points = read_points(_resolve(ctx, tract_spec.file, ("manifest", "tracts", tract_spec.name, "file")),
                             ("manifest", "tracts", tract_spec.name, "file"))
        tract = build_tract(tract_spec, points, _to_metres(m)[0], phantom, options.tract_clearance_m)
        phantom.centrelines[tract_spec.name] = tract.centreline
        built_tracts[tract_spec.name] = tract
        for mark, point in tract.landmark_points_m.items():
            site = f"{tract_spec.name}_{mark}"
            try:
                medium = phantom.antenna_medium(point, field=("manifest", "tracts", tract_spec.name, "landmarks", mark))
            except InvalidGeometryError as exc:
                raise PhantomValidationError(exc.reason, field=exc.field) from None
            if phantom.medium_name(medium) != tract_spec.organ:
                raise _fail(f"landmark {mark!r} lies in {phantom.medium_name(medium)!r}, not in {tract_spec.organ!r}",
                            ("manifest", "tracts", tract_spec.name, "landmarks", mark))
            phantom.sites[site] = Site(site, "capsule", np.asarray(point, float), tract_spec.organ)
        tracts_report.append({"name": tract_spec.name, "organ": tract_spec.organ,
                              "length_mm": tract.centreline.length_m * 1e3,
                              "points": int(sum(len(p.points_m) for p in tract.centreline.pieces)),
                              "reverse": tract_spec.reverse,
                              "landmarks_s_mm": {k: v * 1e3 for k, v in tract.landmarks_s_m.items()},
                              "notes": tract.notes})
    phantom.metadata.update({"source": "anatomy", "tracts": {t["name"]: t["landmarks_s_mm"] for t in tracts_report}})
    journey_report = _journey(m, phantom, built_tracts)
    ctx.timings["total_s"] = time.perf_counter() - clock
    report = _report(m, phantom, organ_notes, organ_source, body_notes, layers_report, tracts_report, sensor_report,
                     plan, ctx.timings)
    report["journey"] = journey_report
    ctx.progress(1.0, "built")
    return BuildResult(phantom, report)


def _journey(m: BuildManifest, phantom: Phantom, tracts: dict) -> dict | None:
    """The tracts of ``m.journey`` joined in order into the ``gi_tract`` centreline (the capsule's way: the
    position jumps where one tract ends and the next begins, the arc length runs on), which replaces their own
    centrelines, with every landmark's site and arc length along it (``phantom.metadata["journey"]``)."""
    if not m.journey:
        return None
    pieces, parts, sites = [], [], {}
    start = 0.0
    for name in m.journey:
        tract = tracts[name]
        pieces += [(p.organ, p.points_m) for p in tract.centreline.pieces]
        parts.append({"tract": name, "organ": tract.organ, "start_m": start, "length_m": tract.centreline.length_m})
        for mark, s in tract.landmarks_s_m.items():
            sites[f"{name}_{mark}"] = start + s
        start += tract.centreline.length_m
    line = Centreline(pieces, field="manifest.journey")
    for name in m.journey:  # their points are the journey's pieces now: not kept twice
        phantom.centrelines.pop(name, None)
    phantom.centrelines[GI_TRACT] = line
    journey = {"centreline": GI_TRACT, "length_m": line.length_m, "parts": parts, "sites_s_m": sites}
    phantom.metadata["journey"] = journey
    return journey


def _manifest_field(field_: Field | None, fields: dict[str, Field], m: BuildManifest) -> Field:
    """The manifest entry a phantom check's field (``organs.<name>``, ``sites.<name>``) is about."""
    if field_ is None:
        return "manifest"
    if isinstance(field_, str) and field_.startswith("organs."):
        name = field_.split(".", 1)[1]
        if m.body is not None and name == m.body.name:
            return ("manifest", "body", "surface")
        return fields.get(name, ("manifest", "organs", name))
    if isinstance(field_, str) and field_.startswith("sites."):
        return ("manifest", "sensors", field_.split(".", 1)[1])
    return field_


def _inset(mesh: trimesh.Trimesh, distance_m: float) -> trimesh.Trimesh:
    moved = mesh.copy()
    moved.vertices = mesh.vertices - distance_m * mesh.vertex_normals
    return moved


def _check_inside_body(organs: dict[str, trimesh.Trimesh], body: trimesh.Trimesh, fields: dict[str, Field],
                       body_name: str, options: Options, crossing: set[int] | None = None) -> None:
    """An organ may graze the body surface (clipped later), but not cross it deeper than the tolerance.
    ``crossing``: the organs (by position) whose surfaces cross the body's, when known: every other one lies
    wholly inside or wholly outside the body, which one vertex tells."""
    from raytrace.body.anatomy.grid import SurfaceDistance

    distance = None
    for k, (name, mesh) in enumerate(organs.items()):
        if crossing is not None and k not in crossing and body.contains(mesh.vertices[:1]).all():
            continue
        outside = ~body.contains(mesh.vertices)
        if not outside.any():
            continue
        distance = distance or SurfaceDistance(body.vertices, body.faces, 1e-3)
        depth = float(distance(mesh.vertices[outside]).max())
        if depth > options.overlap_tolerance_m:
            where = np.round(mesh.vertices[outside].mean(axis=0) * 1e3, 1).tolist()
            raise _fail(f"organ {name!r} crosses the body surface ({body_name!r}): it reaches {depth * 1e3:.3g} mm "
                        f"outside it around {where} mm, more than overlap_tolerance_m = "
                        f"{options.overlap_tolerance_m * 1e3:g} mm", fields[name])


def _sensor_positions(m: BuildManifest, body: trimesh.Trimesh | None) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    if body is not None:
        for i, belt in enumerate(m.belts):
            out.update(belt_positions(body, belt, i))
    to_m, _ = _to_metres(m)
    for name, point in m.sensors.items():
        if name in out:
            raise _fail(f"sensor {name!r} is also the name of a belt's sensor", ("manifest", "sensors", "points", name))
        out[name] = to_m(np.asarray(point, float)[None, :])[0]
    return out


def _check_sensors(phantom: Phantom, sensors: dict[str, np.ndarray], m: BuildManifest) -> list[dict]:
    out = []
    for name in sensors:
        site = phantom.sites[name]
        if site.medium == "air":
            where = ("manifest", "sensors", "points", name) if name in m.sensors else ("manifest", "sensors", "belts")
            raise _fail(f"sensor {name!r} at {np.round(site.position_m * 1e3, 1).tolist()} mm lies outside the body "
                        "(in air): a contact sensor lies in the skin", where)
        out.append({"name": name, "position_mm": (site.position_m * 1e3).round(2).tolist(), "medium": site.medium})
    return out


def _layer_report(name, material, depth_m, thickness_m, mesh, layer=None) -> dict:
    row = {"name": name, "medium": material.label, "depth_mm": depth_m * 1e3,
           "thickness_mm": None if thickness_m is None else thickness_m * 1e3, "triangles": int(len(mesh.faces)),
           "volume_ml": float(mesh.volume) * 1e6}
    if layer is not None:
        row.update({"decimation_error_mm": layer.decimation_error_m * 1e3,
                    "thinnest_depth_mm": layer.thinnest_depth_m * 1e3,
                    "gives_way_percent": layer.gives_way_fraction * 100})
    return row


def _report(m, phantom, organ_notes, organ_source, body_notes, layers, tracts, sensors, plan, timings) -> dict:
    organs = []
    for i, organ in enumerate(phantom.organs):
        parent = int(phantom.parent[i])
        organs.append({
            "name": organ.name, "medium": organ.material.label, "triangles": int(len(organ.mesh.faces)),
            "volume_ml": float(phantom.volumes_m3[i]) * 1e6, "area_cm2": float(phantom.areas_m2[i]) * 1e4,
            "parent": "air" if parent == AIR_INDEX else phantom.organs[parent].name,
            "source": organ_source.get(organ.name, "generated" if organ.name != (m.body.name if m.body else None)
                                       else ", ".join(m.body.files) or f"label {m.body.label}"),
            "repairs": organ_notes.get(organ.name, body_notes if m.body and organ.name == m.body.name else []) or [],
        })
    return {
        "name": m.name, "triangles": phantom.triangle_count, "units": m.units, "scale_m_per_unit": m.scale,
        "frame": "x = subject's left, y = posterior (-y anterior), z = up",
        "transform": {"axes": [("-" if s < 0 else "") + "xyz"[a] for a, s in m.axes], "origin": list(m.origin)},
        "bounds_mm": (phantom.bounds_m * 1e3).round(1).tolist(),
        "organs": organs, "layers": layers, "tracts": tracts, "sensors": sensors,
        "sites": sorted(phantom.sites), "plan": plan, "timings_s": {k: round(v, 2) for k, v in timings.items()},
        "options": {k: getattr(m.options, k) for k in m.options.__dataclass_fields__},
    }


def markdown_report(report: dict) -> str:
    """The build report as Markdown (docs/phantoms.md shows the worked example's)."""
    lines = [f"# Build report: {report['name']}", "",
             f"{report['triangles']} triangles; bounds {report['bounds_mm']} mm ({report['frame']}); "
             f"transform axes {report['transform']['axes']}, origin {report['transform']['origin']} (file units), "
             f"scale {report['scale_m_per_unit']:g} m per unit.", "",
             "| organ | medium | parent | triangles | volume (mL) | area (cm²) |", "|---|---|---|---:|---:|---:|"]
    for o in report["organs"]:
        lines.append(f"| {o['name']} | {o['medium']} | {o['parent']} | {o['triangles']} | {o['volume_ml']:.1f} | "
                     f"{o['area_cm2']:.1f} |")
    lines += ["", "Repairs and sources:", ""]
    for o in report["organs"]:
        lines.append(f"- **{o['name']}** ({o['source']}): " + ("; ".join(o["repairs"]) or "none needed"))
    if report["layers"]:
        lines += ["", "Body wall (generated inward from the body surface):", "",
                  "| layer | medium | depth (mm) | thickness (mm) | triangles | decimation error (mm) | "
                  "thinnest depth (mm) | gives way to organs (% of its vertices) |",
                  "|---|---|---:|---:|---:|---:|---:|---:|"]
        for row in report["layers"]:
            def f(key, fmt="{:.2f}"):
                return "-" if row.get(key) is None else fmt.format(row[key])
            cells = [row["name"], row["medium"], f("depth_mm", "{:.1f}"), f("thickness_mm", "{:.1f}"),
                     str(row["triangles"]), f("decimation_error_mm", "{:.3f}"), f("thinnest_depth_mm"),
                     f("gives_way_percent", "{:.1f}")]
            lines.append("| " + " | ".join(cells) + " |")
    if report["tracts"]:
        lines += ["", "Tracts:", ""]
        for t in report["tracts"]:
            marks = ", ".join(f"{k} {v:.0f} mm" for k, v in t["landmarks_s_mm"].items())
            lines.append(f"- **{t['name']}** in {t['organ']}: {t['length_mm']:.0f} mm, {t['points']} points"
                         f"{' (reversed)' if t['reverse'] else ''}; landmarks: {marks or 'none'}"
                         + (f"; {'; '.join(t['notes'])}" if t["notes"] else ""))
    if report.get("journey"):
        j = report["journey"]
        lines += ["", f"Journey (centreline `{j['centreline']}`): {j['length_m'] * 1e3:.0f} mm through "
                  + ", ".join(f"{p['tract']} from {p['start_m'] * 1e3:.0f} mm" for p in j["parts"]) + "; sites: "
                  + (", ".join(f"{k} {v * 1e3:.0f} mm" for k, v in j["sites_s_m"].items()) or "none")]
    if report["sensors"]:
        media = sorted({s["medium"] for s in report["sensors"]})
        lines += ["", f"Sensors: {len(report['sensors'])} (media: {', '.join(media)}).", ""]
    lines += ["", "Timings (s): " + ", ".join(f"{k} {v}" for k, v in report["timings_s"].items()), ""]
    return "\n".join(lines)

