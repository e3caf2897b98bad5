"""A sweep placed in its phantom: every capsule position and receiver resolved, the tasks cut.

:func:`make_plan` does every check that needs the phantom before any work starts, each
error naming the spec field (``capsule_positions[2].site``, ``receivers[0].position_m``,
``capsule_positions.along_tract.ds_m``): sites exist, positions lie inside the phantom and
off every organ surface, arc lengths lie on the named centreline, no receiver sits on a
capsule position, the expanded grid stays within the limits. The plan is plain data
(:meth:`Plan.to_dict`), stored with the sweep so that a resumed sweep runs exactly the
positions of the first run, whatever happened to the phantom's code since.

Tasks are chunks of ``chunk_positions`` consecutive positions (each with every frequency
and receiver); a row's seed depends on its position, frequency and receiver indices only
(:mod:`sweeps.task`), so the chunking and the number of workers never change a number.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from raytrace.body.phantom import Phantom
from raytrace.errors import CapsuleRTError, InputError
from raytrace.solver.footprint import estimate
from raytrace.spec import MIN_SEPARATION_M, Antenna, ChannelSpec
from sweeps.spec import LIMITS, Limits, SweepSpec, SweepSpecError

__all__ = ["Plan", "check_footprint", "make_plan"]


@dataclass(frozen=True, eq=False)
class Plan:
    """Resolved positions (``positions_m`` (N, 3), ``labels``, ``s_m`` (NaN off any centreline),
    ``media``, capsule ``polarizations`` (N, 3)), receivers (``receivers``: antenna dicts with
    their names, ``receivers_m``, ``receiver_media``), ``frequencies_hz`` and the chunking."""

    phantom_id: str
    positions_m: np.ndarray
    labels: tuple[str, ...]
    s_m: np.ndarray
    media: tuple[str, ...]
    polarizations: np.ndarray
    receivers: tuple[dict, ...]
    receivers_m: np.ndarray
    receiver_media: tuple[str, ...]
    frequencies_hz: tuple[float, ...]
    chunk_positions: int
    centreline: str | None

    @property
    def n_positions(self) -> int:
        return len(self.positions_m)

    @property
    def total_traces(self) -> int:
        return self.n_positions * len(self.frequencies_hz)

    @property
    def n_tasks(self) -> int:
        return -(-self.n_positions // self.chunk_positions)

    def task_positions(self, task: int) -> range:
        start = task * self.chunk_positions
        return range(start, min(start + self.chunk_positions, self.n_positions))

    def to_dict(self) -> dict[str, Any]:
        return {
            "phantom_id": self.phantom_id,
            "positions_m": self.positions_m.tolist(),
            "labels": list(self.labels),
            "s_m": [None if np.isnan(s) else float(s) for s in self.s_m],
            "media": list(self.media),
            "polarizations": self.polarizations.tolist(),
            "receivers": [dict(r) for r in self.receivers],
            "receivers_m": self.receivers_m.tolist(),
            "receiver_media": list(self.receiver_media),
            "frequencies_hz": list(self.frequencies_hz),
            "chunk_positions": self.chunk_positions,
            "centreline": self.centreline,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Plan":
        return cls(
            phantom_id=d["phantom_id"],
            positions_m=np.array(d["positions_m"], float).reshape(-1, 3),
            labels=tuple(d["labels"]),
            s_m=np.array([np.nan if s is None else s for s in d["s_m"]], float),
            media=tuple(d["media"]),
            polarizations=np.array(d["polarizations"], float).reshape(-1, 3),
            receivers=tuple(d["receivers"]),
            receivers_m=np.array(d["receivers_m"], float).reshape(-1, 3),
            receiver_media=tuple(d["receiver_media"]),
            frequencies_hz=tuple(float(f) for f in d["frequencies_hz"]),
            chunk_positions=int(d["chunk_positions"]),
            centreline=d.get("centreline"),
        )


def _centreline(phantom: Phantom, name: str, field: str):
    line = phantom.centrelines.get(name)
    if line is None:
        have = ", ".join(sorted(phantom.centrelines)) or "none"
        raise SweepSpecError(f"phantom {phantom.name!r} has no centreline {name!r} (its centrelines: {have})",
                             field=field)
    return line


#: The footprint's largest term (raytrace.solver.footprint.Footprint.largest_field) as a sweep spec field.
_FOOTPRINT_FIELDS = {"band.points": "channel.band.points", "max_interactions": "channel.max_interactions",
                     "rays": "channel.rays", "receivers": "receivers"}


def check_footprint(spec: SweepSpec, receivers: tuple[Antenna, ...], phantom_id: str, limits: Limits) -> None:
    """Refuse a sweep one of whose traces is estimated (:func:`raytrace.solver.footprint.estimate`,
    docs/service.md "Memory and work model") to shoot more than ``limits.max_ray_segments`` segments
    (field ``channel.rays``) or to need more than ``limits.max_trace_bytes`` (the field whose term is
    largest: ``channel.band.points``, ``channel.max_interactions``, ``channel.rays`` or ``receivers``):
    the rule of a channel request, applied before any of the sweep's work."""
    if limits.max_ray_segments is None and limits.max_trace_bytes is None:
        return
    tx = Antenna(position_m=[0.0, 0.0, 0.0])  # the footprint depends on the knobs and the counts only
    for f in spec["frequencies_hz"]:
        channel = spec.channel_spec(tx, receivers, f, phantom_id)
        fp = estimate(channel)
        knobs = (f"rays {channel.rays}, max_interactions {channel.max_interactions}, dynamic_range_db "
                 f"{channel.dynamic_range_db:g}, {len(receivers)} receivers"
                 + (f", {len(channel.band.frequencies_hz)} band points" if channel.band is not None else ""))
        if limits.max_ray_segments is not None and fp.ray_segments > limits.max_ray_segments:
            raise SweepSpecError(
                f"each trace's shooting is estimated at {fp.ray_segments:.3g} ray segments ({knobs}), over the work "
                f"budget of {limits.max_ray_segments:.3g} per trace: lower channel.rays, channel.max_interactions "
                "or channel.dynamic_range_db", field="channel.rays")
        if limits.max_trace_bytes is not None and fp.peak_bytes > limits.max_trace_bytes:
            field = _FOOTPRINT_FIELDS[fp.largest_field()]
            raise SweepSpecError(
                f"each trace is estimated to need {fp.peak_bytes / 2**20:.0f} MiB ({knobs}), over the "
                f"{limits.max_trace_bytes / 2**20:.0f} MiB a trace may hold; lower {field} first (its term is the "
                "largest), or channel.rays, channel.max_interactions, channel.dynamic_range_db, receivers",
                field=field)


