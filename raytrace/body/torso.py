"""The default torso phantom: a procedural abdomen section, embedded (no downloads).

Anatomy (``docs/tissues.md`` section 5; numbers below cite it)
------------------------------------------------------------------------
A stylised MIRD-type trunk (Cristy-Eckerman organ set as coded in Geant4
``G4MIRD*.cc`` and the DoseCalcs ``MIRDTEXTPhantom.geom``) with the two
layers MIRD phantoms lack and RF work needs: subcutaneous fat and the
abdominal muscle wall (docs/tissues.md 5.2). Organs, outside in:

===================  =========================  ==========================================
organ (medium name)  tissue                     shape
===================  =========================  ==========================================
skin                 skin_dry (IT'IS "Skin")    rounded elliptic cylinder, 2 mm shell
subcutaneous_fat     fat_average_infiltrated    17.5 mm layer
muscle_wall          muscle                     10 mm anterior/posterior, 17 mm lateral
visceral_cavity      muscle (see below)         the abdominal cavity, contains the organs
liver                liver                      ellipsoid, subject's right upper quadrant
stomach              stomach                    MIRD ellipsoid, left upper quadrant
small_intestine      small_intestine            rounded elliptic cylinder at the umbilicus
ascending_colon      colon                      MIRD ULI elliptic tube (capsule)
transverse_colon     colon                      MIRD ULI elliptic tube along x (capsule)
descending_colon     colon                      MIRD LLI elliptic tube (capsule)
left/right_kidney    kidney                     ellipsoids beside the spine
spine                bone_cortical              lumbar vertebral column, elliptic rod
left/right_lung      lung_inflated              ellipsoids (lung bases) above liver/stomach
===================  =========================  ==========================================

Visceral background: the space between the organs (mesentery, omentum,
vessels, peritoneal fluid, retroperitoneal muscle such as psoas) is filled
with ``muscle``. Wet soft tissue dominates it, and the muscle-equivalent
("2/3 muscle") liquid is the standard body-tissue simulant of implant and
SAR work, so a capsule's near field and the organ contrasts are those of a
muscle-like host. A fat-muscle mixture would lower the background
permittivity; users can study that through uploads or the ``homogeneous``
override. The psoas/paraspinal muscles are not modelled separately: the
muscle wall has a uniform 10 mm posterior thickness and the cavity behind the
kidneys and spine is the same muscle background.

Frame (right-handed, metres)
----------------------------
x = subject's left, y = posterior (so **-y is anterior**, the MIRD trunk
convention of docs/tissues.md 5.3), z = up. The origin is on the trunk axis at the
level of the small-intestine mid-plane (about the umbilicus, L3-L4; the
sensor belt is 50 mm above it): MIRD trunk z = -140 mm maps to z = 0. The modelled
section spans z = -134.5 mm (below the descending colon) to +394.5 mm (above
the lung bases); its rounded top and bottom are cuts through the body, each
with all four layers so that every surface is closed.

Dimensions (mm, docs/tissues.md)
---------------------------
* Outer skin ellipse 163 x 119: ANSUR II male mean waist breadth/depth
  326.4 / 237.8 mm halved (5.1). Skin 2 mm (MIRD skin shell 174.5 vs 172.5,
  5.2). Fat 17.5 mm (CT, L3-L4, male mean, 5.2). Muscle wall 10 mm
  anterior (rectus abdominis mean 8.08, right 10.1 mm) and 17 mm lateral
  (EO + IO + TA = 5.39 + 6.7 + 4.88 mm) (5.2). Hence cavity 126.5 x 89.5.
* Organ centres and semi-axes follow the MIRD table (5.3), moved/shrunk only
  where the MIRD shapes overlap (MIRD cuts organs by each other; here every
  organ is a separate closed surface that never touches another):
  stomach, ascending/descending colon and kidneys' depth keep their MIRD
  centres; the transverse colon is set 15 mm below the stomach; the small
  intestine is the MIRD slab (AP extent -48 ... +22 mm, 90 mm tall) narrowed
  to +-45 mm so that it lies between the colon limbs; the liver is an
  ellipsoid 136 x 100 x 130 mm instead of the plane-cut MIRD elliptic tube;
  the kidneys are 60 x 36 x 100 mm (a real kidney: ~110 x 60 x 30 mm)
  moved laterally to clear the spine; the lungs are their bases only.

Named sites
-----------
Capsule sites (kind ``capsule``) at interior points of the stomach, the
small intestine (two), and the three colon segments, each at least ~10 mm
from its organ's surface. Sensor sites (kind ``sensor``): contact sensors
taped to the body, modelled inside the 2 mm skin layer, SENSOR_DEPTH_M = 1 mm
below the faceted outer skin surface (medium ``skin``), in two rows around
the abdomen (polar angle from anterior towards the subject's left):

* ``belt_*`` at z = 50 mm (between the small intestine and the transverse
  colon): anterior 0, anterior_left 30, left 75, posterior_left 135,
  posterior 180, posterior_right 225, anterior_right 330 deg;
* ``upper_*`` at z = 125 mm (stomach level): anterior_left 30, left 75,
  posterior 180, right 285, anterior_right 330 deg.

Why in the skin and not in air: from tissue, only rays within the escape
cone of the skin/air interface (about 8 degrees from the local normal,
n_skin ~ 6.9 at 402 MHz) leave the body, and the muscle wall -> fat
interface admits only about 26 degrees. A receiver even 5 mm off the skin
is therefore in a genuine geometric-optics shadow for most capsule
positions (the field there is carried by surface/lateral waves that ray
optics does not model); a contact sensor is what WCE receiver arrays are
and what the thesis' FDTD sensors measure. Receivers in air can still be
placed anywhere through explicit positions.

Why these positions and not a uniform belt every 45 degrees: the same
critical angles leave contact positions that some capsule cannot reach by
any refraction-only path (the fat layer's 26 deg when a capsule sees the
sensor's patch of the muscle wall obliquely; the wedge behind a colon's
limb). Mapping every 15 deg at twelve heights (``tools/
torso_sensor_reachability.py``) shows the flanks (polar 90-120 and
240-270 deg) shadowed from some capsule at every height, and the anterior
wall reachable from all six capsules only in patches. Every site above has
a direct path from all six capsule sites at resolutions 48, 64 and 96 and
at 5e4 and 1e5 rays, so each is inside a reachable patch, not on its
edge. Other contact positions: :func:`contact_point`.

GI tract centreline
-------------------
``phantom.centrelines["gi_tract"]`` (:func:`gi_tract`, a
:class:`~raytrace.body.centreline.Centreline`): the capsule's way through the
stomach (fundus -> body -> antrum), the small intestine (a loop from the
subject's left upper to right lower quadrant, through both small-intestine
sites), then the ascending colon (caecum upwards), the transverse colon
(right to left) and the descending colon (downwards). Each piece is a smooth
curve (centripetal Catmull-Rom through the control points of
``_GI_CONTROL_MIRD``) that stays at least 3 mm inside its organ at every
resolution (tests/raytrace/test_centreline.py), and every capsule site lies
on it. The organs are separate closed surfaces (no duodenum, no colic
flexures), so the position jumps at the four junctions while the arc length
``s_m``, counted inside the lumens only, runs on (total 0.688 m).

Resolution
----------
``build_torso(resolution)``: ``resolution`` points around every ring and
``resolution // 2`` rings pole to pole for every organ, so triangles =
15 organs x 2 x resolution x (resolution // 2 - 1) ~ 15 resolution^2:
resolution 24 ~ 8e3, 48 (default) ~ 3.3e4, 96 ~ 1.4e5, 256 ~ 9.8e5.
Resolutions below 24 are refused: the 2 mm skin layer would be thinner than
the chord sagitta of the faceted outer surface and the layers would cross.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import trimesh

from raytrace.body.centreline import GI_TRACT, Centreline, smooth_polyline
from raytrace.body.phantom import Material, Organ, Phantom
from raytrace.body.shapes import rounded_cylinder, superquadric
from raytrace.physics.tissues import DEFAULT_FAT

__all__ = [
    "BELT_SITES",
    "UPPER_SITES",
    "DEFAULT_RESOLUTION",
    "MIN_RESOLUTION",
    "MAX_RESOLUTION",
    "SENSOR_DEPTH_M",
    "TORSO_NAME",
    "build_torso",
    "contact_point",
    "gi_tract",
    "default_torso",
    "expected_site_media",
]

TORSO_NAME = "torso"
DEFAULT_RESOLUTION = 48
MIN_RESOLUTION = 24
MAX_RESOLUTION = 320

_MM = 1e-3
#: MIRD trunk z of this model's origin (small-intestine mid-plane) [mm].
_Z0_MIRD_MM = -140.0

# --- body layers (docs/tissues.md 5.1 / 5.2), mm --------------------------------
_SKIN_A, _SKIN_B = 163.0, 119.0  # ANSUR II male mean waist breadth/2, depth/2
_SKIN_T = 2.0  # MIRD skin shell
_FAT_T = 17.5  # CT L3-L4 male mean subcutaneous fat
_MUSCLE_T_AP = 10.0  # rectus abdominis (mean 8.08, right 10.1)
_MUSCLE_T_LAT = 17.0  # external + internal oblique + transversus
_CAVITY_Z_MIRD = (-245.0, 225.0)  # cavity extent along z in MIRD trunk coordinates
_MUSCLE_T_CAP = 10.0  # top/bottom cuts: pelvic floor / diaphragm stand-ins
#: Body shells are rounded elliptic cylinders: straight side, flat cut ends,
#: rims rounded over 30 mm height and 25 % of the radius (about 30 mm at the
#: waist depth), so no sharp edge spoils the smooth normals.
_BODY_RIM = (30.0, 0.25)


@dataclass(frozen=True)
class _Spec:
    name: str
    tissue: str
    center_mird_mm: tuple[float, float, float]
    semi_axes_mm: tuple[float, float, float]
    exponent: float = 2.0  # superquadric exponent; ignored when rim is given
    axis: str = "z"
    rim: tuple[float, float] | None = None  # rounded cylinder: (rim height mm, rim fraction)


def _body_specs() -> list[_Spec]:
    z_lo, z_hi = _CAVITY_Z_MIRD
    zc = (z_lo + z_hi) / 2.0
    cav_c = (z_hi - z_lo) / 2.0
    cav_a = _SKIN_A - _SKIN_T - _FAT_T - _MUSCLE_T_LAT
    cav_b = _SKIN_B - _SKIN_T - _FAT_T - _MUSCLE_T_AP
    mus = (_SKIN_A - _SKIN_T - _FAT_T, _SKIN_B - _SKIN_T - _FAT_T, cav_c + _MUSCLE_T_CAP)
    fat = (_SKIN_A - _SKIN_T, _SKIN_B - _SKIN_T, mus[2] + _FAT_T)
    skin = (_SKIN_A, _SKIN_B, fat[2] + _SKIN_T)
    rim = _BODY_RIM
    return [
        _Spec("skin", "skin_dry", (0.0, 0.0, zc), skin, rim=rim),
        _Spec("subcutaneous_fat", DEFAULT_FAT, (0.0, 0.0, zc), fat, rim=rim),
        _Spec("muscle_wall", "muscle", (0.0, 0.0, zc), mus, rim=rim),
        _Spec("visceral_cavity", "muscle", (0.0, 0.0, zc), (cav_a, cav_b, cav_c), rim=rim),
    ]


def _organ_specs() -> list[_Spec]:
    z_lo, z_hi = _CAVITY_Z_MIRD
    zc = (z_lo + z_hi) / 2.0
    return [
        # Liver: MIRD elliptic tube 141.9 x 82 (half-height 72.1) centred at the
        # trunk axis, cut by a plane; here an ellipsoid kept to the subject's
        # right so it clears the stomach (x >= 34.7 mm) and the spine.
        _Spec("liver", "liver", (-44.0, -17.0, 20.0), (68.0, 50.0, 65.0)),
        # Stomach: MIRD ellipsoid 34.3 x 29.2 x 71.6 at (69, -39.2, 0), raised
        # 15 mm to clear the transverse colon and moved 5 mm medially and 5 mm
        # posteriorly to clear the (fat- and muscle-lined, so narrower) cavity.
        _Spec("stomach", "stomach", (64.0, -34.0, 15.0), (34.3, 29.2, 71.6)),
        # Small intestine: MIRD slab z in [-180, -80], y in [-48.6, 22]; here
        # z in [-185, -95], y in [-48, 22], |x| <= 45 (between the colon limbs).
        _Spec("small_intestine", "small_intestine", (0.0, -13.0, -140.0), (45.0, 35.0, 45.0),
              rim=(15.0, 0.35)),
        # Colon, MIRD ULI/LLI elliptic tubes as capsule-like closed solids.
        _Spec("ascending_colon", "colon", (-73.3, -23.1, -142.2), (21.6, 24.5, 43.0), 4.0),
        _Spec("transverse_colon", "colon", (0.0, -23.1, -75.0), (24.5, 13.5, 90.6), 4.0, "x"),
        _Spec("descending_colon", "colon", (78.6, -23.1, -167.9), (16.2, 20.9, 68.85), 4.0),
        # Kidneys: MIRD (+-51.8, 58.8, -22.5), 40.5 x 15.3 x 49.6; moved to
        # clear the spine and the cavity wall.
        _Spec("left_kidney", "kidney", (63.0, 46.0, -50.0), (30.0, 18.0, 50.0)),
        _Spec("right_kidney", "kidney", (-63.0, 46.0, -50.0), (30.0, 18.0, 50.0)),
        # Lumbar spine: vertebral bodies ~40 x 32 mm, the full section height.
        _Spec("spine", "bone_cortical", (0.0, 45.0, zc), (20.0, 16.0, (z_hi - z_lo) / 2.0 - 10.0),
              rim=(10.0, 0.5)),
        # Lungs: MIRD ellipsoids 40.9 x 69.8 x 205.5 at (+-73.3, 0, 76.6), upper
        # half; only their bases are in the section.
        _Spec("left_lung", "lung_inflated", (70.0, 5.0, 155.0), (40.0, 55.0, 60.0)),
        _Spec("right_lung", "lung_inflated", (-70.0, 5.0, 155.0), (40.0, 55.0, 60.0)),
    ]


def _to_model_m(point_mird_mm) -> np.ndarray:
    p = np.asarray(point_mird_mm, float).copy()
    p[..., 2] -= _Z0_MIRD_MM
    return p * _MM


# Capsule sites: organ interior points in MIRD coordinates [mm].
_CAPSULE_SITES_MIRD: dict[str, tuple[str, tuple[float, float, float]]] = {
    "stomach": ("stomach", (64.0, -34.0, 15.0)),
    "small_intestine_1": ("small_intestine", (-20.0, -25.0, -125.0)),
    "small_intestine_2": ("small_intestine", (20.0, -5.0, -155.0)),
    "ascending_colon": ("ascending_colon", (-73.3, -23.1, -142.2)),
    "transverse_colon": ("transverse_colon", (0.0, -23.1, -75.0)),
    "descending_colon": ("descending_colon", (78.6, -23.1, -167.9)),
}

# GI tract centreline: control points per organ in MIRD coordinates [mm], in the order a
# capsule passes them; each list runs through that organ's capsule site(s) (module doc).
_GI_CONTROL_MIRD: tuple[tuple[str, tuple[tuple[float, float, float], ...]], ...] = (
    ("stomach", ((64.0, -34.0, 75.0), (64.0, -34.0, 15.0), (56.0, -36.0, -30.0), (50.0, -38.0, -40.0))),
    ("small_intestine", ((30.0, -20.0, -112.0), (5.0, -32.0, -115.0), (-20.0, -25.0, -125.0),
                         (-30.0, -10.0, -138.0), (0.0, -4.0, -145.0), (20.0, -5.0, -155.0),
                         (26.0, -20.0, -165.0), (0.0, -30.0, -169.0), (-30.0, -18.0, -165.0))),
    ("ascending_colon", ((-73.3, -23.1, -178.0), (-73.3, -23.1, -142.2), (-73.3, -23.1, -104.0))),
    ("transverse_colon", ((-80.0, -23.1, -75.0), (0.0, -23.1, -75.0), (80.0, -23.1, -75.0))),
    ("descending_colon", ((78.6, -23.1, -106.0), (78.6, -23.1, -167.9), (78.6, -23.1, -226.0))),
)
#: Spacing of the smoothed centreline's vertices [m].
_GI_STEP_M = 2e-3


def gi_tract() -> Centreline:
    """The torso's GI tract centreline (module doc, "GI tract centreline"); independent of the
    mesh resolution."""
    return Centreline([(organ, smooth_polyline(_to_model_m(np.array(points)), _GI_STEP_M))
                       for organ, points in _GI_CONTROL_MIRD])


#: Depth of the (contact) sensor sites below the faceted outer skin surface [m]
#: (the skin is 2 mm thick, so the sites sit mid-skin).
SENSOR_DEPTH_M = 1e-3

#: Sensor rows: height above the small-intestine mid-plane [m] and the polar angle of each
#: site [deg] (module doc: why these).
_BELT_Z_M = 0.050
_BELT_DIRECTIONS = {
    "belt_anterior": 0.0,
    "belt_anterior_left": 30.0,
    "belt_left": 75.0,
    "belt_posterior_left": 135.0,
    "belt_posterior": 180.0,
    "belt_posterior_right": 225.0,
    "belt_anterior_right": 330.0,
}
_UPPER_Z_M = 0.125
_UPPER_DIRECTIONS = {
    "upper_anterior_left": 30.0,
    "upper_left": 75.0,
    "upper_posterior": 180.0,
    "upper_right": 285.0,
    "upper_anterior_right": 330.0,
}
#: Names of the sensor sites of each row, in polar order.
BELT_SITES = tuple(_BELT_DIRECTIONS)
UPPER_SITES = tuple(_UPPER_DIRECTIONS)


def _skin_ray(polar_deg: float, z_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The analytic outer-skin point at a polar angle and height, and its outward normal.

    ``polar_deg`` is the polar angle around the trunk axis from anterior (-y)
    towards the subject's left (+x). The skin cross-section at height z is an
    ellipse of semi-axes (a, b) along the straight side of the trunk.
    """
    skin = _body_specs()[0]
    a, b, c = (v * _MM for v in skin.semi_axes_mm)
    zc = (skin.center_mird_mm[2] - _Z0_MIRD_MM) * _MM
    if abs(z_m - zc) > c - skin.rim[0] * _MM:
        raise ValueError("sensor sites must lie beside the straight side of the skin")
    psi = np.radians(polar_deg)
    d = np.array([np.sin(psi), -np.cos(psi)])
    r = 1.0 / np.sqrt((d[0] / a) ** 2 + (d[1] / b) ** 2)
    p = r * d
    n = np.array([p[0] / a**2, p[1] / b**2])
    n /= np.linalg.norm(n)
    return np.array([p[0], p[1], z_m]), np.array([n[0], n[1], 0.0])


