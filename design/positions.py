"""Capsule positions of a design request (docs/design.md, "Capsule positions").

One of:

* ``{"along_tract": {"ds_m": 0.02, "start_m": 0, "stop_m": null, "centreline": "gi_tract"}}``: every
  ``ds_m`` along a centreline of the phantom (:meth:`raytrace.body.centreline.Centreline.sample_s`);
* ``{"sites": ["stomach", ...]}`` or ``{"sites": null}``: named capsule sites (null: every capsule site);
* ``{"positions_m": [[x, y, z], ...]}``: explicit positions.

Each position gets a label, its organ (the medium it is in) and, on a centreline, its arc length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from design.checks import mapping, number, vector
from design.errors import DesignInputError
from raytrace.body.phantom import Phantom
from raytrace.errors import InputError

#: Most capsule positions of one request.
MAX_POSITIONS = 2_000


@dataclass(frozen=True)
class Positions:
    positions_m: np.ndarray  # (P, 3)
    labels: tuple[str, ...]
    organ: tuple[str, ...]
    s_m: tuple[float | None, ...]

    def __len__(self) -> int:
        return len(self.positions_m)

    def to_dict(self) -> dict:
        return {"positions_m": self.positions_m.tolist(), "labels": list(self.labels), "organ": list(self.organ),
                "s_m": list(self.s_m)}

    @classmethod
    def from_dict(cls, d: dict) -> "Positions":
        return cls(np.asarray(d["positions_m"], float).reshape(-1, 3), tuple(d["labels"]), tuple(d["organ"]),
                   tuple(d["s_m"]))


def check_positions_spec(data, field: str = "positions") -> dict:
    """The normalised JSON form of a positions spec (no phantom needed)."""
    data = mapping(data if data is not None else {"along_tract": {}}, field, {"along_tract", "sites", "positions_m"})
    if len(data) != 1:
        raise DesignInputError("give exactly one of along_tract, sites or positions_m", field)
    if "along_tract" in data:
        at = mapping(data["along_tract"] or {}, f"{field}.along_tract", {"ds_m", "start_m", "stop_m", "centreline"})
        f = f"{field}.along_tract"
        out = {"ds_m": number(at.get("ds_m", 0.02), f"{f}.ds_m", lo=1e-3, hi=10.0),
               "start_m": number(at.get("start_m", 0.0), f"{f}.start_m", lo=0.0),
               "stop_m": None if at.get("stop_m") is None else number(at["stop_m"], f"{f}.stop_m", lo=0.0),
               "centreline": at.get("centreline", "gi_tract")}
        if not isinstance(out["centreline"], str) or not out["centreline"]:
            raise DesignInputError("must be a centreline name", f"{f}.centreline")
        return {"along_tract": out}
    if "sites" in data:
        sites = data["sites"]
        if sites is not None and (not isinstance(sites, list) or not sites
                                  or not all(isinstance(s, str) and s for s in sites)):
            raise DesignInputError("must be a non-empty list of site names, or null for every capsule site",
                                   f"{field}.sites")
        if sites is not None and len(sites) > MAX_POSITIONS:
            raise DesignInputError(f"at most {MAX_POSITIONS} positions", f"{field}.sites")
        return {"sites": sites}
    pts = data["positions_m"]
    if not isinstance(pts, list) or not pts:
        raise DesignInputError("must be a non-empty list of [x, y, z]", f"{field}.positions_m")
    if len(pts) > MAX_POSITIONS:
        raise DesignInputError(f"at most {MAX_POSITIONS} positions", f"{field}.positions_m")
    return {"positions_m": [vector(p, f"{field}.positions_m[{i}]").tolist() for i, p in enumerate(pts)]}


def resolve_positions(phantom: Phantom, spec: dict, field: str = "positions") -> Positions:
    """The positions of a normalised spec (:func:`check_positions_spec`) in ``phantom``; a
    :class:`DesignInputError` naming the field for an unknown site or centreline, a position on a
    surface or outside the phantom, or too many positions."""
    line = phantom.centrelines.get("gi_tract")
    if "along_tract" in spec:
        at = spec["along_tract"]
        f = f"{field}.along_tract"
        line = phantom.centrelines.get(at["centreline"])
        if line is None:
            have = ", ".join(sorted(phantom.centrelines)) or "none"
            raise DesignInputError(f"phantom {phantom.name!r} has no centreline {at['centreline']!r} "
                                   f"(its centrelines: {have})", f"{f}.centreline")
        stop = line.length_m if at["stop_m"] is None else at["stop_m"]
        if at["start_m"] > line.length_m or stop > line.length_m + 1e-12 or stop < at["start_m"]:
            raise DesignInputError(f"start_m and stop_m must lie in [0, {line.length_m:.4g}] m, start before stop",
                                   f"{f}.stop_m")
        count = int(np.floor((stop - at["start_m"]) / at["ds_m"] + 1e-9)) + 1
        if count > MAX_POSITIONS:
            raise DesignInputError(f"{count} positions exceed the limit of {MAX_POSITIONS}: a larger ds_m",
                                   f"{f}.ds_m")
        s = line.sample_s(at["ds_m"], at["start_m"], stop)
        pts = np.asarray(line.point_m(s), float).reshape(-1, 3)
        organs = [str(o) for o in np.atleast_1d(line.organ_at(s))]
        labels = [f"{o}@{v * 1e3:.0f}mm" for o, v in zip(organs, s)]
        s_list: list[float | None] = [float(v) for v in s]
        where = [f"{f}.ds_m"] * len(pts)
    elif "sites" in spec:
        names = spec["sites"] or [n for n, s in phantom.sites.items() if s.kind == "capsule"]
        if not names:
            raise DesignInputError(f"phantom {phantom.name!r} has no capsule sites", f"{field}.sites")
        pts, labels, where = [], [], []
        for i, n in enumerate(names):
            site = phantom.sites.get(n)
            if site is None:
                raise DesignInputError(f"phantom {phantom.name!r} has no site {n!r}", f"{field}.sites[{i}]")
            pts.append(site.position_m)
            labels.append(n)
            where.append(f"{field}.sites[{i}]")
        pts = np.asarray(pts, float)
        s_list = [None] * len(pts) if line is None else [float(v) for v in np.atleast_1d(line.project(pts))]
        organs = None
    else:
        pts = np.asarray(spec["positions_m"], float)
        labels = [f"p{i}" for i in range(len(pts))]
        where = [f"{field}.positions_m[{i}]" for i in range(len(pts))]
        s_list = [None] * len(pts) if line is None else [float(v) for v in np.atleast_1d(line.project(pts))]
        organs = None
    phantom.check_antenna_bounds(pts, where)
    try:
        medium = phantom.medium_index(pts)
        phantom.check_antenna_clearance(pts, where)
    except InputError:
        for k, p in enumerate(pts):  # name the first bad one
            phantom.antenna_medium(p, field=where[k])
        raise
    names = [phantom.medium_name(int(m)) for m in medium]
    if organs is None:
        organs = names
    return Positions(pts, tuple(labels), tuple(organs), tuple(s_list))
