"""The server's request limits, declared once (docs/service.md, "Limits").

A limit an operator may lower is a :class:`~service.settings.Settings` field (``max_rays``,
``max_interactions``, ``max_receivers``, ``max_band_points``, ``max_trials``) whose hard ceiling is a
constant here. A request field bounded by one says so where it is declared: its schema bound is the
ceiling and :func:`capped` names the setting (``Field(..., le=MAX_RAYS, json_schema_extra=capped("max_rays"))``,
or the same key in a hand-written schema such as the sweep spec's). From there one object,
:class:`Limits` (``Limits.of(settings)``), feeds

* the served OpenAPI document (:meth:`Limits.lower_schema`: every capped bound, default and example
  lowered to the setting; the marker key removed),
* the one "lower or refuse" rule of a request (:func:`service.admission.lower_or_refuse`: an absent
  knob's default is lowered to the limit, a given one above it is a 422 naming the field),
* the sweep and design jobs' own limits (``service.sweep_jobs.limits_for``,
  ``service.design_jobs.limits_for``).

This module imports nothing of the project, so the request models (and the typed client) stay light.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

# Hard ceilings: the schema's bounds, and the largest value each setting may take.
MAX_RAYS = 1_000_000
MAX_INTERACTIONS = 10
MAX_RECEIVERS = 64
MAX_BAND_POINTS = 201
MAX_TRIALS = 10_000
MAX_PROFILE_PATHS = 10_000

#: The settings that lower a request bound, and each one's ceiling.
CEILINGS: Mapping[str, int] = {"max_rays": MAX_RAYS, "max_interactions": MAX_INTERACTIONS,
                               "max_receivers": MAX_RECEIVERS, "max_band_points": MAX_BAND_POINTS,
                               "max_trials": MAX_TRIALS}

#: The JSON Schema key that names the setting lowering a bound (never served: lower_schema drops it).
LIMIT_KEY = "x-capsule-rt-limit"


def capped(setting: str, **extra: Any) -> dict[str, Any]:
    """The ``json_schema_extra`` of a field whose bound (``maximum``, or ``maxItems`` for a list) the
    setting ``setting`` lowers."""
    if setting not in CEILINGS:
        raise ValueError(f"{setting!r} is not a limit setting; known: {', '.join(CEILINGS)}")
    return {LIMIT_KEY: setting, **extra}


@dataclass(frozen=True)
class Limits:
    """The request limits of one server: ``caps[setting]`` for every setting of :data:`CEILINGS`."""

    caps: Mapping[str, int]

    @classmethod
    def of(cls, settings: Any) -> "Limits":
        return cls({name: int(getattr(settings, name)) for name in CEILINGS})

    def __getitem__(self, setting: str) -> int:
        return self.caps[setting]

    def lower_schema(self, node: Any, examples: list | None = None) -> None:
        """Lower, in place, every bound of a JSON Schema marked with :data:`LIMIT_KEY` to this server's
        limit (and the property's default and the examples' values with it), and drop the marker.
        ``examples`` are instances of ``node`` found higher up (an object's example holds its
        properties' examples)."""
        if isinstance(node, list):
            for item in node:
                self.lower_schema(item)
            return
        if not isinstance(node, dict):
            return
        mine = [*(examples or []), *node.get("examples", []), *([node["example"]] if "example" in node else [])]
        mine = [e for e in mine if isinstance(e, dict)]
        for key, value in node.items():
            if key == "properties" and isinstance(value, dict):
                for prop, spec in value.items():
                    setting = spec.pop(LIMIT_KEY, None) if isinstance(spec, dict) else None
                    if setting is not None:
                        self._lower_property(spec, prop, self.caps[setting], mine)
                    self.lower_schema(spec, [e[prop] for e in mine if isinstance(e.get(prop), dict)])
            elif key not in ("examples", "example", "default"):
                self.lower_schema(value)

    @staticmethod
    def _lower_property(spec: dict, prop: str, cap: int, examples: list[dict]) -> None:
        for branch in [spec, *spec.get("anyOf", []), *spec.get("oneOf", [])]:
            for keyword in ("maximum", "maxItems"):
                if keyword in branch and branch[keyword] > cap:
                    branch[keyword] = cap
        if isinstance(spec.get("default"), int) and not isinstance(spec["default"], bool) and spec["default"] > cap:
            spec["default"] = cap
        for example in examples:
            current = example.get(prop)
            if isinstance(current, int) and not isinstance(current, bool) and current > cap:
                example[prop] = cap
            elif isinstance(current, list) and len(current) > cap:
                example[prop] = current[:cap]