def _contact_point(skin_mesh: trimesh.Trimesh, polar_deg: float, z_m: float) -> np.ndarray:
    """A point SENSOR_DEPTH_M below the faceted outer skin surface, along the
    analytic normal (the facets are inscribed in the analytic ellipse, up to
    1.4 mm inside it at the coarsest resolution, so the depth is measured from
    the mesh itself: the site is mid-skin at every resolution)."""
    point, normal = _skin_ray(polar_deg, z_m)
    start = point + 0.01 * normal
    locations, _, _ = skin_mesh.ray.intersects_location(start[None, :], -normal[None, :])
    if len(locations) == 0:
        raise ValueError(f"no skin surface along the sensor normal at {polar_deg} deg")
    first = locations[np.argmin(np.linalg.norm(locations - start, axis=1))]
    return first - SENSOR_DEPTH_M * normal


def contact_point(phantom: Phantom, polar_deg: float, z_m: float) -> np.ndarray:
    """Position [m] of a contact sensor on the torso ``phantom`` (any resolution), placed like
    the sensor sites: SENSOR_DEPTH_M inside the skin at polar angle ``polar_deg`` (from
    anterior towards the subject's left) and height ``z_m``. ``ValueError`` off the straight
    side of the trunk (|z| beyond the rounded rims)."""
    skin = phantom.organs[phantom.organ_index("skin")].mesh
    return _contact_point(skin, float(polar_deg), float(z_m))


