"""Built-in scenarios: ready-made tracing cases on the built-in phantoms.

``SCENARIOS`` maps a scenario id to a :class:`Scenario`; the service lists
them (``GET /v1/scenarios``) and a channel request may start from one. The
phantoms themselves are in :mod:`raytrace.body.library`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from raytrace.body.library import (
    SPHERE_RADIUS_M,
    THESIS_BACK_DEPTH_M,
    THESIS_DISTANCE_M,
    THESIS_EPS_R,
    THESIS_FRONT_DEPTH_M,
)
from raytrace.body.torso import BELT_SITES, TORSO_NAME, UPPER_SITES
from raytrace.errors import NotFoundError
from raytrace.spec import Antenna, ChannelSpec

__all__ = ["SCENARIOS", "Scenario", "get_scenario"]


@dataclass(frozen=True)
class Scenario:
    """A ready-made tracing case: a :class:`ChannelSpec` on a built-in phantom, with what it
    is meant to show. Its ``max_interactions``, ``rays`` and ``dynamic_range_db`` are the
    values that make the case show it; requests may override any field."""

    id: str
    description: str
    spec: ChannelSpec
    notes: str = ""
    metadata: dict = field(default_factory=dict)


def _case(phantom: str, transmitter: str, receivers: tuple[str, ...], **knobs) -> ChannelSpec:
    """A spec with antennas at the phantom's sites (named after them); 4 interactions and
    50 000 rays unless the case says otherwise."""
    knobs = {"max_interactions": 4, "rays": 50_000, **knobs}
    return ChannelSpec(Antenna(site=transmitter), tuple(Antenna(site=r) for r in receivers), phantom=phantom, **knobs)


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
            spec=_case("thesis-fig-5-6", "tx", ("rx",), frequency_hz=402e6, max_interactions=1, rays=100_000,
                       dynamic_range_db=20.0),
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
            spec=_case("homogeneous-sphere", "centre", ("inner", "outer"), max_interactions=2),
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
            spec=_case("half-space", "tx", ("rx_normal", "rx_oblique"), max_interactions=2),
            notes=(
                "Oracle: Snell/Fermat refraction delay and lossy Fresnel transmission at one "
                "planar interface (y = 0). The box's other faces are >= 0.97 m of muscle away."
            ),
        ),
        Scenario(
            id="layered-slab",
            description=(
                "Planar skin 2 mm / fat 17.5 mm / muscle stack (docs/tissues.md 5.2), transmitter "
                "30 mm deep in muscle, receivers in air 5 mm off the skin and inside the fat."
            ),
            spec=_case("layered-slab", "tx", ("rx_normal", "rx_oblique", "rx_fat"), max_interactions=6),
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
            spec=_case(TORSO_NAME, "small_intestine_1", BELT_SITES),
        ),
        Scenario(
            id="torso-stomach",
            description=(
                "Default torso: capsule in the stomach, five sensors at stomach level and the "
                "seven-sensor belt."
            ),
            spec=_case(TORSO_NAME, "stomach", UPPER_SITES + BELT_SITES),
        ),
        Scenario(
            id="torso-descending-colon",
            description="Default torso: capsule in the descending colon, the seven-sensor belt.",
            spec=_case(TORSO_NAME, "descending_colon", BELT_SITES),
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
