"""The exact field of a horizontal Hertzian dipole in planar layers: the planar full-wave cases'
second reference (docs/validation.md, "The exact layered field as a second reference") and the
oracle of tests/raytrace/test_stratified.py. It shares no code with the tracer.

Transmission-line Green's functions (Michalski & Mosig, IEEE TAP 45(3), 1997): for a unit current
source and the receiver at lateral offset rho at azimuth phi, ``E_t = G p`` with

    G_xx = -1/2 [S0{Ve + Vh} - cos 2phi S2{Ve - Vh}],   G_yy = -1/2 [S0{Ve + Vh} + cos 2phi S2{Ve - Vh}],
    G_xy = G_yx = 1/2 sin 2phi S2{Ve - Vh},             S_n{f} = 1/(2 pi) int_0^inf f J_n(kr rho) kr dkr,

``Ve`` and ``Vh`` the TM and TE line voltages at the receiver (``Z_TE = w mu0 / kz``, ``Z_TM = kz /
(w eps)``), the source in the bottom half-space, every multiple reflection by the lines'
generalized reflection coefficients. The integral runs on a trapezoid of 40 000 points along a path
lifted above the real axis (relative error ~1e-6 against the closed-form dipole field).

    python -m bench.fullwave exact      # tracer and FDTD against it on the planar cases' reports
"""

from __future__ import annotations

import numpy as np
from scipy.special import jv

C = 299_792_458.0
EPS0 = 8.8541878128e-12
MU0 = 1.25663706212e-6
F = 402e6


def decaying_kz(k, kr):
    kz = np.sqrt(k * k - kr * kr + 0j)
    return np.where(kz.imag > 0, -kz, kz)


