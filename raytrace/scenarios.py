"""Built-in scenarios (phantom + antennas + frequency) and the phantom catalogue.

``SCENARIOS`` maps a scenario id to a :class:`Scenario`; ``builtin_phantoms()``
maps a phantom id to a cached factory. The service lists and serves both
(``GET /v1/scenarios``, ``GET /v1/phantoms``); tests use the planar ones as
closed-form oracles for the tracer.

Planar geometries are finite boxes
----------------------------------
A :class:`~raytrace.phantom.Phantom` is a set of closed, nested surfaces that
never touch, so a "half-space" is a large box and a layered stack is a set of
nested boxes whose front faces are the layer interfaces, each inner box's
lateral and back faces inset by ``_INSET_M`` (10 mm) from its parent's. The
region of interest (antennas within ~0.1 m of the origin) sees only the
front faces; the other faces are kept out of the way by distance (``_HALF_M``
= 1 m: at least ~2 m of extra path, > 30 ns later than the paths of interest
in tissue) and, in lossy tissue, by absorption (muscle at 402 MHz absorbs
about 1.65 dB/cm, so a round trip to a wall 1 m away costs over 300 dB). The
thesis slab is lossless, so its lateral walls do return weak, late echoes;
see that scenario's notes.

Frame: as in the torso (``raytrace.torso``): metres, -y is anterior (towards
the receivers in air), z up. Every planar interface is a plane y = const
with the body on the +y side.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from raytrace.errors import NotFoundError
from raytrace.paths import Antenna
from raytrace.phantom import Material, Organ, Phantom
from raytrace.shapes import box, superquadric
from raytrace.tissues import DEFAULT_FAT
from raytrace.torso import BELT_SITES, TORSO_NAME, UPPER_SITES, default_torso

__all__ = [
    "SCENARIOS",
    "Scenario",
    "builtin_phantoms",
    "get_phantom",
    "get_scenario",
    "THESIS_EPS_R",
    "THESIS_DISTANCE_M",
]

#: Average torso permittivity used by the thesis for ranging (Ch. 5).
THESIS_EPS_R = 27.9
#: Real transmitter-receiver distance of the thesis' ray-tracing case (Tables 5.1-5.3).
THESIS_DISTANCE_M = 0.076
#: Thesis slab: the Tx-Rx line lies this far from the front (y = 0) wall ...
THESIS_FRONT_DEPTH_M = 0.030
#: ... and this far from the back wall (slab thickness 0.080 m).
THESIS_BACK_DEPTH_M = 0.050

#: Half-size of the planar boxes along x and z, and the depth of their back face [m].
_HALF_M = 1.0
#: Inset of a nested box's lateral and back faces from its parent's [m].
_INSET_M = 0.010

#: Layer thicknesses of the layered slab (tissues.md 5.2) [m]: skin (MIRD shell)
#: and subcutaneous fat (CT L3-L4 male mean); muscle fills the rest.
LAYER_SKIN_M = 0.002
LAYER_FAT_M = 0.0175

SPHERE_RADIUS_M = 0.10
SPHERE_RESOLUTION = 96


@dataclass(frozen=True)
class Scenario:
    """A ready-made tracing case.

    ``transmitter`` / ``receivers`` are :class:`Antenna` objects or names of
    the phantom's sites (resolved by :meth:`resolve`). ``max_interactions``,
    ``rays`` and ``dynamic_range_db`` are suggestions that make the case show
    what it is meant to show; requests may override them.
    """

    id: str
    description: str
    phantom_id: str
    transmitter: Antenna | str
    receivers: tuple[Antenna | str, ...]
    frequency_hz: float = 402e6
    max_interactions: int = 4
    rays: int = 50_000
    dynamic_range_db: float | None = None
    notes: str = ""
    metadata: dict = field(default_factory=dict)

    def phantom(self) -> Phantom:
        """The scenario's phantom (cached: built once per process)."""
        return get_phantom(self.phantom_id)

    def resolve(self) -> tuple[Phantom, Antenna, tuple[Antenna, ...]]:
        """The phantom and the antennas, site names replaced by positioned antennas
        (named after the site, default polarization and pattern)."""
        phantom = self.phantom()

        def one(item: Antenna | str, where: str) -> Antenna:
            if isinstance(item, Antenna):
                return item
            site = phantom.sites.get(item)
            if site is None:
                raise NotFoundError(f"phantom {phantom.name!r} has no site {item!r}", field=where)
            return Antenna(position_m=np.array(site.position_m, float), name=item)

        tx = one(self.transmitter, "transmitter")
        rxs = tuple(one(r, f"receivers[{i}]") for i, r in enumerate(self.receivers))
        return phantom, tx, rxs