def make_plan(spec: SweepSpec, phantom: Phantom, phantom_id: str | None = None, limits: Limits = LIMITS) -> Plan:
    """Resolve ``spec`` against ``phantom`` (module docstring); raises :class:`SweepSpecError` or the
    raytrace input errors, with the spec field."""
    phantom_id = phantom_id or spec["phantom"]
    entries = spec["capsule_positions"]
    positions, labels, s_values, fields = [], [], [], []
    line_name: str | None = None
    if "along_tract" in entries[0]:
        a = entries[0]["along_tract"]
        where = "capsule_positions.along_tract"
        line = _centreline(phantom, a["centreline"], f"{where}.centreline")
        line_name = a["centreline"]
        stop = line.length_m if a["stop_m"] is None else a["stop_m"]
        if a["start_m"] > line.length_m or stop > line.length_m * (1 + 1e-12):
            bad = "start_m" if a["start_m"] > line.length_m else "stop_m"
            raise SweepSpecError(f"beyond the centreline's length {line.length_m:.6g} m", field=f"{where}.{bad}")
        n_float = np.floor((stop - a["start_m"]) / a["ds_m"] * (1 + 1e-12)) + 1  # inf for a subnormal ds_m
        n = int(min(n_float, limits.max_positions + 1))
        if n > limits.max_positions or n * len(spec["frequencies_hz"]) > limits.max_traces:
            raise SweepSpecError(f"{n} positions x {len(spec['frequencies_hz'])} frequencies exceed the limits "
                                 f"({limits.max_positions} positions, {limits.max_traces} traces); raise ds_m",
                                 field=f"{where}.ds_m")
        s = line.sample_s(a["ds_m"], a["start_m"], stop)
        positions = list(line.point_m(s))
        organs = line.organ_at(s)
        labels = [f"{organ}@{v * 1e3:.1f}mm" for organ, v in zip(organs, s)]
        s_values = list(s)
        fields = [f"{where}.ds_m"] * len(s)
    else:
        for i, entry in enumerate(entries):
            where = f"capsule_positions[{i}]"
            if "site" in entry:
                site = phantom.sites.get(entry["site"])
                if site is None:
                    known = ", ".join(sorted(n for n, s in phantom.sites.items() if s.kind == "capsule")) or "none"
                    raise SweepSpecError(f"phantom {phantom.name!r} has no site {entry['site']!r}; its capsule "
                                         f"sites: {known}", field=f"{where}.site")
                positions.append(np.asarray(site.position_m, float))
                labels.append(entry.get("name", entry["site"]))
                fields.append(f"{where}.site")
                s_values.append(None)
            elif "position_m" in entry:
                positions.append(np.asarray(entry["position_m"], float))
                labels.append(entry.get("name", f"p{i}"))
                fields.append(f"{where}.position_m")
                s_values.append(None)
            else:
                line = _centreline(phantom, entry["centreline"], f"{where}.centreline")
                line_name = line_name or entry["centreline"]
                if entry["s_m"] > line.length_m:
                    raise SweepSpecError(f"{entry['s_m']:g} m is beyond the centreline's length "
                                         f"{line.length_m:.6g} m", field=f"{where}.s_m")
                positions.append(line.point_m(entry["s_m"]))
                labels.append(entry.get("name", f"{line.organ_at(entry['s_m'])}@{entry['s_m'] * 1e3:.1f}mm"))
                fields.append(f"{where}.s_m")
                s_values.append(entry["s_m"])
    pos = np.array(positions, float).reshape(-1, 3)
    if line_name is None and phantom.centrelines:
        line_name = "gi_tract" if "gi_tract" in phantom.centrelines else sorted(phantom.centrelines)[0]
    line = phantom.centrelines.get(line_name) if line_name else None
    s_arr = np.array([np.nan if v is None else float(v) for v in s_values], float)
    if line is not None:
        missing = np.isnan(s_arr)
        if missing.any():
            s_arr[missing] = line.project(pos[missing])

    phantom.check_antenna_bounds(pos, fields)  # the rule of ChannelSpec.resolve and of upload sites
    # media: one lookup for all positions, then one by one to name the first bad one
    try:
        media_idx = phantom.medium_index(pos)
    except InputError:
        for k, p in enumerate(pos):
            phantom.medium_index(p[None, :], field=fields[k])
        raise
    media = tuple(phantom.medium_names(media_idx))

    pol_spec = spec["channel"]["capsule_polarization"]
    if pol_spec == "tangent":
        if line is None:
            raise SweepSpecError("\"tangent\" needs a phantom with a centreline", field="channel.capsule_polarization")
        pols = line.tangent(s_arr)
    else:
        pols = np.broadcast_to(np.asarray(pol_spec, float), pos.shape).copy()

    if spec["receivers"] == "sensors":
        rx_dicts = [{"site": n, "name": n} for n, s in phantom.sites.items() if s.kind == "sensor"]
        if not rx_dicts:
            raise SweepSpecError(f"phantom {phantom.name!r} has no sensor sites; list the receivers",
                                 field="receivers")
    else:
        rx_dicts = [dict(r) for r in spec["receivers"]]
    try:
        probe = ChannelSpec(Antenna(position_m=pos[0]), tuple(Antenna.from_dict(r) for r in rx_dicts),
                            phantom=phantom_id)
        resolved = probe.resolve(phantom)
    except CapsuleRTError as exc:
        if exc.field and exc.field.startswith("transmitter"):
            raise type(exc)(exc.reason, field=fields[0]) from None
        raise
    check_footprint(spec, probe.receivers, phantom_id, limits)
    rx_m = resolved.rx_m
    for k in range(len(pos)):
        d = np.linalg.norm(rx_m - pos[k], axis=1)
        if np.any(d < MIN_SEPARATION_M):
            r = int(np.argmax(d < MIN_SEPARATION_M))
            raise SweepSpecError(f"receiver {probe.receivers[r].name!r} is within {MIN_SEPARATION_M} m of this "
                                 "capsule position", field=fields[k])
    return Plan(
        phantom_id=phantom_id,
        positions_m=pos,
        labels=tuple(labels),
        s_m=s_arr,
        media=media,
        polarizations=np.asarray(pols, float),
        receivers=tuple(r.to_dict() | {"name": r.name} for r in probe.receivers),
        receivers_m=rx_m,
        receiver_media=tuple(phantom.medium_names(resolved.rx_medium)),
        frequencies_hz=tuple(spec["frequencies_hz"]),
        chunk_positions=spec["chunk_positions"],
        centreline=line_name if line is not None else None,
    )
