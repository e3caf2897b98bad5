"""Where geometric optics stops: what a profile says about its own validity.

Two kinds of statement, both reported with every receiver profile:

1. **Electrical size** (:func:`smallest_organ`).

   Ray optics replaces each organ surface by its local tangent plane (Fresnel coefficients of
   plane waves). That holds when the first Fresnel zone of a ray, the patch of surface that
   carries its field, fits on the surface. A ray meeting an organ of width D from distances of
   the organ's own scale (d1, d2 ~ D / 2) has a first Fresnel zone of radius
   r_F = sqrt(lambda d1 d2 / (d1 + d2)) = sqrt(lambda D) / 2; it fits across the organ
   (2 r_F <= D) exactly when D >= lambda. Below one wavelength the organ scatters in the
   resonance (Mie) regime, where diffraction and creeping waves, absent from the tracer, are
   as strong as the rays themselves (docs/science.md, section 8, "Electrical size").

   An organ's width D is the middle one of its three principal extents (length >= width >=
   thickness, from the principal axes of its mesh vertices): the narrower of its surface's two
   tangent directions. A slab's width is its lateral size (a planar layer is what ray optics
   does exactly, whatever its thickness: its multiple reflections are rays), a tube's its
   diameter, a sphere's its diameter. The wavelength is the organ's own tissue's,
   c / (f Re n), at the carrier.

2. **Per-receiver regimes** (:func:`receiver_flags`): where full-wave comparisons showed
   geometric optics to be off.

   docs/validation.md ("Validity per receiver") gives the FDTD error band of each flag. When a
   receiver's strongest direct path is evaluated as the generalized-ray integral through the layers
   it crosses (dipole antennas, ``near_field`` on, layers within 40 deg of parallel:
   :mod:`raytrace.solver.stratified`), its near field, the lateral wave along the layers and the
   lossy oblique Fresnel coefficients are all in it and none of the geometric-optics flags below
   applies; it is flagged only

   * ``curved_layers``: when its layers are tilted by more than :data:`CURVED_DEG` from parallel
     (the integral assumes planar, parallel ones; on the torso within 0.7 dB of gprMax up to 19 deg
     and to 1.1 dB at 24-34 deg).

   Otherwise (geometric optics: isotropic antennas, the near-field term off, layers too far from
   parallel) a receiver is flagged (``raytrace.results.VALIDITY_FLAGS``):

   * ``near_field``: within :data:`NEAR_FIELD_WAVELENGTHS` wavelengths (in the transmitter's
     medium) of the transmitter, and its strongest direct path is not the exact dipole field
     (the near-field term is off, or the path crosses interfaces, where the term is approximate);
   * ``in_air_near_body``: in air within :data:`AIR_NEAR_BODY_M` of the body (the outermost
     organs' surfaces): GO misses the surface and lateral waves that dominate there;
   * ``grazing_exit``: its strongest direct path leaves the body into air at more than
     :data:`GRAZING_DEG` from the normal;
   * ``near_critical_angle``: its strongest direct path refracts at more than
     :data:`OBLIQUE_TISSUE_DEG` on the far side of an interface between tissues (going from
     a denser tissue into a thinner one, e.g. muscle into fat, whose critical cone is 26.6 deg
     from the normal in the muscle: 35 deg in the fat is 16 deg in the muscle). A layered FDTD
     of contact sensors 0-55 mm off the normal placed it: up to 32 deg in the fat GO is within
     0.6 dB of the FDTD, from 39 deg it is 1.1 dB low and 5.7 dB low at 64 deg (docs/validation.md);
   * ``no_direct_path``: no refraction-only path (a GO shadow: the field there is diffracted).
"""

from __future__ import annotations

import numpy as np

from raytrace.body.phantom import Phantom
from raytrace.physics.em import C0
from raytrace.results import Path

#: Organs narrower than this many wavelengths make a profile carry a warning (module docstring).
ELECTRICAL_SIZE_THRESHOLD_WAVELENGTHS = 1.0


def organ_width_m(phantom: Phantom, organ: int) -> float:
    """The middle principal extent of organ ``organ``'s mesh [m] (module docstring)."""
    v = np.asarray(phantom.organs[organ].mesh.vertices, float)
    centred = v - v.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    proj = centred @ axes.T
    return float(np.sort(proj.max(axis=0) - proj.min(axis=0))[1])