# ------------------------------------------------------------- phantoms
def _nested_slab(layers: list[tuple[str, Material, float]]) -> list[Organ]:
    """Nested boxes: ``layers`` = (name, material, front-face y) outermost first.

    Box k spans y in [front_k, _HALF_M - k inset], x and z in +-(_HALF_M - k inset).
    """
    organs = []
    for k, (name, material, front_y) in enumerate(layers):
        h = _HALF_M - k * _INSET_M
        organs.append(Organ(name, material, box([-h, front_y, -h], [h, h, h])))
    return organs


@functools.cache
def thesis_slab() -> Phantom:
    """Homogeneous lossless eps_r 27.9 slab in air for the thesis' Fig 5.5/5.6 case.

    The thesis text (Sec 5.4) states only: three paths (direct + two), average
    body permittivity 27.9 (v = 0.568e8 m/s), real distance 0.076 m, first TOA
    1.338 ns (Table 5.1); the figure itself is not in the text. Assumed here:
    the body is a 27.9, sigma = 0 (lossless, frequency-independent) slab
    y in [0, 0.080] m in air; transmitter and receiver lie on a line parallel
    to its faces, 0.030 m behind the front face and 0.050 m in front of the back
    face, 0.076 m apart. The two faces give the two reflected paths (image
    method: lengths sqrt(0.076^2 + (2*0.030)^2) = 0.0968 m and
    sqrt(0.076^2 + (2*0.050)^2) = 0.1256 m; incidence 51.7 and 37.2 deg, beyond
    the 10.9 deg critical angle: total internal reflection).
    """
    thickness = THESIS_FRONT_DEPTH_M + THESIS_BACK_DEPTH_M
    body = Organ(
        "body",
        Material(relative_permittivity=THESIS_EPS_R, conductivity_s_per_m=0.0),
        box([-_HALF_M, 0.0, -_HALF_M], [_HALF_M, thickness, _HALF_M]),
    )
    half = THESIS_DISTANCE_M / 2.0
    y = THESIS_FRONT_DEPTH_M
    return Phantom.build(
        "thesis-fig-5-6",
        [body],
        sites={"tx": ("capsule", [-half, y, 0.0]), "rx": ("sensor", [half, y, 0.0])},
        description=thesis_slab.__doc__.split("\n\n")[0],
    )


