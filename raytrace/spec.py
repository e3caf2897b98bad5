"""What a channel computation is asked: one frozen, validated :class:`ChannelSpec`.

A spec names its phantom by id and its antennas by position or by one of the
phantom's sites, so it is small, pickles cheaply (a sweep ships thousands to
its workers) and round-trips to JSON: :meth:`ChannelSpec.to_dict` writes exactly
the body of ``POST /v1/channel`` and :meth:`ChannelSpec.from_dict` reads it.

Every rule and every default of a channel request lives here, once:

* :class:`ChannelSpec` checks what needs no phantom (types, ranges, unique
  receiver names, polarizations) when it is built;
* :meth:`ChannelSpec.resolve` checks what needs the phantom (sites exist,
  positions inside it and not on an organ surface, antennas apart) and returns
  the arrays the solver runs on (:class:`ResolvedChannel`).

Both raise :class:`~raytrace.errors.InputError` subclasses whose ``field`` is the
dotted path of the offending value in the JSON form (``receivers[2].position_m``),
which the service turns into a 422's ``loc``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any, Literal, Mapping, Sequence

import numpy as np

from raytrace.body.phantom import Phantom
from raytrace.errors import CapsuleRTError, FrequencyOutOfRangeError, InputError, InvalidGeometryError, NotFoundError
from raytrace.physics.em import C0, refractive_index
from raytrace.physics.materials import Material
from raytrace.physics.tissues import FREQUENCY_MAX_HZ, FREQUENCY_MIN_HZ

Pattern = Literal["isotropic", "dipole"]
PATTERNS: tuple[str, ...] = ("isotropic", "dipole")

#: Receivers closer than this to the transmitter are rejected [m].
MIN_SEPARATION_M = 1e-4
#: Largest dynamic range [dB]: float64 resolves amplitude ratios down to its epsilon, 2.2e-16
#: (-313 dB); a path weaker than the strongest by more cannot change any sum of their amplitudes.
MAX_DYNAMIC_RANGE_DB = 300.0


def wavelength_m(material: Material, frequency_hz: float | np.ndarray) -> np.ndarray:
    """Wavelength of a plane wave in ``material``, ``c / (f Re n)`` [m] (docs/science.md, section 8)."""
    f = np.asarray(frequency_hz, float)
    return C0 / (f * refractive_index(material.complex_relative_permittivity(f)).real)


def geometric_optics_min_frequency_hz(material: Material, size_m: float) -> float | None:
    """Lowest frequency of the tissue model's range at which the wavelength in ``material`` is no
    longer than ``size_m`` (None: not even at its highest). The wavelength falls monotonically
    with frequency in every passive medium of the model (``f Re n`` grows with f: the group
    velocity is positive), so a bisection in log f finds it to 1e-6 relative."""
    if wavelength_m(material, FREQUENCY_MAX_HZ) > size_m:
        return None
    lo, hi = math.log(FREQUENCY_MIN_HZ), math.log(FREQUENCY_MAX_HZ)
    if wavelength_m(material, FREQUENCY_MIN_HZ) <= size_m:
        return FREQUENCY_MIN_HZ
    while hi - lo > 1e-6:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if wavelength_m(material, math.exp(mid)) <= size_m else (mid, hi)
    return math.exp(hi)


def _at(prefix: str, exc: CapsuleRTError) -> CapsuleRTError:
    """The same error with its field placed under ``prefix`` (``position_m`` -> ``receivers[1].position_m``)."""
    where = f"{prefix}.{exc.field}" if exc.field else prefix
    out = type(exc).__new__(type(exc))
    out.__dict__.update(exc.__dict__)
    CapsuleRTError.__init__(out, exc.reason, where)
    return out


def _vector(value: Any, name: str) -> np.ndarray:
    if isinstance(value, (str, bytes)) or isinstance(value, bool):
        raise InvalidGeometryError("expected three numbers", field=name)
    try:
        v = np.asarray(value, dtype=float).reshape(3)
    except (TypeError, ValueError) as exc:
        raise InvalidGeometryError("expected three numbers", field=name) from exc
    if not np.isfinite(v).all():
        raise InvalidGeometryError(f"coordinates must be finite numbers, got {v.tolist()}", field=name)
    v = v.copy()
    v.flags.writeable = False
    return v


def _number(value: Any, name: str, unit: str) -> float:
    if isinstance(value, bool):
        raise InputError(f"must be a number of {unit}, got {value!r}", field=name)
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"must be a number of {unit}", field=name) from exc
    if not math.isfinite(x):
        raise InputError(f"must be finite, got {value!r}", field=name)
    return x


def _positive_int(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise InputError(f"must be a positive integer, got {value!r}", field=name)
    return int(value)


def _frequency(value: Any, name: str) -> float:
    f = _number(value, name, "hertz")
    if not FREQUENCY_MIN_HZ <= f <= FREQUENCY_MAX_HZ:
        raise FrequencyOutOfRangeError(
            f"{f:g} Hz is outside the tissue model's range {FREQUENCY_MIN_HZ:g}-{FREQUENCY_MAX_HZ:g} Hz", field=name
        )
    return f


@dataclass(frozen=True, eq=False)
class Antenna:
    """An antenna: where it is (``position_m`` or a phantom ``site``, exactly one),
    its polarization (normalised to a unit vector) and its pattern. Vectors are
    read-only float arrays; antennas compare equal when every field does.

    An isotropic antenna radiates unit field along the projection of its
    polarization onto the plane normal to the ray; a ``dipole`` also weights
    by sin(theta) from its axis (= the polarization). A receiver's response is
    the projection of the arriving field onto its polarization.
    """

    position_m: np.ndarray | None = None
    name: str = ""
    polarization: np.ndarray = (0.0, 0.0, 1.0)
    pattern: Pattern = "isotropic"
    site: str | None = None

    def __post_init__(self) -> None:
        if (self.position_m is None) == (self.site is None):
            raise InputError("give exactly one of position_m or site", field="position_m")
        if self.position_m is not None:
            object.__setattr__(self, "position_m", _vector(self.position_m, "position_m"))
        elif not isinstance(self.site, str) or not self.site:
            raise InputError(f"a site is a non-empty name, got {self.site!r}", field="site")
        pol = _vector(self.polarization, "polarization")
        largest = float(np.max(np.abs(pol)))
        if largest == 0.0:
            raise InvalidGeometryError("polarization must be a non-zero vector", field="polarization")
        pol = pol / largest  # first to unit scale: |(1e200, 1e200, 0)| overflows, |(0, 0, 1e-320)| underflows
        object.__setattr__(self, "polarization", _vector(pol / np.linalg.norm(pol), "polarization"))
        if self.pattern not in PATTERNS:
            raise InputError(f"pattern must be one of {', '.join(PATTERNS)}, got {self.pattern!r}", field="pattern")
        if not isinstance(self.name, str):
            raise InputError(f"a name is a string, got {self.name!r}", field="name")

    def _key(self) -> tuple:
        pos = None if self.position_m is None else tuple(self.position_m.tolist())
        return (pos, self.site, self.name, tuple(self.polarization.tolist()), self.pattern)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Antenna) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"site": self.site} if self.site is not None else {
            "position_m": self.position_m.tolist()}
        out["polarization"] = self.polarization.tolist()
        out["pattern"] = self.pattern
        if self.name:
            out["name"] = self.name
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Antenna":
        unknown = set(data) - {"position_m", "site", "name", "polarization", "pattern"}
        if unknown:
            raise InputError(f"unknown field(s) {', '.join(sorted(unknown))}", field=sorted(unknown)[0])
        return cls(**dict(data))


@dataclass(frozen=True, eq=False)
class Band:
    """Frequencies at which every path's gain is also evaluated: ``points`` equally spaced
    from ``start_hz`` to ``stop_hz`` (both included), or an explicit ``frequencies_hz``
    list (exactly one of the two forms). ``frequencies_hz`` always holds the values
    (a read-only array)."""

    start_hz: float | None = None
    stop_hz: float | None = None
    points: int | None = None
    frequencies_hz: np.ndarray | None = None

    def __post_init__(self) -> None:
        linear = (self.start_hz, self.stop_hz, self.points)
        if self.frequencies_hz is None:
            if any(v is None for v in linear):
                raise InputError("give start_hz, stop_hz and points, or frequencies_hz", field="start_hz")
            object.__setattr__(self, "start_hz", _frequency(self.start_hz, "start_hz"))
            object.__setattr__(self, "stop_hz", _frequency(self.stop_hz, "stop_hz"))
            object.__setattr__(self, "points", _positive_int(self.points, "points"))
            if self.points < 2:
                raise InputError("a band needs at least 2 points", field="points")
            if not self.stop_hz > self.start_hz:
                raise InputError("stop_hz must be greater than start_hz", field="stop_hz")
            values = np.linspace(self.start_hz, self.stop_hz, self.points)
        else:
            if any(v is not None for v in linear):
                raise InputError("give either start_hz, stop_hz and points, or frequencies_hz", field="frequencies_hz")
            if isinstance(self.frequencies_hz, (str, bytes)):
                raise InputError("expected a list of frequencies", field="frequencies_hz")
            try:
                values = np.array([_frequency(f, f"frequencies_hz[{i}]") for i, f in enumerate(self.frequencies_hz)])
            except TypeError as exc:
                raise InputError("expected a list of frequencies", field="frequencies_hz") from exc
            if values.size == 0:
                raise InputError("a band needs at least one frequency", field="frequencies_hz")
        values.flags.writeable = False
        object.__setattr__(self, "frequencies_hz", values)

    def _key(self) -> tuple:
        return (self.start_hz, self.stop_hz, self.points, tuple(self.frequencies_hz.tolist()))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Band) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def to_dict(self) -> dict[str, Any]:
        if self.start_hz is None:
            return {"frequencies_hz": self.frequencies_hz.tolist()}
        return {"start_hz": self.start_hz, "stop_hz": self.stop_hz, "points": self.points}


def _coerce(value: Any, cls: type, name: str):
    """``value`` as a ``cls`` (from a mapping, or already one), errors placed under ``name``."""
    if isinstance(value, cls):
        return value
    if not isinstance(value, Mapping):
        raise InputError(f"expected an object, got {type(value).__name__}", field=name)
    try:
        if hasattr(cls, "from_dict"):
            return cls.from_dict(value)
        return cls(**dict(value))
    except CapsuleRTError as exc:
        raise _at(name, exc) from None
    except TypeError as exc:  # an unknown or missing key
        raise InputError(str(exc), field=name) from None


@dataclass(frozen=True)
class ChannelSpec:
    """A channel computation: phantom, transmitter, receivers, frequency (and band),
    and the tracer's knobs. Build it from Python or :meth:`from_dict` (the JSON of
    ``POST /v1/channel``); both validate everything that needs no phantom.

    ``max_interactions`` bounds the reflections + refractions of the shot rays (the
    direct, refraction-only path is searched whatever its refractions); ``rays`` is
    the number launched from the transmitter; paths weaker than the strongest of a
    receiver by more than ``dynamic_range_db`` are dropped; ``homogeneous`` replaces
    every organ's material by one medium (the thesis' homogeneous case); ``near_field`` gives
    the refraction-only paths the Hertzian dipole's near-field terms (exact on a straight path in
    one medium, approximate through interfaces: ``raytrace/solver/field.py``, docs/validation.md).
    """

    transmitter: Antenna
    receivers: tuple[Antenna, ...]
    phantom: str = "torso"
    frequency_hz: float = 402e6
    band: Band | None = None
    max_interactions: int = 6
    rays: int = 100_000
    dynamic_range_db: float = 80.0
    homogeneous: Material | None = None
    near_field: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.phantom, str) or not self.phantom:
            raise InputError(f"a phantom id is a non-empty string, got {self.phantom!r}", field="phantom")
        object.__setattr__(self, "transmitter", _coerce(self.transmitter, Antenna, "transmitter"))
        if isinstance(self.receivers, (str, bytes, Mapping)) or not isinstance(self.receivers, Sequence):
            raise InputError("receivers must be a list of antennas", field="receivers")
        if len(self.receivers) == 0:
            raise InputError("at least one receiver is needed", field="receivers")
        rx = tuple(_coerce(r, Antenna, f"receivers[{i}]") for i, r in enumerate(self.receivers))
        names: set[str] = set()
        named = []
        for i, r in enumerate(rx):
            name = r.name or r.site or f"r{i}"
            if name in names:
                raise InputError(f"receiver name {name!r} is used twice", field=f"receivers[{i}].name")
            names.add(name)
            named.append(r if r.name == name else replace(r, name=name))
        object.__setattr__(self, "receivers", tuple(named))
        object.__setattr__(self, "frequency_hz", _frequency(self.frequency_hz, "frequency_hz"))
        if self.band is not None:
            object.__setattr__(self, "band", _coerce(self.band, Band, "band"))
        object.__setattr__(self, "max_interactions", _positive_int(self.max_interactions, "max_interactions"))
        object.__setattr__(self, "rays", _positive_int(self.rays, "rays"))
        dr = _number(self.dynamic_range_db, "dynamic_range_db", "decibels")
        if not 0.0 < dr <= MAX_DYNAMIC_RANGE_DB:
            raise InputError(f"must be in (0, {MAX_DYNAMIC_RANGE_DB:g}] dB, got {dr:g}", field="dynamic_range_db")
        object.__setattr__(self, "dynamic_range_db", dr)
        if self.homogeneous is not None:
            object.__setattr__(self, "homogeneous", _coerce(self.homogeneous, Material, "homogeneous"))
        if not isinstance(self.near_field, (bool, np.bool_)):
            raise InputError(f"must be true or false, got {self.near_field!r}", field="near_field")
        object.__setattr__(self, "near_field", bool(self.near_field))

    # ------------------------------------------------------------ JSON form
    def to_dict(self) -> dict[str, Any]:
        """The JSON body of ``POST /v1/channel`` for this spec (every field explicit)."""
        out: dict[str, Any] = {
            "phantom": self.phantom,
            "transmitter": self.transmitter.to_dict(),
            "receivers": [r.to_dict() for r in self.receivers],
            "frequency_hz": self.frequency_hz,
            "band": None if self.band is None else self.band.to_dict(),
            "max_interactions": self.max_interactions,
            "rays": self.rays,
            "dynamic_range_db": self.dynamic_range_db,
            "homogeneous": None,
            "near_field": self.near_field,
        }
        if self.homogeneous is not None:
            h = self.homogeneous
            out["homogeneous"] = {"tissue": h.tissue} if h.tissue is not None else {
                "relative_permittivity": h.relative_permittivity, "conductivity_s_per_m": h.conductivity_s_per_m}
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], base: "ChannelSpec | None" = None) -> "ChannelSpec":
        """A spec from its JSON form; keys absent (or null) take ``base``'s values, else the defaults."""
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise InputError(f"unknown field(s) {', '.join(sorted(unknown))}", field=sorted(unknown)[0])
        given = {k: v for k, v in data.items() if v is not None}
        if base is not None:
            return replace(base, **given)
        for required in ("transmitter", "receivers"):
            if required not in given:
                raise InputError("is required", field=required)
        return cls(**given)

    # ------------------------------------------------------------ against a phantom
    def resolve(self, phantom: Phantom) -> "ResolvedChannel":
        """The arrays the solver runs on, after the checks that need ``phantom``: sites
        exist, every antenna lies inside the phantom's bounding box (the phantom's one rule,
        :meth:`~raytrace.body.phantom.Phantom.check_antenna_bounds`) and not on an organ surface,
        and no receiver is within :data:`MIN_SEPARATION_M` of the transmitter."""

        def place(a: Antenna, where: str) -> np.ndarray:
            if a.site is not None:
                site = phantom.sites.get(a.site)
                if site is None:
                    known = ", ".join(sorted(phantom.sites)) or "none"
                    raise NotFoundError(f"phantom {phantom.name!r} has no site {a.site!r}; its sites: {known}",
                                        field=f"{where}.site")
                return np.asarray(site.position_m, float).copy()
            p = np.asarray(a.position_m, float)
            phantom.check_antenna_bounds(p, [f"{where}.position_m"])
            return p

        def leaf(a: Antenna, where: str) -> str:
            return f"{where}.site" if a.site is not None else f"{where}.position_m"

        tx = place(self.transmitter, "transmitter")
        rx = np.array([place(r, f"receivers[{i}]") for i, r in enumerate(self.receivers)])
        tx_medium = int(phantom.medium_index(tx[None, :], field=leaf(self.transmitter, "transmitter"))[0])
        try:
            rx_medium = np.asarray(phantom.medium_index(rx), dtype=np.int64)
        except InputError:  # one by one, so that the error names the first bad receiver
            for i, r in enumerate(rx):
                phantom.medium_index(r[None, :], field=leaf(self.receivers[i], f"receivers[{i}]"))
            raise
        phantom.check_antenna_clearance(np.vstack([tx[None, :], rx]),
                                        [leaf(self.transmitter, "transmitter")]
                                        + [leaf(r, f"receivers[{i}]") for i, r in enumerate(self.receivers)])
        self._check_geometric_optics(phantom, tx_medium)
        for i in range(len(rx)):
            if np.linalg.norm(rx[i] - tx) < MIN_SEPARATION_M:
                raise InvalidGeometryError(
                    f"receiver is within {MIN_SEPARATION_M} m of the transmitter; the channel is undefined",
                    field=leaf(self.receivers[i], f"receivers[{i}]"))
        return ResolvedChannel(
            spec=self,
            phantom=phantom,
            tx_m=tx,
            tx_medium=tx_medium,
            tx_polarization=np.array(self.transmitter.polarization),
            rx_m=rx,
            rx_medium=rx_medium,
            rx_polarization=np.array([r.polarization for r in self.receivers]),
            rx_pattern=np.array([r.pattern for r in self.receivers]),
        )

    def _check_geometric_optics(self, phantom: Phantom, tx_medium: int) -> None:
        """Ray optics needs the wavelength well below the bodies it crosses; a wavelength longer
        than the whole phantom (its size: the diagonal of its bounding box, the longest straight
        line it can hold) is a frequency where the tracer's answer means nothing (e.g.
        ``frequency_hz: 402``, MHz typed as Hz: gains of +40 dB). Organs nearer the wavelength are
        the profiles' electrical-size warnings' business, not a refusal.
        Checked in the transmitter's tissue, where every path starts, at the carrier and every band
        frequency; raises :class:`~raytrace.errors.FrequencyOutOfRangeError` naming the field and
        the valid range for this transmitter. A transmitter in air (a test scene next to a small
        body) is not checked here: its line of sight is exact at any frequency, and each profile's
        electrical size (``smallest_organ_size_wavelengths``) flags the organs its paths cross."""
        if tx_medium < 0:
            return
        lo, hi = np.asarray(phantom.bounds_m[0], float), np.asarray(phantom.bounds_m[1], float)
        size = float(np.linalg.norm(hi - lo))
        material = self.homogeneous or phantom.organs[tx_medium].material
        checks = [("frequency_hz", self.frequency_hz)]
        if self.band is not None:
            if self.band.start_hz is not None:
                checks += [("band.start_hz", self.band.start_hz), ("band.stop_hz", self.band.stop_hz)]
            else:
                checks += [(f"band.frequencies_hz[{i}]", f) for i, f in enumerate(self.band.frequencies_hz)]
        where = phantom.medium_name(tx_medium)
        for name, f in checks:
            lam = float(wavelength_m(material, f))
            if lam > size:
                f_min = geometric_optics_min_frequency_hz(material, size)
                valid = (f"no frequency up to {FREQUENCY_MAX_HZ:g} Hz is" if f_min is None else
                         f"the tracer's valid range for this transmitter is {f_min:.4g}-{FREQUENCY_MAX_HZ:g} Hz")
                raise FrequencyOutOfRangeError(
                    f"{f:g} Hz: the wavelength in the transmitter's medium ({where}) is {lam:.4g} m, longer than "
                    f"the phantom ({size:.4g} m, its bounding-box diagonal), where geometric optics does not hold; "
                    f"{valid} (the wavelength no longer than the phantom). A frequency in MHz typed as Hz?",
                    field=name)


@dataclass(frozen=True, eq=False)
class ResolvedChannel:
    """A :class:`ChannelSpec` placed in its phantom: what the solver consumes."""

    spec: ChannelSpec
    phantom: Phantom
    tx_m: np.ndarray
    tx_medium: int
    tx_polarization: np.ndarray
    rx_m: np.ndarray = field(repr=False)
    rx_medium: np.ndarray = field(repr=False)
    rx_polarization: np.ndarray = field(repr=False)
    rx_pattern: np.ndarray = field(repr=False)

    @property
    def band_frequencies_hz(self) -> np.ndarray | None:
        return None if self.spec.band is None else self.spec.band.frequencies_hz
