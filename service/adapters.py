"""The service's only contact points with the physics packages.

Everything the HTTP layer needs from ``raytrace`` / ``estimators`` beyond
plain data classes goes through here, so an interface change is one edit.
"""

from __future__ import annotations

import io
import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from raytrace.errors import PhantomValidationError
from raytrace.phantom import Phantom

log = logging.getLogger("capsule_rt.adapters")


@dataclass(frozen=True)
class ScenarioSpec:
    """A built-in scenario as the service sees it: defaults for a channel request."""

    id: str
    description: str
    phantom: str
    frequency_hz: float | None = None
    notes: str = ""
    request: dict[str, Any] = field(default_factory=dict)  # ChannelRequest fields it supplies


# --------------------------------------------------------------- built-ins
def builtin_phantoms_and_scenarios() -> tuple[dict[str, Phantom], dict[str, ScenarioSpec]]:
    phantoms: dict[str, Phantom] = {}
    scenarios: dict[str, ScenarioSpec] = {}
    try:
        from raytrace import scenarios as sc  # type: ignore[attr-defined]
    except ImportError:
        sc = None
    if sc is not None and hasattr(sc, "builtin_phantoms"):
        for pid, factory in sc.builtin_phantoms().items():
            phantoms[pid] = factory() if callable(factory) else factory
    else:
        try:
            from raytrace.torso import default_torso  # type: ignore[import-not-found]

            phantoms["torso"] = default_torso()
        except ImportError:
            log.warning("no built-in phantoms available (raytrace.torso / raytrace.scenarios missing)")
    if sc is not None and hasattr(sc, "SCENARIOS"):
        for sid, s in dict(sc.SCENARIOS).items():
            scenarios[sid] = scenario_spec(sid, s)
    return phantoms, scenarios


def _antenna_dict(a: Any, name: str | None = None) -> dict[str, Any]:
    if isinstance(a, dict):
        return dict(a)
    if isinstance(a, str):
        out: dict[str, Any] = {"site": a}
    else:
        pos = getattr(a, "position_m", a)
        out = {"position_m": [float(x) for x in np.asarray(pos, float).reshape(3)]}
        pol = getattr(a, "polarization", None)
        if pol is not None:
            out["polarization"] = [float(x) for x in np.asarray(pol, float).reshape(3)]
        pattern = getattr(a, "pattern", None)
        if pattern is not None:
            out["pattern"] = pattern
        nm = getattr(a, "name", None)
        if nm:
            name = nm
    if name:
        out["name"] = name
    return out


def scenario_spec(sid: str, s: Any) -> ScenarioSpec:
    """Convert a ``raytrace.scenarios`` entry (object or dict) to a :class:`ScenarioSpec`."""
    get = (lambda k, d=None: s.get(k, d)) if isinstance(s, dict) else (lambda k, d=None: getattr(s, k, d))
    request: dict[str, Any] = {}
    phantom = get("phantom_id")
    if not isinstance(phantom, str):
        phantom = get("phantom")
    if not isinstance(phantom, str):
        phantom = "torso"
    tx = get("transmitter")
    if tx is not None:
        request["transmitter"] = _antenna_dict(tx)
        request["transmitter"].pop("name", None)
    rxs = get("receivers")
    if rxs is not None:
        request["receivers"] = [_antenna_dict(r) for r in rxs]
    f = get("frequency_hz")
    if f is not None:
        request["frequency_hz"] = float(f)
    band = get("band")
    if band is not None:
        request["band"] = dict(band) if isinstance(band, dict) else {
            "start_hz": float(band.start_hz), "stop_hz": float(band.stop_hz), "points": int(band.points)
        }
    for key in ("max_interactions", "rays", "dynamic_range_db"):
        v = get(key)
        if v is not None:
            request[key] = v
    homogeneous = get("homogeneous")
    if homogeneous is not None:
        request["homogeneous"] = homogeneous if isinstance(homogeneous, dict) else {
            "relative_permittivity": float(homogeneous.relative_permittivity),
            "conductivity_s_per_m": float(homogeneous.conductivity_s_per_m or 0.0),
        }
    return ScenarioSpec(
        id=sid,
        description=str(get("description", "") or ""),
        phantom=phantom,
        frequency_hz=request.get("frequency_hz"),
        notes=str(get("notes", "") or ""),
        request=request,
    )