@functools.cache
def homogeneous_sphere() -> Phantom:
    """A 0.10 m radius sphere of muscle in air (homogeneous, lossy, dispersive).

    With the transmitter at the centre every wall reflection returns through
    the centre, so a receiver at distance s from it sees exactly two
    single-bounce paths (normal incidence): lengths 2R - s (near wall) and
    2R + s (far wall).
    """
    mesh = superquadric([0.0, 0.0, 0.0], [SPHERE_RADIUS_M] * 3, 2.0,
                        segments=SPHERE_RESOLUTION, rings=SPHERE_RESOLUTION // 2)
    direction = np.array([2.0, -1.0, 0.5]) / np.sqrt(5.25)
    return Phantom.build(
        "homogeneous-sphere",
        [Organ("sphere", Material(tissue="muscle"), mesh)],
        sites={
            "centre": ("capsule", [0.0, 0.0, 0.0]),
            "inner": ("sensor", 0.05 * direction),
            "outer": ("sensor", (SPHERE_RADIUS_M + 0.005) * direction),
        },
        description=homogeneous_sphere.__doc__.split("\n\n")[0],
    )


@functools.cache
def half_space() -> Phantom:
    """Muscle filling y > 0 (a 2 m x 1 m x 2 m box), air in front: one planar interface."""
    organs = _nested_slab([("muscle", Material(tissue="muscle"), 0.0)])
    return Phantom.build(
        "half-space",
        organs,
        sites={
            "tx": ("capsule", [0.0, 0.030, 0.0]),
            "rx_normal": ("sensor", [0.0, -0.050, 0.0]),
            "rx_oblique": ("sensor", [0.060, -0.040, 0.0]),
        },
        description=half_space.__doc__,
    )


@functools.cache
def layered_slab() -> Phantom:
    """Planar skin (2 mm) / fat (17.5 mm) / muscle stack, air in front (tissues.md 5.2)."""
    fat_front = LAYER_SKIN_M
    muscle_front = LAYER_SKIN_M + LAYER_FAT_M
    organs = _nested_slab(
        [
            ("skin", Material(tissue="skin_dry"), 0.0),
            ("fat", Material(tissue=DEFAULT_FAT), fat_front),
            ("muscle", Material(tissue="muscle"), muscle_front),
        ]
    )
    return Phantom.build(
        "layered-slab",
        organs,
        sites={
            "tx": ("capsule", [0.0, muscle_front + 0.030, 0.0]),
            "rx_normal": ("sensor", [0.0, -0.005, 0.0]),
            "rx_oblique": ("sensor", [0.040, -0.005, 0.0]),
            "rx_fat": ("sensor", [0.0, fat_front + LAYER_FAT_M / 2.0, 0.0]),
        },
        description=layered_slab.__doc__,
    )


_PHANTOMS: dict[str, Callable[[], Phantom]] = {
    TORSO_NAME: default_torso,
    "thesis-fig-5-6": thesis_slab,
    "homogeneous-sphere": homogeneous_sphere,
    "half-space": half_space,
    "layered-slab": layered_slab,
}


def builtin_phantoms() -> dict[str, Callable[[], Phantom]]:
    """Phantom id -> factory (each builds once per process, then returns the cached object)."""
    return dict(_PHANTOMS)


def get_phantom(phantom_id: str) -> Phantom:
    """A built-in phantom by id; :class:`NotFoundError` for an unknown id."""
    factory = _PHANTOMS.get(phantom_id)
    if factory is None:
        raise NotFoundError(
            f"unknown phantom {phantom_id!r}; built-in: {', '.join(_PHANTOMS)}", field="phantom"
        )
    return factory()


# ------------------------------------------------------------- scenarios
SCENARIOS: dict[str, Scenario] = {
    s.id: s
    for s in (
        Scenario(
            id="thesis-fig-5-6",
            description=(
                "Thesis Fig 5.5/5.6: homogeneous lossless eps_r 27.9 body, transmitter and "
                "receiver 0.076 m apart; direct path (TOA 1.338 ns) plus two reflections."
            ),
            phantom_id="thesis-fig-5-6",
            transmitter="tx",
            receivers=("rx",),
            frequency_hz=402e6,
            max_interactions=1,
            rays=100_000,
            dynamic_range_db=20.0,
            notes=(
                "The thesis text gives the permittivity (27.9, taken lossless: sigma = 0), the "
                "distance (0.076 m), the first TOA (1.338 ns) and 'three paths'; the geometry is "
                "assumed: a 0.080 m slab in air, Tx-Rx line 0.030 m behind its front face and "
                "parallel to it. Reflected paths: 0.0968 m (front, 2.1 dB below the direct path) "
                "and 0.1256 m (back, 4.4 dB below), both total internal reflections. The slab's "
                "lateral faces are 1 m away: with max_interactions=1 they add echoes >= 2.0 m "
                "long (>= 35 ns, >= 28 dB below the direct path); dynamic_range_db=20 keeps "
                "exactly the thesis' three paths."
            ),
            metadata={
                "expected_path_lengths_m": [
                    THESIS_DISTANCE_M,
                    float(np.hypot(THESIS_DISTANCE_M, 2 * THESIS_FRONT_DEPTH_M)),
                    float(np.hypot(THESIS_DISTANCE_M, 2 * THESIS_BACK_DEPTH_M)),
                ],
                "relative_permittivity": THESIS_EPS_R,
            },
        ),
        Scenario(
            id="homogeneous-sphere",
            description=(
                "Muscle sphere (R = 0.10 m) in air, transmitter at the centre, receivers "
                "inside (0.05 m) and outside (5 mm off the surface)."
            ),
            phantom_id="homogeneous-sphere",
            transmitter="centre",
            receivers=("inner", "outer"),
            max_interactions=2,
            notes=(
                "Oracle: direct path in a homogeneous lossy medium (delay, Friis with the "
                "complex wavenumber); from the centre every wall reflection is at normal "
                "incidence and returns through the centre, so 'inner' gets single-bounce "
                "paths of length 0.15 m and 0.25 m."
            ),
            metadata={"radius_m": SPHERE_RADIUS_M},
        ),
        Scenario(
            id="half-space",
            description=(
                "Planar muscle/air interface: transmitter 30 mm deep in muscle, receivers in "
                "air at normal and oblique incidence."
            ),
            phantom_id="half-space",
            transmitter="tx",
            receivers=("rx_normal", "rx_oblique"),
            max_interactions=2,
            notes=(
                "Oracle: Snell/Fermat refraction delay and lossy Fresnel transmission at one "
                "planar interface (y = 0). The box's other faces are >= 0.97 m of muscle away."
            ),
        ),
        Scenario(
            id="layered-slab",
            description=(
                "Planar skin 2 mm / fat 17.5 mm / muscle stack (tissues.md 5.2), transmitter "
                "30 mm deep in muscle, receivers in air 5 mm off the skin and inside the fat."
            ),
            phantom_id="layered-slab",
            transmitter="tx",
            receivers=("rx_normal", "rx_oblique", "rx_fat"),
            max_interactions=6,
            notes=(
                "Oracle: multiple reflections in the skin and fat layers with analytic delays; "
                "at normal incidence the coherent sum tends to the transfer-matrix "
                "transmission of the stack. Interfaces: y = 0 (air/skin), 0.002 (skin/fat), "
                "0.0195 m (fat/muscle)."
            ),
        ),
        Scenario(
            id="torso-small-intestine",
            description=(
                "Default torso: capsule in the small intestine (site small_intestine_1), the "
                "seven-sensor belt around the abdomen 35 mm above it."
            ),
            phantom_id=TORSO_NAME,
            transmitter="small_intestine_1",
            receivers=BELT_SITES,
        ),
        Scenario(
            id="torso-stomach",
            description=(
                "Default torso: capsule in the stomach, five sensors at stomach level and the "
                "seven-sensor belt."
            ),
            phantom_id=TORSO_NAME,
            transmitter="stomach",
            receivers=UPPER_SITES + BELT_SITES,
        ),
        Scenario(
            id="torso-descending-colon",
            description="Default torso: capsule in the descending colon, the seven-sensor belt.",
            phantom_id=TORSO_NAME,
            transmitter="descending_colon",
            receivers=BELT_SITES,
        ),
    )
}


def get_scenario(scenario_id: str) -> Scenario:
    """A built-in scenario by id; :class:`NotFoundError` for an unknown id."""
    scenario = SCENARIOS.get(scenario_id)
    if scenario is None:
        raise NotFoundError(
            f"unknown scenario {scenario_id!r}; built-in: {', '.join(SCENARIOS)}", field="scenario"
        )
    return scenario
