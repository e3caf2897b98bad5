"""The service's only contact points with the physics packages.

Everything the HTTP layer needs from ``raytrace`` / ``estimators`` beyond
plain data classes goes through here, so an interface change is one edit.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from raytrace.body.phantom import Phantom

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
def builtin_phantoms_and_scenarios(errors: list[str] | None = None) -> tuple[dict[str, Phantom], dict[str, ScenarioSpec]]:
    """Build every built-in phantom and list the scenarios. A phantom whose
    factory fails is logged and reported in ``errors`` (with the scenarios
    that need it) instead of taking the whole service down."""
    errors = [] if errors is None else errors
    phantoms: dict[str, Phantom] = {}
    scenarios: dict[str, ScenarioSpec] = {}
    try:
        from raytrace import scenarios as sc  # type: ignore[attr-defined]
        from raytrace.body import library
    except ImportError:
        sc = None
    if sc is not None:
        for pid, factory in library.builtin_phantoms().items():
            try:
                phantoms[pid] = factory() if callable(factory) else factory
            except Exception as exc:  # a broken built-in must not stop the others
                log.exception("built-in phantom failed to build", extra={"phantom": pid})
                errors.append(f"built-in phantom {pid!r} failed to build: {exc}")
    else:
        try:
            from raytrace.body.torso import default_torso  # type: ignore[import-not-found]

            phantoms["torso"] = default_torso()
        except ImportError:
            log.warning("no built-in phantoms available (raytrace.body.torso / raytrace.scenarios missing)")
    if sc is not None and hasattr(sc, "SCENARIOS"):
        for sid, s in dict(sc.SCENARIOS).items():
            spec = scenario_spec(sid, s)
            if spec.phantom in phantoms:
                scenarios[sid] = spec
            else:
                errors.append(f"scenario {sid!r} unavailable: its phantom {spec.phantom!r} is missing")
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
    """Parse and validate an uploaded phantom (raises PhantomValidationError / InputError naming the field)."""
    from raytrace.body.gltf import load_phantom

    kwargs: dict[str, Any] = {}
    if max_bytes is not None:
        kwargs["max_bytes"] = max_bytes
    if max_triangles is not None:
        kwargs["max_triangles"] = max_triangles
    return load_phantom(glb, manifest, **kwargs)


def export_glb(phantom: Phantom) -> bytes:
    from raytrace.body.gltf import export_glb as _export

    return _export(phantom)


def export_manifest(phantom: Phantom) -> dict:
    from raytrace.body.gltf import export_manifest as _export

    return _export(phantom)
