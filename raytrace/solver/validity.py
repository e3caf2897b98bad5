"""Per-receiver flags: where full-wave comparisons showed geometric optics to be off.

docs/validation.md ("Validity per receiver") gives the FDTD error band of each flag. A
receiver is flagged (``raytrace.results.VALIDITY_FLAGS``):

* ``near_field``: within :data:`NEAR_FIELD_WAVELENGTHS` wavelengths (in the transmitter's
  medium) of the transmitter, and its strongest direct path is not the exact dipole field
  (the near-field term is off, or the path crosses interfaces, where the term is approximate);
* ``in_air_near_body``: in air within :data:`AIR_NEAR_BODY_M` of the body (the outermost
  organs' surfaces): GO misses the surface and lateral waves that dominate there;
* ``grazing_exit``: its strongest direct path leaves the body into air at more than
  :data:`GRAZING_DEG` from the normal;
* ``near_critical_angle``: its strongest direct path refracts at more than :data:`GRAZING_DEG`
  on the far side of an interface between tissues (it sits near that interface's critical cone);
* ``no_direct_path``: no refraction-only path (a GO shadow: the field there is diffracted).
"""

from __future__ import annotations

import numpy as np

from raytrace.body.phantom import Phantom

#: Near-field flag range, in wavelengths of the transmitter's medium.
NEAR_FIELD_WAVELENGTHS = 2.0
#: In-air flag range from the body's surface [m] (FDTD: GO 2-5 dB low within it).
AIR_NEAR_BODY_M = 0.12
#: Transmitted angle above which a refraction counts as grazing / near critical [deg].
GRAZING_DEG = 70.0


def receiver_flags(phantom: Phantom, rx_m: np.ndarray, rx_medium: np.ndarray, distance_m: np.ndarray,
                   wavelength_tx_m: float, near_field: bool, strongest_direct: list[tuple[bool, float, float] | None]
                   ) -> list[tuple[str, ...]]:
    """Flags per receiver. ``strongest_direct[r]``: None without a direct path, else (straight,
    largest sin of its transmitted angles into tissue, the same into air)."""
    out: list[list[str]] = [[] for _ in range(len(rx_m))]
    in_air = np.flatnonzero(np.asarray(rx_medium) < 0)
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
    for r, info in enumerate(strongest_direct):
        if info is None:
            out[r].append("no_direct_path")
            continue
        straight, sin_t, sin_exit = info
        if distance_m[r] < NEAR_FIELD_WAVELENGTHS * wavelength_tx_m and not (near_field and straight):
            out[r].insert(0, "near_field")
        if sin_exit > s_graze:
            out[r].append("grazing_exit")
        if sin_t > s_graze:
            out[r].append("near_critical_angle")
    return [tuple(f) for f in out]
