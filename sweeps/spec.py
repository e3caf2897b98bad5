"""What a sweep asks: one validated, frozen :class:`SweepSpec` (``docs/sweeps.md``, "The spec").

One module (~520 lines) because it is the one validator of the spec format: every rule and default
of a sweep, each naming its field, in the order the format reads.

A sweep is a grid of channel computations, capsule positions x frequencies, each traced
to every receiver, then ranged by every requested method::

    {"phantom": "torso",
     "capsule_positions": [{"site": "stomach"}, {"position_m": [x, y, z]}, {"s_m": 0.25}]
                          | {"along_tract": {"ds_m": 0.01, "start_m": 0, "stop_m": null, "centreline": "gi_tract"}},
     "receivers": [{"site": "belt_anterior"}, {"name": "r2", "position_m": [...]}] | "sensors",
     "frequencies_hz": [402e6, 2.45e9],
     "channel": {"max_interactions": 4, "rays": 20000, "dynamic_range_db": 80,
                 "band": {"span_hz": 20e6, "points": 21} | {"start_hz", "stop_hz", "points"} | null,
                 "homogeneous": null | {"tissue": ...} | {"relative_permittivity", "conductivity_s_per_m"},
                 "capsule_polarization": [0, 0, 1] | "tangent", "capsule_pattern": "isotropic"},
     "ranging": {"relative_permittivity": 27.9,
                 "toa": {"methods": ["gcc", "all_peaks", "first_peak"], "snr_db": 30, "waveform": {...}},
                 "pdoa": {"methods": ["regression"], "snr_db": 30, "span_hz": 20e6, "points": 21},
                 "rss": {"model": "cm2_deep_tissue" | {"path_loss_d0_db", "exponent", "shadowing_db"},
                         "shadowing": true}},
     "localization": {"methods": [...]},
     "trials": 100, "seed": 0, "chunk_positions": 4}

Validation follows the requests' discipline: every error is a
:class:`SweepSpecError` (an :class:`~raytrace.errors.InputError`, so HTTP 422) whose
``field`` is the dotted path of the offending value (``channel.rays``,
``capsule_positions[3].s_m``, ``ranging.toa.waveform.sample_rate_hz``). The channel
settings are checked by building a :class:`~raytrace.ChannelSpec` for every frequency
(its own rules, not a copy), the ranging settings by building the estimators' waveform
and model objects. What needs the phantom (sites exist, positions inside, the
centreline) is checked when the sweep is planned (:mod:`sweeps.plan`), before any work.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from estimators.errors import EstimatorInputError
from estimators.pdoa import METHODS as PDOA_METHODS
from estimators.toa import METHODS as TOA_METHODS
from estimators.toa import make_waveform
from raytrace.body.centreline import GI_TRACT
from raytrace.errors import CapsuleRTError
from raytrace.spec import PATTERNS, Antenna, Band, ChannelSpec
from sweeps import localization
from sweeps.base import SweepSpecError, _fail, _mapping, _number, method_columns, rss_model

__all__ = [
    "LIMITS",
    "Limits",
    "PDOA_METHODS",
    "SweepSpec",
    "SweepSpecError",
    "TOA_METHODS",
    "load_spec",
    "method_columns",
]

#: Largest seed: what a JSON number holds exactly (the HTTP schema's maximum too).
MAX_SEED = 2**53 - 1


@dataclass(frozen=True)
class Limits:
    """Size limits of one sweep (the service may lower them through its settings)."""

    max_spec_bytes: int = 1 << 20
    max_positions: int = 10_000
    max_receivers: int = 64
    max_frequencies: int = 64
    max_traces: int = 100_000  # positions x frequencies
    max_rays: int = 1_000_000
    max_interactions: int = 10
    max_band_points: int = 201
    max_trials: int = 10_000
    max_chunk_positions: int = 256
    #: Work and memory caps of one trace (``raytrace.solver.footprint``: a trace whose estimate exceeds
    #: either is refused before the sweep starts, naming the spec field to lower); None: not checked.
    max_ray_segments: int | None = None
    max_trace_bytes: int | None = None


LIMITS = Limits()

_TOP = {"name", "description", "phantom", "capsule_positions", "receivers", "frequencies_hz", "channel",
        "ranging", "localization", "trials", "seed", "chunk_positions"}
#: The ChannelSpec fields a sweep's ``channel`` sets for every trace (the rest vary per trace).
_SPEC_KNOBS = ("max_interactions", "rays", "dynamic_range_db", "homogeneous", "near_field")
_CHANNEL = {"max_interactions", "rays", "dynamic_range_db", "band", "homogeneous", "near_field",
            "capsule_polarization", "capsule_pattern"}


def _list(value: Any, field: str, max_len: int, what: str) -> list:
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Sequence):
        raise _fail(f"expected a list of {what}", field)
    if not value:
        raise _fail(f"at least one {what[:-1] if what.endswith('s') else what} is needed", field)
    if len(value) > max_len:
        raise _fail(f"{len(value)} {what} exceed the limit of {max_len}", field)
    return list(value)


def _integral(value: Any) -> Any:
    """JSON Schema's ``integer`` is any number without a fractional part: ``4.0`` (or YAML's ``4.0``)
    counts as 4; a boolean or any other value is left to be refused."""
    return int(value) if type(value) is float and value.is_integer() else value


def _int(value: Any, field: str, lo: int, hi: int) -> int:
    value = _integral(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise _fail(f"must be an integer, got {value!r}", field)
    if not lo <= value <= hi:
        raise _fail(f"must be between {lo} and {hi}, got {value}", field)
    return int(value)


def _at(prefix: str, exc: CapsuleRTError | EstimatorInputError, rename: Mapping[str, str] | None = None):
    """``exc`` as a SweepSpecError under ``prefix`` (fields renamed first: ChannelSpec -> sweep names)."""
    inner = exc.field or ""
    head = inner.split(".", 1)[0].split("[", 1)[0]
    if rename and head in rename:
        inner = rename[head] + inner[len(head):]
        where = inner
    else:
        where = f"{prefix}.{inner}" if prefix and inner else (prefix or inner)
    return _fail(exc.reason, where)


# ------------------------------------------------------------------ positions
def _positions(value: Any, limits: Limits) -> tuple[dict, ...]:
    field = "capsule_positions"
    if isinstance(value, Mapping):
        along = _mapping(value, field, {"along_tract"}).get("along_tract")
        if along is None:
            raise _fail("give a list of positions or {\"along_tract\": {\"ds_m\": ...}}", field)
        along = dict(_mapping(along, f"{field}.along_tract", {"ds_m", "start_m", "stop_m", "centreline"}))
        where = f"{field}.along_tract"
        if "ds_m" not in along:
            raise _fail("required: the spacing along the tract [m]", f"{where}.ds_m")
        out = {"along_tract": {
            "ds_m": _number(along["ds_m"], f"{where}.ds_m", positive=True),
            "start_m": _number(along.get("start_m", 0.0), f"{where}.start_m", nonnegative=True),
            "stop_m": None if along.get("stop_m") is None else _number(along["stop_m"], f"{where}.stop_m",
                                                                       nonnegative=True),
            "centreline": along.get("centreline", GI_TRACT),
        }}
        a = out["along_tract"]
        if a["stop_m"] is not None and a["stop_m"] < a["start_m"]:
            raise _fail("must not be less than start_m", f"{where}.stop_m")
        if not isinstance(a["centreline"], str) or not a["centreline"]:
            raise _fail("a centreline name is a non-empty string", f"{where}.centreline")
        return (out,)
    items = _list(value, field, limits.max_positions, "positions")
    out = []
    for i, item in enumerate(items):
        where = f"{field}[{i}]"
        item = _mapping(item, where, {"site", "position_m", "s_m", "name", "centreline"})
        kinds = [k for k in ("site", "position_m", "s_m") if k in item]
        if len(kinds) != 1:
            raise _fail("give exactly one of site, position_m or s_m", where)
        kind = kinds[0]
        entry: dict[str, Any] = {}
        if kind == "site":
            if not isinstance(item["site"], str) or not item["site"]:
                raise _fail(f"a site is a non-empty name, got {item['site']!r}", f"{where}.site")
            entry["site"] = item["site"]
        elif kind == "position_m":
            try:
                entry["position_m"] = Antenna(position_m=item["position_m"]).position_m.tolist()
            except CapsuleRTError as exc:
                raise _fail(exc.reason, f"{where}.position_m") from None
        else:
            entry["s_m"] = _number(item["s_m"], f"{where}.s_m", nonnegative=True)
            entry["centreline"] = item.get("centreline", GI_TRACT)
            if not isinstance(entry["centreline"], str) or not entry["centreline"]:
                raise _fail("a centreline name is a non-empty string", f"{where}.centreline")
        if "centreline" in item and kind != "s_m":
            raise _fail("only a position given by s_m names a centreline", f"{where}.centreline")
        if "name" in item:
            name = item["name"]
            if not isinstance(name, str) or not 0 < len(name) <= 64:
                raise _fail("a name is a string of 1-64 characters", f"{where}.name")
            entry["name"] = name
        out.append(entry)
    return tuple(out)


# ------------------------------------------------------------------ channel
def _band(value: Any, field: str, limits: Limits) -> dict | None:
    """A band (``{span_hz, points}`` around each carrier, or a :class:`~raytrace.spec.Band`'s fields), its
    ``points`` checked against ``limits.max_band_points`` before any frequency is allocated."""
    if value is None:
        return None
    value = _mapping(value, field)
    if "points" in value:  # bounded before Band's linspace allocates them (1e11 points: 745 GiB)
        _int(value["points"], f"{field}.points", 2, limits.max_band_points)
    if "span_hz" in value:
        value = _mapping(value, field, {"span_hz", "points"})
        if "points" not in value:
            raise _fail("required with span_hz", f"{field}.points")
        return {"span_hz": _number(value["span_hz"], f"{field}.span_hz", positive=True),
                "points": value["points"]}
    frequencies = value.get("frequencies_hz")
    if isinstance(frequencies, Sequence) and not isinstance(frequencies, (str, bytes)) \
            and len(frequencies) > limits.max_band_points:
        raise _fail(f"{len(frequencies)} band points exceed the limit of {limits.max_band_points}",
                    f"{field}.frequencies_hz")
    try:
        return Band(**dict(value)).to_dict()
    except CapsuleRTError as exc:
        raise _at(field, exc) from None
    except TypeError as exc:
        raise _fail(str(exc), field) from None


def carrier_band(band: dict | None, frequency_hz: float) -> Band | dict | None:
    """The ChannelSpec band of a carrier: a ``span_hz`` band is centred on it."""
    if band is None:
        return None
    if "span_hz" in band:
        half = band["span_hz"] / 2.0
        return {"start_hz": frequency_hz - half, "stop_hz": frequency_hz + half, "points": band["points"]}
    return band


# ------------------------------------------------------------------ ranging
def _methods(value: Any, field: str, allowed: Sequence[str]) -> tuple[str, ...]:
    items = _list(value, field, len(allowed), "methods")
    for i, m in enumerate(items):
        if m not in allowed:
            raise _fail(f"unknown method {m!r} ({' | '.join(allowed)})", f"{field}[{i}]")
    if len(set(items)) != len(items):
        raise _fail("a method is listed twice", field)
    return tuple(items)


def _snr(value: Any, field: str) -> float | None:
    if value is None:
        return None
    snr = _number(value, field)
    if not -50.0 <= snr <= 200.0:
        raise _fail(f"must lie in [-50, 200] dB, got {snr:g}", field)
    return snr


def _ranging(value: Any, frequencies: tuple[float, ...], limits: Limits) -> dict:
    field = "ranging"
    value = _mapping({} if value is None else value, field, {"relative_permittivity", "toa", "pdoa", "rss"})
    out: dict[str, Any] = {}
    eps = _number(value.get("relative_permittivity", 27.9), f"{field}.relative_permittivity")
    if eps < 1.0:
        raise _fail(f"must be >= 1 (v = c / sqrt(eps_r) cannot exceed c), got {eps:g}",
                    f"{field}.relative_permittivity")
    out["relative_permittivity"] = eps
    if value.get("toa") is not None:
        where = f"{field}.toa"
        toa = _mapping(value["toa"], where, {"methods", "snr_db", "waveform"})
        waveform = dict(_mapping(toa.get("waveform", {}), f"{where}.waveform"))
        if "carrier_hz" in waveform:
            raise _fail("the carrier is each of frequencies_hz; leave carrier_hz out", f"{where}.waveform.carrier_hz")
        methods = _methods(toa.get("methods", ["gcc"]), f"{where}.methods", TOA_METHODS)
        for i, f in enumerate(frequencies):  # the estimators' own checks (Nyquist, peak sampling) per carrier
            try:
                wf = make_waveform({**waveform, "carrier_hz": f})
            except (EstimatorInputError, TypeError) as exc:
                if isinstance(exc, TypeError):
                    raise _fail(str(exc), f"{where}.waveform") from None
                raise _at(where, exc) from None
            if set(methods) & {"first_peak", "all_peaks"} and wf.sample_rate_hz < 4.0 * f:
                raise _fail(f"peak methods need sample_rate_hz >= 4 x carrier ({4 * f:.6g} Hz for "
                            f"frequencies_hz[{i}])", f"{where}.waveform.sample_rate_hz")
        out["toa"] = {"methods": list(methods), "snr_db": _snr(toa.get("snr_db", 30.0), f"{where}.snr_db"),
                      "waveform": waveform}
    if value.get("pdoa") is not None:
        where = f"{field}.pdoa"
        pdoa = _mapping(value["pdoa"], where, {"methods", "snr_db", "span_hz", "points", "duration_s"})
        methods = _methods(pdoa.get("methods", ["two_tone"]), f"{where}.methods", PDOA_METHODS)
        span = _number(pdoa.get("span_hz", 20e6), f"{where}.span_hz", positive=True)
        points = _int(pdoa.get("points", 21 if "regression" in methods else 2), f"{where}.points", 2,
                      limits.max_band_points)
        if "regression" in methods and points < 3:
            raise _fail("the regression needs at least 3 tones", f"{where}.points")
        for f in frequencies:
            if span / 2.0 >= f:
                raise _fail(f"a span of {span:g} Hz around {f:g} Hz reaches zero frequency", f"{where}.span_hz")
        out["pdoa"] = {"methods": list(methods), "snr_db": _snr(pdoa.get("snr_db", 30.0), f"{where}.snr_db"),
                       "span_hz": span, "points": points,
                       "duration_s": None if pdoa.get("duration_s") is None else _number(
                           pdoa["duration_s"], f"{where}.duration_s", positive=True)}
    if value.get("rss") is not None:
        where = f"{field}.rss"
        rss = _mapping(value["rss"], where, {"model", "shadowing"})
        model = rss.get("model", "cm2_deep_tissue")
        rss_model(model, f"{where}.model")
        shadowing = rss.get("shadowing", True)
        if not isinstance(shadowing, bool):
            raise _fail(f"must be true or false, got {shadowing!r}", f"{where}.shadowing")
        out["rss"] = {"model": copy.deepcopy(model), "shadowing": shadowing}
    return out


# ------------------------------------------------------------------ the spec
@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep (module docstring). Build with :meth:`from_dict` or :func:`load_spec`;
    :meth:`to_dict` is its normalised JSON form (every default explicit), which
    :meth:`from_dict` reads back to an equal spec; :attr:`sha256` identifies it."""

    data: Mapping[str, Any]

    @classmethod
    def from_dict(cls, data: Any, limits: Limits = LIMITS) -> "SweepSpec":
        data = _mapping(data, "", _TOP)
        out: dict[str, Any] = {}
        name = data.get("name", "")
        if not isinstance(name, str) or len(name) > 128:
            raise _fail("a name is a string of at most 128 characters", "name")
        description = data.get("description", "")
        if not isinstance(description, str) or len(description) > 4000:
            raise _fail("a description is a string of at most 4000 characters", "description")
        out["name"], out["description"] = name, description
        phantom = data.get("phantom", "torso")
        if not isinstance(phantom, str) or not phantom:
            raise _fail(f"a phantom id is a non-empty string, got {phantom!r}", "phantom")
        out["phantom"] = phantom
        if "capsule_positions" not in data:
            raise _fail("required: where the capsule is (sites, positions, s_m or along_tract)", "capsule_positions")
        out["capsule_positions"] = [dict(p) for p in _positions(data["capsule_positions"], limits)]
        receivers = data.get("receivers", "sensors")
        if receivers == "sensors":
            out["receivers"] = "sensors"
        else:
            items = _list(receivers, "receivers", limits.max_receivers, "receivers")
            try:
                probe = ChannelSpec(Antenna(site="_"), tuple(items))  # ChannelSpec's own antenna rules
            except CapsuleRTError as exc:
                raise _at("", exc) from None
            out["receivers"] = [r.to_dict() for r in probe.receivers]
        freqs = _list(data.get("frequencies_hz", [402e6]), "frequencies_hz", limits.max_frequencies, "frequencies")
        freqs = [_number(f, f"frequencies_hz[{i}]", positive=True) for i, f in enumerate(freqs)]
        if len(set(freqs)) != len(freqs):
            raise _fail("a frequency is listed twice", "frequencies_hz")
        out["frequencies_hz"] = freqs

        channel = dict(_mapping(data.get("channel", {}) or {}, "channel", _CHANNEL))
        band = _band(channel.pop("band", None), "channel.band", limits)
        polarization = channel.pop("capsule_polarization", [0.0, 0.0, 1.0])
        pattern = channel.pop("capsule_pattern", "isotropic")
        if pattern not in PATTERNS:
            raise _fail(f"must be one of {', '.join(PATTERNS)}, got {pattern!r}", "channel.capsule_pattern")
        if polarization != "tangent":
            try:
                polarization = Antenna(site="_", polarization=polarization).polarization.tolist()
            except CapsuleRTError as exc:
                raise _fail(exc.reason + " (or \"tangent\": along the centreline)", "channel.capsule_polarization") \
                    from None
        knobs = {k: v for k, v in channel.items() if v is not None}
        rename = {"frequency_hz": "frequencies_hz", "band": "channel.band", "rays": "channel.rays",
                  "max_interactions": "channel.max_interactions", "dynamic_range_db": "channel.dynamic_range_db",
                  "homogeneous": "channel.homogeneous", "near_field": "channel.near_field"}
        probe_rx = tuple(Antenna(site="_rx") for _ in range(1)) if out["receivers"] == "sensors" else \
            tuple(Antenna.from_dict(r) for r in out["receivers"])
        for i, f in enumerate(freqs):  # one ChannelSpec per carrier: ChannelSpec's own rules
            try:
                spec = ChannelSpec(Antenna(site="_", polarization=[0, 0, 1], pattern=pattern), probe_rx,
                                   frequency_hz=f, band=carrier_band(band, f), **knobs)
            except CapsuleRTError as exc:
                err = _at("channel", exc, rename)
                if err.field == "frequencies_hz":
                    err = _fail(err.reason, f"frequencies_hz[{i}]")
                elif err.field.startswith("channel.band") and band is not None and "span_hz" in band:
                    err = _fail(f"{err.reason} (the band around frequencies_hz[{i}] = {f:g} Hz)", "channel.band")
                raise err from None
            except TypeError as exc:
                raise _fail(str(exc), "channel") from None
        # unset knobs are at most the limits (as the service's channel requests); set ones are refused above
        lowered = {key: cap for key, cap in (("rays", limits.max_rays), ("max_interactions", limits.max_interactions))
                   if key not in knobs and getattr(spec, key) > cap}
        if lowered:
            spec = dataclasses.replace(spec, **lowered)
        if spec.rays > limits.max_rays:
            raise _fail(f"{spec.rays} exceeds the limit of {limits.max_rays}", "channel.rays")
        if spec.max_interactions > limits.max_interactions:
            raise _fail(f"{spec.max_interactions} exceeds the limit of {limits.max_interactions}",
                        "channel.max_interactions")
        if spec.band is not None and len(spec.band.frequencies_hz) > limits.max_band_points:
            raise _fail(f"{len(spec.band.frequencies_hz)} band points exceed the limit of {limits.max_band_points}",
                        "channel.band")
        ch = {k: v for k, v in spec.to_dict().items() if k in _SPEC_KNOBS}
        ch.update(band=band, capsule_polarization=polarization, capsule_pattern=pattern)
        out["channel"] = ch

        out["ranging"] = _ranging(data.get("ranging"), tuple(freqs), limits)
        out["localization"] = localization.validate(data.get("localization"), out["ranging"], "localization")
        out["trials"] = _int(data.get("trials", min(100, limits.max_trials)), "trials", 1, limits.max_trials)
        seed = _integral(data.get("seed", 0))
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
            got = f"an integer of {len(str(abs(seed)))} digits" if isinstance(seed, int) and abs(seed) > 10**20 \
                else repr(seed)[:100]
            raise _fail(f"must be an integer in [0, 2^53 - 1] (a JSON number holds integers exactly up to 2^53), "
                        f"got {got}", "seed")
        out["seed"] = int(seed)
        out["chunk_positions"] = _int(data.get("chunk_positions", 4), "chunk_positions", 1,
                                      limits.max_chunk_positions)
        n_listed = len(out["capsule_positions"]) if "along_tract" not in out["capsule_positions"][0] else 0
        if n_listed * len(freqs) > limits.max_traces:
            raise _fail(f"{n_listed} positions x {len(freqs)} frequencies exceed the limit of {limits.max_traces} "
                        "traces", "capsule_positions")
        return cls(json.loads(json.dumps(out)))

    # ------------------------------------------------------------ accessors
    def __getitem__(self, key: str) -> Any:
        return self.data[key]

    def to_dict(self) -> dict[str, Any]:
        return copy.deepcopy(dict(self.data))

    @property
    def sha256(self) -> str:
        return hashlib.sha256(json.dumps(self.data, sort_keys=True).encode()).hexdigest()

    @property
    def methods(self) -> list[str]:
        return method_columns(self.data["ranging"])

    def channel_spec(self, transmitter: Antenna, receivers: tuple[Antenna, ...], frequency_hz: float,
                     phantom_id: str) -> ChannelSpec:
        """The ChannelSpec of one trace of this sweep."""
        ch = self.data["channel"]
        knobs = {k: ch[k] for k in _SPEC_KNOBS if k in ch}  # specs stored before a knob existed lack it
        return ChannelSpec(transmitter, receivers, phantom=phantom_id, frequency_hz=frequency_hz,
                           band=carrier_band(ch["band"], frequency_hz), **knobs)


def load_spec(source: str | Path | Mapping, limits: Limits = LIMITS) -> SweepSpec:
    """A spec from a mapping, a ``.json`` / ``.yaml`` / ``.yml`` file, or a built-in spec's name
    (``sweeps.experiments.builtin_specs``)."""
    if isinstance(source, Mapping):
        return SweepSpec.from_dict(source, limits)
    path = Path(source)
    if not path.exists():
        from sweeps.experiments import builtin_spec_path

        builtin = builtin_spec_path(str(source))
        if builtin is None:
            raise _fail(f"no file {str(source)!r} and no built-in spec of that name "
                        "(`capsule-rt sweep --list`)", "spec")
        path = builtin
    size = path.stat().st_size
    if size > limits.max_spec_bytes:
        raise _fail(f"{size} bytes exceed the limit of {limits.max_spec_bytes}", "spec")
    return SweepSpec.from_dict(parse_text(path.read_text(), path.suffix), limits)


def parse_text(text: str, suffix: str = ".yaml") -> Any:
    """The object of a JSON or YAML text (YAML's safe loader: plain data only)."""
    if suffix == ".json":
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            raise _fail(f"not valid JSON: {exc}", "spec") from None
    import re

    import yaml

    class Loader(yaml.SafeLoader):
        """YAML 1.1 reads ``402e6`` (no dot) as a string; numbers are what a sweep author means.
        The pure-Python loader, not libyaml's (``CSafeLoader``, 3.7 times faster on a 1 MB spec):
        libyaml's composer recurses in C, and a body of 100 000 nested ``[`` overflowed a worker
        thread's stack and killed the process (tests/service/test_sweeps_api.py); Python's
        recursion limit turns the same body into a 400."""

    Loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^[-+]?(?:[0-9][0-9_]*)?(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
        list("-+0123456789."))
    try:
        data = yaml.load(text, Loader=Loader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise _fail(f"not valid YAML: {exc}", "spec") from None
    except ValueError as exc:  # an integer of more digits than Python converts (sys.get_int_max_str_digits)
        raise _fail(f"not valid YAML for a spec: {str(exc)[:200]}", "spec") from None
    _check_expanded_size(data)
    return data


#: Values a spec may hold once YAML's aliases are expanded: what JSON of ``Limits.max_spec_bytes``
#: can hold (each value takes at least two bytes, ``0,``).
MAX_SPEC_VALUES = LIMITS.max_spec_bytes // 2


def _check_expanded_size(data: Any) -> None:
    """Refuse a YAML document whose aliases expand it past :data:`MAX_SPEC_VALUES` values (ten
    nested lists of ten aliases are 1e10 values in a few hundred bytes: validating, copying or
    quoting them in an error would not end). Counts shared values once per reference, stops at the cap."""
    count, stack = 0, [data]
    while stack:
        value = stack.pop()
        count += 1
        if count > MAX_SPEC_VALUES:
            raise _fail(f"the spec expands to more than {MAX_SPEC_VALUES} values (YAML aliases repeat what "
                        "they refer to): write it out, or use fewer aliases", "spec")
        if isinstance(value, Mapping):
            stack.extend(value.keys())
            stack.extend(value.values())
        elif isinstance(value, list):
            stack.extend(value)
