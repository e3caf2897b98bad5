"""A coverage map over the skin, unrolled (docs/design.md, "Coverage").

Each sensor candidate is drawn at its polar angle around ``axis`` (through the candidates' centroid,
measured from ``reference``, the phantom frame's anterior -y by default, towards +x: the torso's
"from anterior towards the subject's left") against its height along ``axis``, coloured by its value
(SNR, received power, the fraction of capsule positions with a direct path...). Chosen sensors are
circled; the phantom's own sensor sites marked. Plain arrays in, a Figure out.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from plots.figure import new_figure


def unroll(points_m: np.ndarray, axis=(0.0, 0.0, 1.0), reference=(0.0, -1.0, 0.0),
           centre_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(polar angle [deg] in [0, 360), height [m]) of each point around ``axis`` (module docstring)."""
    p = np.asarray(points_m, float).reshape(-1, 3)
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    centre = p.mean(axis=0) if centre_m is None else np.asarray(centre_m, float)
    r = np.asarray(reference, float)
    r = r - (r @ a) * a
    r /= np.linalg.norm(r)
    q = np.cross(a, r)  # 90 degrees from the reference, right-handed about the axis
    d = p - centre
    angle = np.degrees(np.arctan2(d @ q, d @ r)) % 360.0
    return angle, p @ a


def skin_coverage(points_m, values, *, label: str = "value", axis=(0.0, 0.0, 1.0), chosen_m=None, sites_m=None,
                  title: str = "", width_in: float = 9.0, height_in: float = 4.5, cmap: str = "viridis") -> Figure:
    """The unrolled map (module docstring). ``chosen_m``: sensors to circle; ``sites_m``: sites to mark."""
    pts = np.asarray(points_m, float).reshape(-1, 3)
    v = np.asarray(values, float)
    centre = pts.mean(axis=0)
    ang, h = unroll(pts, axis, centre_m=centre)
    fig = new_figure(width_in, height_in)
    ax = fig.add_subplot(1, 1, 1)
    ok = np.isfinite(v)
    ax.scatter(ang[~ok], h[~ok] * 1e3, s=10, c="#cccccc", marker="x", linewidths=0.6, label="no value")
    sc = ax.scatter(ang[ok], h[ok] * 1e3, s=14, c=v[ok], cmap=cmap)
    fig.colorbar(sc, ax=ax, label=label)
    if sites_m is not None and len(sites_m):
        sa, sh = unroll(np.asarray(sites_m, float), axis, centre_m=centre)
        ax.scatter(sa, sh * 1e3, s=60, marker="s", facecolors="none", edgecolors="#d62728", label="sensor sites")
    if chosen_m is not None and len(chosen_m):
        ca, ch = unroll(np.asarray(chosen_m, float), axis, centre_m=centre)
        ax.scatter(ca, ch * 1e3, s=120, marker="o", facecolors="none", edgecolors="black", linewidths=1.5,
                   label="chosen sensors")
    ax.set_xlim(0, 360)
    ax.set_xticks(range(0, 361, 45))
    ax.set_xlabel("polar angle from anterior towards +x [deg]")
    ax.set_ylabel("height [mm]")
    if title:
        ax.set_title(title)
    ax.legend(loc="upper right", fontsize=7)
    return fig
