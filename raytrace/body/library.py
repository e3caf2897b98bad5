"""The built-in phantoms: the default torso, the CT abdomen and the planar and spherical test bodies.

``builtin_phantoms()`` maps a phantom id to a cached factory; ``get_phantom(id)``
builds (once per process) and returns one. The service lists and serves them
(``GET /v1/phantoms``); tests use the planar ones as closed-form oracles.

Planar geometries are finite boxes
----------------------------------
A :class:`~raytrace.body.phantom.Phantom` is a set of closed, nested surfaces that
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

Frame: as in the torso (:mod:`raytrace.body.torso`): metres, -y is anterior (towards
the receivers in air), z up. Every planar interface is a plane y = const
with the body on the +y side.
"""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from raytrace.body.phantom import Organ, Phantom
from raytrace.body.shapes import box, superquadric
from raytrace.body.torso import TORSO_NAME, default_torso
from raytrace.errors import NotFoundError
from raytrace.physics.materials import Material
from raytrace.physics.tissues import DEFAULT_FAT

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

#: Layer thicknesses of the layered slab (docs/tissues.md 5.2) [m]: skin (MIRD shell)
#: and subcutaneous fat (CT L3-L4 male mean); muscle fills the rest.
LAYER_SKIN_M = 0.002
LAYER_FAT_M = 0.0175

SPHERE_RADIUS_M = 0.10
SPHERE_RESOLUTION = 96


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
    """Planar skin (2 mm) / fat (17.5 mm) / muscle stack, air in front (docs/tissues.md 5.2)."""
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


def abdomen_ct() -> Phantom:
    """One real abdomen from CT through the anatomy pipeline, cached on disk (raytrace/body/abdomen.py).

    Imported when first asked for: ``python -m raytrace.body.abdomen`` (the install-time build) must be able
    to run that module as ``__main__`` without the package having imported it first."""
    from raytrace.body.abdomen import abdomen_ct as build

    return build()


_PHANTOMS: dict[str, Callable[[], Phantom]] = {
    TORSO_NAME: default_torso,
    "abdomen-ct": abdomen_ct,
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