def line_voltages(kr, w, eps, d, h, zr, reverberations=None):
    """(Ve, Vh) at height ``zr`` above the bottom interface, unit shunt current at depth ``h`` below
    it in the bottom half-space; layers ``eps`` (bottom half-space, finite layers of thicknesses
    ``d``, top half-space). ``reverberations``: None for the full field; k for the direct pass up to
    the receiver's layer followed by exactly k reflections inside that layer (one generalized ray)."""
    k = w / C * np.sqrt(np.asarray(eps, complex))
    n = len(eps)
    kz = [decaying_kz(k[i], kr) for i in range(n)]
    tops = np.concatenate([[0.0], np.cumsum(d)])
    m = int(np.searchsorted(tops, zr))  # receiver's layer
    out = []
    for pol in "eh":
        z = [kz[i] / (w * EPS0 * eps[i]) if pol == "e" else w * MU0 / kz[i] for i in range(n)]
        if reverberations is not None:  # one generalized ray: local coefficients only
            v = z[0] / 2 * np.exp(-1j * kz[0] * h)
            for i in range(m):
                v = v * 2 * z[i + 1] / (z[i] + z[i + 1])
                if i + 1 < m:
                    v = v * np.exp(-1j * kz[i + 1] * d[i])
            t, thick = zr - tops[m - 1], d[m - 1]
            g_top = (z[m + 1] - z[m]) / (z[m + 1] + z[m])
            g_bot = (z[m - 1] - z[m]) / (z[m - 1] + z[m])
            r = reverberations
            length = 2 * thick * (r // 2) + (t if r % 2 == 0 else 2 * thick - t)
            out.append(v * g_top ** ((r + 1) // 2) * g_bot ** (r // 2) * np.exp(-1j * kz[m] * length))
            continue
        gam = [0j] * n  # generalized reflection at the top of layer i, seen from inside it
        for i in range(n - 2, -1, -1):
            if i + 1 == n - 1:
                zin = z[n - 1]
            else:
                e2 = np.exp(-2j * kz[i + 1] * d[i])
                zin = z[i + 1] * (1 + gam[i + 1] * e2) / (1 - gam[i + 1] * e2)
            gam[i] = (zin - z[i]) / (zin + z[i])
        v_int = z[0] / 2 * np.exp(-1j * kz[0] * h) * (1 + gam[0])  # total voltage at the bottom interface
        for i in range(1, m):
            e2 = np.exp(-2j * kz[i] * d[i - 1])
            v_int = v_int / (1 + gam[i] * e2) * np.exp(-1j * kz[i] * d[i - 1]) * (1 + gam[i])
        t = zr - tops[m - 1]
        if m == n - 1:
            out.append(v_int * np.exp(-1j * kz[m] * t))
        else:
            e2 = np.exp(-2j * kz[m] * d[m - 1])
            out.append(v_int / (1 + gam[m] * e2) * (np.exp(-1j * kz[m] * t)
                                                    + gam[m] * np.exp(-1j * kz[m] * (2 * d[m - 1] - t))))
    return out


def exact_field(eps, d, h, zr, rho_xy, p, q, reverberations=None, f=F, points=40_000):
    """q . E of the horizontal dipole p (I dl = 1), both (x, y) in the layers' plane."""
    w = 2 * np.pi * f
    k_re = w / C * np.max(np.sqrt(np.asarray(eps, complex)).real)
    t = np.linspace(0.0, max(60.0 / (h + zr), 5 * k_re), points)
    top = 1.5 * k_re
    kr = t + 1j * 0.02 * k_re * np.where(t < top, np.sin(np.pi * t / top), 0.0)
    dkr = np.gradient(kr, t)
    ve, vh = line_voltages(kr, w, eps, d, h, zr, reverberations)
    rho = float(np.hypot(*rho_xy))
    phi = float(np.arctan2(rho_xy[1], rho_xy[0]))
    s0 = np.trapezoid((ve + vh) * jv(0, kr * rho) * kr * dkr, t) / (2 * np.pi)
    s2 = np.trapezoid((ve - vh) * jv(2, kr * rho) * kr * dkr, t) / (2 * np.pi)
    g = np.array([[-0.5 * (s0 - np.cos(2 * phi) * s2), 0.5 * np.sin(2 * phi) * s2],
                  [0.5 * np.sin(2 * phi) * s2, -0.5 * (s0 + np.cos(2 * phi) * s2)]])
    return complex(np.asarray(q, complex) @ g @ np.asarray(p, complex))


def as_gain(e, n_tx, n_rx, f=F):
    """The tracer's normalisation of a field of I dl = 1 (docs/validation.md, "Normalisation")."""
    return e / (-1j * 2 * np.pi * f * MU0 / (4 * np.pi)) * C / f / (4 * np.pi) / np.sqrt(n_tx.real * n_rx.real)


def _layer_geometry(layers, cell_m: float):
    """(tissues bottom up with air on top, finite thicknesses bottom up, fronts as the grid sees them)."""
    fronts = [round(f / cell_m + 1e-9) * cell_m for _, _, f in layers]
    tissue = [t for _, t, _ in layers][::-1]
    return tissue, list(np.diff(fronts)[::-1]), fronts


def case_rows(report: dict, layers) -> list[dict]:
    """Per run and receiver of a planar case's :func:`fullwave.run.compare` report: the exact field at
    the tracer's positions (the grid's layer positions), and tracer - exact and FDTD - exact in gain
    [dB], phase [deg] and group delay [s] (+-1 MHz, as the report's)."""
    from raytrace.physics.tissues import complex_relative_permittivity

    rows = []
    for run in report["runs"]:
        if not run.get("ran"):
            continue
        h = run["cell_m"]
        tissue, d, fronts = _layer_geometry(layers, h)
        tx = np.asarray(run["transmitter_m"], float)
        f0 = report["request"]["frequency_hz"]
        for r, pos in zip(run["receivers"], run["tracer_receivers_m"]):
            pos = np.asarray(pos, float)
            out = {}
            for tag, f in (("0", f0), ("lo", f0 - 1e6), ("hi", f0 + 1e6)):
                eps = [complex(complex_relative_permittivity(t, f)) for t in tissue] + [1.0 + 0j]
                n = np.sqrt(np.array(eps))
                layer = int(np.searchsorted(fronts, pos[1]))  # 0: air, 1: the outermost layer, ...
                n_rx = n[-1] if layer == 0 else n[len(tissue) - layer]
                e = exact_field(eps, d, tx[1] - fronts[-1], fronts[-1] - pos[1],
                                [pos[0] - tx[0], pos[2] - tx[2]], [0.0, 1.0], [0.0, 1.0], f=f)
                out[tag] = as_gain(e, n[0], n_rx, f)
            gd = -np.angle(out["hi"] / out["lo"]) / (2 * np.pi * 2e6)
            db, deg = 20 * np.log10(abs(out["0"])), np.degrees(np.angle(out["0"]))
            row = {"cell_m": h, "receiver": r["receiver"], "exact_gain_db": db}
            for who in ("tracer", "fdtd"):
                m = r[who]
                row[who] = (m["gain_db"] - db, (m["phase_deg"] - deg + 180.0) % 360.0 - 180.0, m["group_delay_s"] - gd)
            rows.append(row)
    return rows


def summary(name: str, rows: list[dict]) -> str:
    """One Markdown row: the ranges of tracer - exact and FDTD - exact per cell size."""
    def span(values, fmt):
        lo, hi = min(values), max(values)
        return f"{format(lo, fmt)} to {format(hi, fmt)}" if format(lo, fmt) != format(hi, fmt) else format(lo, fmt)

    def cols(sel, who):
        v = [r[who] for r in sel]
        return " / ".join((span([x[0] for x in v], "+.2f"), span([x[1] for x in v], "+.1f"),
                           span([x[2] * 1e12 for x in v], "+.0f")))

    cells = sorted({r["cell_m"] for r in rows}, reverse=True)
    first = [r for r in rows if r["cell_m"] == cells[0]]
    parts = [f"| {name} | {cols(first, 'tracer')}"]
    parts += [cols([r for r in rows if r["cell_m"] == h], "fdtd") for h in cells]
    return " | ".join(parts) + " |"