def smallest_organ(phantom: Phantom, n_carrier: np.ndarray, frequency_hz: float, paths: tuple[Path, ...],
                   widths: dict[int, float]) -> tuple[str | None, float | None, str | None]:
    """(organ, its width in wavelengths, warning or None) of the electrically smallest organ the
    ``paths`` cross (their segments' media, air excluded); (None, None, None) without one.

    ``n_carrier`` is the complex index of medium m at m + 1 (the media table's carrier row);
    ``widths`` caches :func:`organ_width_m` per organ across the profiles of one trace."""
    crossed = {seg.medium for p in paths for seg in p.segments}
    best: tuple[float, str] | None = None
    for name in crossed:
        if name == "air":
            continue
        i = phantom.organ_index(name)
        if i not in widths:
            widths[i] = organ_width_m(phantom, i)
        size = widths[i] * frequency_hz * float(np.real(n_carrier[i + 1])) / C0
        if best is None or size < best[0]:
            best = (size, name)
    if best is None:
        return None, None, None
    size, name = best
    warning = None
    if size < ELECTRICAL_SIZE_THRESHOLD_WAVELENGTHS:
        warning = (f"the paths cross {name}, {size:.2f} wavelengths wide at {frequency_hz:.6g} Hz: below "
                   f"{ELECTRICAL_SIZE_THRESHOLD_WAVELENGTHS:g} wavelength a ray's first Fresnel zone does not fit on "
                   "the organ, and diffraction the tracer leaves out is as strong as its rays there "
                   "(docs/science.md, section 8)")
    return name, size, warning


#: Near-field flag range, in wavelengths of the transmitter's medium.
NEAR_FIELD_WAVELENGTHS = 2.0
#: In-air flag range from the body's surface [m] (FDTD: GO 2-5 dB low within it).
AIR_NEAR_BODY_M = 0.12
#: Transmitted angle above which a refraction into air counts as a grazing exit [deg].
GRAZING_DEG = 70.0
#: Transmitted angle above which a refraction into a tissue counts as near critical [deg]
#: (module docstring: between the FDTD's 31.8 deg, GO within 0.03 dB, and 38.6 deg, 1.1 dB low).
OBLIQUE_TISSUE_DEG = 35.0
#: Tilt of the layers [deg] beyond which a path evaluated on a stack of planar layers counts as
#: crossing curved ones (module docstring; torso: 18-19 deg within 0.7 dB of gprMax, 24-34 deg to 1.1 dB).
CURVED_DEG = 20.0


def receiver_flags(phantom: Phantom, rx_m: np.ndarray, rx_medium: np.ndarray, distance_m: np.ndarray,
                   wavelength_tx_m: float, near_field: bool,
                   strongest_direct: list[tuple[bool, float, float, float] | None]) -> list[tuple[str, ...]]:
    """Flags per receiver (module docstring). ``strongest_direct[r]``: None without a direct path,
    else (straight, largest sin of its transmitted angles into tissue, the same into air, the tilt of
    its layers [deg] where its gain is the generalized-ray integral through them, else NaN)."""
    out: list[list[str]] = [[] for _ in range(len(rx_m))]
    layered = np.array([info is not None and np.isfinite(info[3]) for info in strongest_direct], bool)
    in_air = np.flatnonzero((np.asarray(rx_medium) < 0) & ~layered)
    if len(in_air):
        outer = [o.mesh for o, parent in zip(phantom.organs, phantom.parent) if parent < 0]
        dist = np.full(len(in_air), np.inf)
        for mesh in outer:
            _, d, _ = mesh.nearest.on_surface(np.asarray(rx_m)[in_air])
            dist = np.minimum(dist, d)
        for r, d in zip(in_air, dist):
            if d < AIR_NEAR_BODY_M:
                out[r].append("in_air_near_body")
    s_graze = np.sin(np.radians(GRAZING_DEG))
    s_oblique = np.sin(np.radians(OBLIQUE_TISSUE_DEG))
    for r, info in enumerate(strongest_direct):
        if info is None:
            out[r].append("no_direct_path")
            continue
        straight, sin_t, sin_exit, tilt_deg = info
        if layered[r]:
            # the layers' exact integral: near field, lateral wave and lossy obliques are in it; exact
            # when the layers are parallel, approximate on tilted (curved) ones
            if tilt_deg > CURVED_DEG:
                out[r].append("curved_layers")
            continue
        if distance_m[r] < NEAR_FIELD_WAVELENGTHS * wavelength_tx_m and not (near_field and straight):
            out[r].insert(0, "near_field")
        if sin_exit > s_graze:
            out[r].append("grazing_exit")
        if sin_t > s_oblique:
            out[r].append("near_critical_angle")
    return [tuple(f) for f in out]
