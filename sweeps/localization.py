"""Per-position localization in a sweep: the extension point for position estimators.

A sweep's ranging rows give, for one capsule position and one carrier, a range (or a
path loss) to every receiver. A *localizer* turns them into a position estimate. The
sweep runs every localizer named in the spec's ``localization.methods`` once per
(position, frequency) and writes one row per (position, frequency, method) to the
localization table (``localization.parquet`` beside ``results.parquet``)::

    position_index, capsule, frequency_hz, method, estimate_x_m, estimate_y_m, estimate_z_m,
    error_m (|estimate - truth|), along_tract_error_m (s of the estimate - s of the truth,
    when the phantom has the centreline), receivers_used, note

A localizer is a function ``fn(inputs: LocalizationInputs, options: dict) -> position_m
(3,) | None`` registered under a name with :func:`register`; ``options`` are the spec
entry's other keys (validated by the localizer's own ``validate`` callable, errors
naming ``localization.methods[i].<key>``). Built-in localizers are registered at import
time by :mod:`sweeps.localizers` (``linear``, ``nonlinear``, ``rss``) when the position
estimators (``estimators.localization``) are on this tree; ``available()`` lists them.

Spec form::

    "localization": {"methods": [{"name": "<registered name>", "ranges_from": "toa_gcc", ...}]}

``ranges_from`` names the ranging column whose ``*_distance_m`` the localizer reads
(any method of the spec's ``ranging``); it is checked here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping

from raytrace.errors import InputError
from sweeps.base import LocalizationInputs, SweepSpecError, method_columns

__all__ = ["LocalizationInputs", "Localizer", "available", "register", "unregister", "validate"]


@dataclass(frozen=True)
class Localizer:
    name: str
    fn: Callable[[LocalizationInputs, dict], Any]
    validate: Callable[[dict, str], dict] | None = None
    description: str = ""


_REGISTRY: dict[str, Localizer] = {}


def register(name: str, fn: Callable[[LocalizationInputs, dict], Any], *,
             validate: Callable[[dict, str], dict] | None = None, description: str = "") -> None:
    """Make ``fn`` available to sweep specs as ``localization.methods[].name == name``."""
    _REGISTRY[name] = Localizer(name, fn, validate, description)


def unregister(name: str) -> None:
    _REGISTRY.pop(name, None)


def available() -> dict[str, Localizer]:
    _load_builtins()
    return dict(_REGISTRY)


def get(name: str) -> Localizer:
    _load_builtins()
    return _REGISTRY[name]


_builtins_loaded = False


def _load_builtins() -> None:
    global _builtins_loaded
    if not _builtins_loaded:
        _builtins_loaded = True
        from sweeps.localizers import BUILTINS  # imported when first needed: it loads the position estimators

        for name, fn, check, description in BUILTINS:
            _REGISTRY.setdefault(name, Localizer(name, fn, check, description))


def _fail(reason: str, where: str) -> InputError:
    return SweepSpecError(reason, field=where)


def validate(value: Any, ranging: Mapping, where: str = "localization") -> dict | None:
    """The normalised ``localization`` entry of a spec (None when absent)."""
    if value is None:
        return None
    if not isinstance(value, Mapping) or set(value) - {"methods"}:
        raise _fail('expected {"methods": [{"name": ..., "ranges_from": ...}, ...]}', where)
    methods = value.get("methods")
    if not isinstance(methods, list) or not methods:
        raise _fail("a non-empty list of localization methods", f"{where}.methods")
    if len(methods) > 16:
        raise _fail(f"{len(methods)} methods exceed the limit of 16", f"{where}.methods")
    registry = available()
    columns = method_columns(ranging)
    out = []
    for i, entry in enumerate(methods):
        at = f"{where}.methods[{i}]"
        if not isinstance(entry, Mapping) or "name" not in entry:
            raise _fail('expected {"name": ..., "ranges_from": ...}', at)
        name = entry["name"]
        if name not in registry:
            have = ", ".join(sorted(registry)) or "none on this installation"
            raise _fail(f"unknown localization method {name!r}; available: {have}", f"{at}.name")
        options = {k: v for k, v in entry.items() if k != "name"}
        source = options.get("ranges_from")
        if source is not None and source not in columns:
            raise _fail(f"{source!r} is not a ranging method of this sweep ({', '.join(columns) or 'none'})",
                        f"{at}.ranges_from")
        loc = registry[name]
        if loc.validate is not None:
            options = loc.validate(dict(options), at)
        out.append({"name": name, **options})
    return {"methods": out}