# --------------------------------------------------------------- glTF
def load_glb(glb: bytes, manifest: dict, *, max_bytes: int | None = None, max_triangles: int | None = None) -> Phantom:
    """Parse and validate an uploaded phantom (raises PhantomValidationError / InputError)."""
    try:
        from raytrace.gltf import load_phantom  # type: ignore[import-not-found]
    except ImportError:
        return _fallback_load_glb(glb, manifest, max_triangles=max_triangles)
    kwargs: dict[str, Any] = {}
    if max_bytes is not None:
        kwargs["max_bytes"] = max_bytes
    if max_triangles is not None:
        kwargs["max_triangles"] = max_triangles
    return load_phantom(glb, manifest, **kwargs)


def export_glb(phantom: Phantom) -> bytes:
    try:
        from raytrace.gltf import export_glb as _export  # type: ignore[import-not-found]
    except ImportError:
        return _fallback_export_glb(phantom)
    return _export(phantom)


def _fallback_export_glb(phantom: Phantom) -> bytes:
    import trimesh

    scene = trimesh.Scene()
    for organ in phantom.organs:
        scene.add_geometry(organ.mesh.copy(), node_name=organ.name, geom_name=organ.name)
    return scene.export(file_type="glb")


def _fallback_load_glb(glb: bytes, manifest: dict, *, max_triangles: int | None = None) -> Phantom:
    """Minimal loader used until ``raytrace.gltf`` exists: nodes named after organs."""
    import trimesh

    from raytrace.phantom import Material, Organ

    try:
        scene = trimesh.load(io.BytesIO(glb), file_type="glb", force="scene", process=False)
    except Exception as exc:  # trimesh raises many types for broken files
        raise PhantomValidationError(f"cannot parse the .glb: {exc}", field="mesh") from exc
    scale = 1e-3 if manifest.get("units", "m") == "mm" else 1.0
    meshes: dict[str, trimesh.Trimesh] = {}
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        mesh = scene.geometry[geom_name].copy()
        mesh.apply_transform(transform)
        mesh.apply_scale(scale)
        meshes[str(node)] = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True, validate=False)
    organs_spec = manifest.get("organs", {})
    missing = sorted(set(organs_spec) - set(meshes))
    extra = sorted(set(meshes) - set(organs_spec))
    if missing:
        raise PhantomValidationError(f"manifest organ(s) {missing} have no mesh node in the .glb", field=f"manifest.organs.{missing[0]}")
    if extra:
        raise PhantomValidationError(f"mesh node(s) {extra} are not named in the manifest", field="manifest.organs")
    organs = []
    for name, spec in organs_spec.items():
        material = Material(
            tissue=spec.get("tissue"),
            relative_permittivity=spec.get("relative_permittivity"),
            conductivity_s_per_m=spec.get("conductivity_s_per_m"),
        )
        organs.append(Organ(name, material, meshes[name]))
    sites = {}
    for name, pos in manifest.get("sites", {}).items():
        sites[name] = ("capsule", [float(x) * scale for x in pos])
    phantom = Phantom.build(manifest.get("name", "uploaded"), organs, {}, description=manifest.get("description", ""), max_triangles=max_triangles)
    for name, (_, pos) in sites.items():
        idx = phantom.medium_index(np.asarray(pos)[None, :], field=f"manifest.sites.{name}")[0]
        from raytrace.phantom import Site

        phantom.sites[name] = Site(name, "sensor" if idx < 0 else "capsule", np.asarray(pos), phantom.medium_name(idx))
    return phantom