def _sites(skin_mesh: trimesh.Trimesh) -> dict[str, tuple[str, np.ndarray]]:
    sites: dict[str, tuple[str, np.ndarray]] = {}
    for name, (_, pos) in _CAPSULE_SITES_MIRD.items():
        sites[name] = ("capsule", _to_model_m(pos))
    for name, deg in _BELT_DIRECTIONS.items():
        sites[name] = ("sensor", _contact_point(skin_mesh, deg, _BELT_Z_M))
    for name, deg in _UPPER_DIRECTIONS.items():
        sites[name] = ("sensor", _contact_point(skin_mesh, deg, _UPPER_Z_M))
    return sites


def expected_site_media() -> dict[str, str]:
    """The medium (organ name or ``air``) each torso site is designed to be in."""
    out = {name: organ for name, (organ, _) in _CAPSULE_SITES_MIRD.items()}
    out.update({name: "skin" for name in (*_BELT_DIRECTIONS, *_UPPER_DIRECTIONS)})
    return out


def build_torso(resolution: int = DEFAULT_RESOLUTION) -> Phantom:
    """Build and validate the default torso at a mesh resolution (see module doc).

    ``resolution`` is the number of segments around every organ (rings pole to
    pole: ``resolution // 2``). Raises ``ValueError`` outside
    [MIN_RESOLUTION, MAX_RESOLUTION]. Validation (watertight, oriented,
    nesting, no intersections) is :meth:`Phantom.build`'s.
    """
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)):
        raise TypeError("resolution must be an int")
    if not MIN_RESOLUTION <= resolution <= MAX_RESOLUTION:
        raise ValueError(f"resolution must be in [{MIN_RESOLUTION}, {MAX_RESOLUTION}], got {resolution}")
    rings = max(resolution // 2, 8)
    organs = []
    for spec in _body_specs() + _organ_specs():
        center = _to_model_m(spec.center_mird_mm)
        semi = np.asarray(spec.semi_axes_mm) * _MM
        if spec.rim is None:
            mesh = superquadric(center, semi, spec.exponent, segments=int(resolution),
                                rings=rings, axis=spec.axis)
        else:
            mesh = rounded_cylinder(center, semi, rim_height_m=spec.rim[0] * _MM,
                                    rim_fraction=spec.rim[1], segments=int(resolution),
                                    rings=rings, axis=spec.axis)
        organs.append(Organ(spec.name, Material(tissue=spec.tissue), mesh))
    phantom = Phantom.build(
        TORSO_NAME,
        organs,
        sites=_sites(organs[0].mesh),
        description=(
            "Default procedural abdomen section: skin, subcutaneous fat, muscle wall, "
            "muscle-like visceral cavity with liver, stomach, small intestine, ascending/"
            "transverse/descending colon, kidneys, lumbar spine and lung bases "
            "(MIRD-type organ set, ANSUR II waist, CT layer thicknesses). Frame: x = "
            "subject's left, y = posterior (-y anterior), z = up, origin on the trunk axis "
            "at the small-intestine mid-plane; metres."
        ),
    )
    phantom.metadata.update({"resolution": int(resolution), "frame": "x left, y posterior, z up, m"})
    phantom.centrelines[GI_TRACT] = gi_tract()
    return phantom


def default_torso(resolution: int = DEFAULT_RESOLUTION) -> Phantom:
    """The torso, built once per process and resolution (explicit LRU cache).

    Treat the result as immutable: it is shared between callers.
    """
    return _cached_torso(int(resolution))


@functools.lru_cache(maxsize=4)
def _cached_torso(resolution: int) -> Phantom:
    return build_torso(resolution)
