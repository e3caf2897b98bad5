"""Phantoms (built-in and uploaded) and built-in scenarios known to one app instance.

Built-ins are built once at start (:meth:`Registry.load_builtins`). Uploaded
phantoms live in :class:`service.storage.PhantomStore`; their description is
read from the stored ``meta.json`` and the phantom itself is parsed lazily
from the stored .glb on first use and kept in a small LRU cache, so uploads
survive a restart without slowing the start down.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from raytrace import SCENARIOS, Scenario
from raytrace.body import gltf, library
from raytrace.body.phantom import AIR_NAME, Phantom
from service.errors import NotFound
from service.storage import Missing, PhantomStore, is_upload_id

log = logging.getLogger("capsule_rt.registry")


def _vec(a) -> list[float]:
    return [float(x) for x in np.asarray(a, float).reshape(3)]


def describe_phantom(phantom_id: str, phantom: Phantom, *, builtin: bool) -> dict[str, Any]:
    """The :class:`service.schemas.phantoms.PhantomOut` dict of a phantom."""
    organs = []
    for i, organ in enumerate(phantom.organs):
        mat = organ.material
        parent = int(phantom.parent[i])
        organs.append(
            {
                "name": organ.name,
                "tissue": mat.tissue,
                "relative_permittivity": None if mat.tissue else float(mat.relative_permittivity),
                "conductivity_s_per_m": None if mat.tissue else float(mat.conductivity_s_per_m),
                "triangles": int(len(organ.mesh.faces)),
                "parent": AIR_NAME if parent < 0 else phantom.organs[parent].name,
                "bounds_m": [_vec(b) for b in np.asarray(organ.mesh.bounds, float)],
            }
        )
    sites = {
        name: {"kind": s.kind, "position_m": _vec(s.position_m), "medium": s.medium}
        for name, s in phantom.sites.items()
    }
    return {
        "id": phantom_id,
        "name": phantom.name,
        "description": phantom.description or "",
        "builtin": builtin,
        "triangles": phantom.triangle_count,
        "bounds_m": [_vec(b) for b in phantom.bounds_m],
        "organs": organs,
        "sites": sites,
    }


SUMMARY_KEYS = ("id", "name", "description", "builtin", "triangles", "bounds_m")


def with_site_kinds(manifest: dict, meta: dict) -> dict:
    """The stored manifest, with the kind of each site that lies in tissue made explicit from
    its description: phantoms uploaded while a kindless site in tissue was still taken as a
    capsule reload (and re-upload) with the kinds they were stored with."""
    sites = manifest.get("sites")
    if not isinstance(sites, dict):
        return manifest
    described = meta.get("sites", {})
    patched = dict(sites)
    for name, spec in sites.items():
        kindless = not isinstance(spec, dict) or spec.get("kind") is None
        known = described.get(name)
        if kindless and known and known.get("medium") != AIR_NAME:
            patched[name] = {"kind": known["kind"], "position_m": known["position_m"]}
    return {**manifest, "sites": patched} if patched != sites else manifest


@dataclass
class Registry:
    store: PhantomStore
    cache_size: int = 8
    builtins: dict[str, Phantom] = field(default_factory=dict)
    builtin_info: dict[str, dict] = field(default_factory=dict)
    scenarios: dict[str, Scenario] = field(default_factory=dict)
    _cache: "OrderedDict[str, Phantom]" = field(default_factory=OrderedDict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _glb_cache: dict[str, bytes] = field(default_factory=dict)
    ready: bool = False
    errors: list[str] = field(default_factory=list)

    # ------------------------------------------------------------ lifecycle
    def load_builtins(self, enabled: bool = True) -> None:
        """Build every built-in phantom and list the scenarios. A phantom whose factory
        fails is logged and reported in :attr:`errors` (with the scenarios that need it)
        instead of taking the whole service down."""
        self.store.init()
        if enabled:
            for pid, factory in library.builtin_phantoms().items():
                try:
                    self.add_builtin(pid, factory())
                except Exception as exc:  # a broken built-in must not stop the others
                    log.exception("built-in phantom failed to build", extra={"phantom": pid})
                    self.errors.append(f"built-in phantom {pid!r} failed to build: {exc}")
            for sid, scenario in SCENARIOS.items():
                if scenario.spec.phantom in self.builtins:
                    self.scenarios[sid] = scenario
                else:
                    self.errors.append(
                        f"scenario {sid!r} unavailable: its phantom {scenario.spec.phantom!r} is missing")
        self.ready = True

    def add_builtin(self, phantom_id: str, phantom: Phantom) -> None:
        self.builtins[phantom_id] = phantom
        self.builtin_info[phantom_id] = describe_phantom(phantom_id, phantom, builtin=True)

    # ------------------------------------------------------------ queries
    def ids(self) -> list[str]:
        return sorted(self.builtins) + self.store.ids()

    def upload_count(self) -> int:
        return len(self.store.ids())

    def info(self, phantom_id: str, field_loc: list | None = None) -> dict[str, Any]:
        if phantom_id in self.builtin_info:
            return self.builtin_info[phantom_id]
        return self._stored(phantom_id, field_loc, self.store.meta)

    def _stored(self, phantom_id: str, field_loc: list | None, read: Callable[[str], Any]) -> Any:
        """``read(phantom_id)`` of a stored upload, or 404: an unknown id, or one deleted
        between the look-up and the read (a concurrent DELETE)."""
        if is_upload_id(phantom_id):
            try:
                return read(phantom_id)
            except Missing:
                pass
        raise NotFound(self.unknown_message(phantom_id), loc=field_loc or ["path", "phantom_id"])

    def summaries(self) -> list[dict[str, Any]]:
        out = []
        for pid in self.ids():
            try:
                info = self.info(pid)
            except NotFound:  # deleted concurrently
                continue
            out.append({k: info[k] for k in SUMMARY_KEYS})
        return out

    def get(self, phantom_id: str, field_loc: list | None = None) -> Phantom:
        """The phantom (parsing a stored upload on first use)."""
        if phantom_id in self.builtins:
            return self.builtins[phantom_id]
        with self._lock:
            if phantom_id in self._cache:
                self._cache.move_to_end(phantom_id)
                return self._cache[phantom_id]
        stored = self._stored(phantom_id, field_loc, self.store.load)
        phantom = gltf.load_phantom(stored.mesh, with_site_kinds(stored.manifest, stored.meta))
        with self._lock:
            self._cache[phantom_id] = phantom
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
        return phantom

    def mesh_glb(self, phantom_id: str) -> bytes:
        if phantom_id in self.builtins:
            if phantom_id not in self._glb_cache:
                self._glb_cache[phantom_id] = gltf.export_glb(self.builtins[phantom_id])
            return self._glb_cache[phantom_id]
        return self._stored(phantom_id, None, self.store.load).mesh

    def manifest(self, phantom_id: str) -> dict:
        """The manifest that reloads :meth:`mesh_glb` through POST /v1/phantoms."""
        if phantom_id in self.builtins:
            return gltf.export_manifest(self.builtins[phantom_id])
        stored = self._stored(phantom_id, None, self.store.load)
        return with_site_kinds(stored.manifest, stored.meta)

    def remember(self, phantom_id: str, phantom: Phantom) -> None:
        """Cache a freshly uploaded phantom (saves re-parsing its .glb on first use)."""
        with self._lock:
            self._cache[phantom_id] = phantom
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)

    def forget(self, phantom_id: str) -> None:
        with self._lock:
            self._cache.pop(phantom_id, None)

    def unknown_message(self, phantom_id: str) -> str:
        known = ", ".join(self.ids()[:20]) or "none"
        return f"unknown phantom {phantom_id!r}; known phantoms: {known} (GET /v1/phantoms)"
