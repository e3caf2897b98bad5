"""Where geometric optics stops: the electrical size of the organs a profile's paths cross.

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
