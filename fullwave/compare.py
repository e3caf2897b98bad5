"""FDTD fields as the tracer's path gains, and the per-receiver comparison report.

Normalisation (docs/validation.md, "Normalisation"). A Hertzian dipole of moment ``I dl`` along
``p`` in a homogeneous medium of wavenumber ``k`` radiates (``exp(+j w t)``, Jackson 9.18)
``E = -j w mu0 I dl / (4 pi r) e^{-jkr} [(I - d d) p (1 + u + u^2) - 2 (u + u^2) d (d . p)]``,
``u = 1 / (jkr)``, and the tracer's gain of the same dipole pair is
``a = lambda0 / (4 pi Re n r) e^{-jkr} [...] . p_rx`` (raytrace/solver/field.py; its far field
is the bracket's first term). Dividing, for any field the FDTD computes,

    a_FDTD(f) = (p_rx . E(f)) / (-j w mu0 I(f) dl / (4 pi)) * lambda0 / (4 pi sqrt(Re n_tx Re n_rx))

which is exactly the tracer's convention in a homogeneous medium (where it is derived) and,
with ``sqrt(Re n_tx Re n_rx)``, its symmetric (reciprocal) extension across media: the same
normalisation the tracer's field module uses. ``E(f) = sum_n E[n] e^{-j w n dt} dt`` (gprMax
stores E at ``n dt``) and ``I(f) = sum_n I((n + 1/2) dt) e^{-j w (n + 1/2) dt} dt`` (its
current samples are taken half a step later), so no time offset is left in the phase.

Per receiver, at the carrier: |a| [dB] and arg a [deg] of the coherent sum; the group delay
``-d arg a / d w`` (central difference over +-1 MHz); and the envelope arrival, the peak of
``|int a(f) W(f) e^{j 2 pi (f - f0) t} df|`` with a Gaussian window ``W`` (``ENVELOPE_SIGMA_HZ``),
the same processing on both sides (the tracer's band gains at the same frequencies).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from raytrace.body.phantom import Phantom
from raytrace.errors import AmbiguousPositionError
from raytrace.physics.em import C0, MU0
from raytrace.spec import Antenna, Band, ChannelSpec

from .model import FdtdModel

#: Half-width of the central difference for group delays [Hz].
GROUP_DELAY_STEP_HZ = 1e6
#: Standard deviation of the Gaussian frequency window of the envelope arrival [Hz].
ENVELOPE_SIGMA_HZ = 40e6
#: Frequencies of the envelope window (over +-4 sigma).
ENVELOPE_POINTS = 33


def gaussiandotnorm(t_s: np.ndarray, f0: float) -> np.ndarray:
    """gprMax's ``gaussiandotnorm`` waveform (its waveforms.py): ``-2 z d e^{-z d^2} sqrt(e / (2 z))``,
    ``z = 2 pi^2 f0^2``, ``d = t - 1 / f0``; peak 1."""
    zeta = 2.0 * np.pi ** 2 * f0 ** 2
    d = t_s - 1.0 / f0
    return -2.0 * zeta * d * np.exp(-zeta * d ** 2) * np.sqrt(np.e / (2.0 * zeta))


def _dft(x: np.ndarray, t_s: np.ndarray, f_hz: np.ndarray) -> np.ndarray:
    """``sum x(t) e^{-j 2 pi f t} dt`` at each frequency (the exp(+j w t) phasor of x)."""
    dt = t_s[1] - t_s[0]
    return np.exp(-2j * np.pi * np.outer(f_hz, t_s)) @ x * dt


def frequencies(f0: float) -> np.ndarray:
    """Carrier, group-delay pair and envelope window: the frequencies both sides are evaluated at."""
    env = f0 + np.linspace(-4, 4, ENVELOPE_POINTS) * ENVELOPE_SIGMA_HZ
    return np.concatenate([[f0, f0 - GROUP_DELAY_STEP_HZ, f0 + GROUP_DELAY_STEP_HZ], env])


def fdtd_gains(model: FdtdModel, output: Path, n_tx: complex, n_rx: np.ndarray) -> tuple[np.ndarray, dict]:
    """(R, F) gains ``a_FDTD`` at :func:`frequencies` from a gprMax output file (module docstring),
    and diagnostics (dt, iterations, the fraction of each receiver's energy in the last 10 % of
    the window: a truncated response would show there)."""
    import h5py

    f0 = model.spec.frequency_hz
    freqs = frequencies(f0)
    with h5py.File(output, "r") as f:
        dt = float(f.attrs["dt"])
        iterations = int(f.attrs["Iterations"])
        rxs = f["rxs"]
        names = sorted(rxs, key=lambda s: int("".join(c for c in s if c.isdigit()) or 0))
        fields = [np.stack([np.asarray(rxs[n][c], float) for c in ("Ex", "Ey", "Ez")], axis=1) for n in names]
    t = np.arange(iterations) * dt
    current = gaussiandotnorm(t + 0.5 * dt, f0)  # the dipoles' common waveform; amplitudes = polarization
    i_f = _dft(current, t + 0.5 * dt, freqs)
    h = model.options.cell_m
    w = 2 * np.pi * freqs
    lam0 = C0 / freqs
    spec = model.spec
    gains, tails = [], []
    for r, e in enumerate(fields):
        pol = np.asarray(spec.receivers[r].polarization, float)
        e_pol = e @ (pol / np.linalg.norm(pol))
        e_f = _dft(e_pol, t, freqs)
        a = e_f / (-1j * w * MU0 * i_f * h / (4 * np.pi)) * lam0 / (4 * np.pi) / math.sqrt(n_tx.real * n_rx[r].real)
        gains.append(a)
        energy = np.cumsum(e_pol ** 2)
        tails.append(float(1.0 - energy[int(0.9 * len(energy))] / max(energy[-1], 1e-300)))
    return np.array(gains), {"dt_s": dt, "iterations": iterations, "tail_energy_fraction": tails}


#: How far a snapped antenna that landed on an organ surface is moved off it for the tracer, in
#: cells (:func:`tracer_spec`): 0.2 mm at 2 mm cells. Not much less: a receiver microns under a
#: surface is where the tracer's shooting stops finding that surface's own reflection, which
#: coincides with the direct path there (measured: missing at 3 um with 1e5 rays, found at 0.2 mm).
OFF_SURFACE_CELLS = 0.1


def _off_surface(phantom: Phantom, snapped: np.ndarray, requested: np.ndarray, step_m: float,
                 where: str) -> np.ndarray:
    """``snapped`` if its medium is defined, else the point ``step_m`` from it along the axis
    direction (+-x, +-y, +-z) that lands in ``requested``'s medium and points most towards it."""
    try:
        phantom.medium_index(snapped[None, :])
        return snapped
    except AmbiguousPositionError:
        pass
    want = int(phantom.medium_index(np.asarray(requested, float)[None, :])[0])
    d = np.asarray(requested, float) - snapped
    best, best_dot = None, -np.inf
    for axis in range(3):
        for sign in (-1.0, 1.0):
            p = snapped.copy()
            p[axis] += sign * step_m
            try:
                medium = int(phantom.medium_index(p[None, :])[0])
            except AmbiguousPositionError:
                continue
            if medium == want and sign * d[axis] > best_dot:
                best, best_dot = p, sign * d[axis]
    if best is None:
        raise ValueError(f"{where} lies on an organ surface and no point {step_m} m from it along an axis is in "
                         "its requested medium; move it off the surface")
    return best


def tracer_spec(model: FdtdModel, base: ChannelSpec | None = None, phantom: Phantom | None = None) -> ChannelSpec:
    """The request the tracer answers for the comparison: the model's snapped positions, dipole
    patterns (the FDTD antennas are Hertzian dipoles) and the band of :func:`frequencies`.

    A grid whose cell faces carry an interface (a planar layer aligned with the grid) puts the
    tangential field's nodes on it, where the tracer refuses an antenna (its medium is
    ambiguous). With ``phantom`` given, such a snapped antenna is moved :data:`OFF_SURFACE_CELLS`
    cells along an axis into its requested medium: the tangential E the FDTD samples on the
    interface is continuous across it, and 0.1 cell (0.2 mm) moves the phase of the surface's
    own reflection by 2 k d (1.3 deg in skin at 402 MHz)."""
    spec = base or model.spec
    tx_m, rx_m = model.tx_m, model.rx_m
    if phantom is not None:
        resolved = spec.resolve(phantom)
        step = OFF_SURFACE_CELLS * model.options.cell_m
        tx_m = _off_surface(phantom, tx_m, resolved.tx_m, step, "transmitter")
        rx_m = np.array([_off_surface(phantom, p, q, step, f"receivers[{i}]")
                         for i, (p, q) in enumerate(zip(rx_m, resolved.rx_m))])
    tx = Antenna(position_m=tx_m, name=spec.transmitter.name, polarization=spec.transmitter.polarization,
                 pattern="dipole")
    rxs = tuple(Antenna(position_m=p, name=r.name, polarization=r.polarization, pattern="dipole")
                for p, r in zip(rx_m, spec.receivers))
    return dataclasses.replace(spec, transmitter=tx, receivers=rxs,
                               band=Band(frequencies_hz=frequencies(spec.frequency_hz)[1:]))


def tracer_gains(result) -> np.ndarray:
    """(R, F) coherent sums of a traced :func:`tracer_spec` at :func:`frequencies`."""
    out = []
    for prof in result.profiles:
        g = np.zeros(len(result.band_frequencies_hz) + 1, complex)
        for p in prof.paths:
            g += np.concatenate([[p.gain], p.band_gains])
        out.append(g)
    return np.array(out)


@dataclass(frozen=True)
class Metrics:
    gain_db: float
    phase_deg: float
    group_delay_s: float
    envelope_s: float

    @staticmethod
    def of(a: np.ndarray, f0: float) -> "Metrics":
        """From gains at :func:`frequencies`."""
        g0 = a[0]
        slope = np.angle(a[2] / a[1]) / (2 * np.pi * 2 * GROUP_DELAY_STEP_HZ)
        env_f = frequencies(f0)[3:]
        win = np.exp(-0.5 * ((env_f - f0) / ENVELOPE_SIGMA_HZ) ** 2)
        t = np.linspace(0.0, 10e-9, 2001)
        env = np.abs(np.exp(2j * np.pi * np.outer(t, env_f - f0)) @ (a[3:] * win))
        k = int(np.argmax(env))
        if 0 < k < len(t) - 1:  # parabolic refinement of the peak
            y0, y1, y2 = env[k - 1], env[k], env[k + 1]
            shift = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2) if (y0 - 2 * y1 + y2) != 0 else 0.0
        else:
            shift = 0.0
        with np.errstate(divide="ignore"):
            return Metrics(float(20 * np.log10(abs(g0))), float(np.degrees(np.angle(g0))), float(-slope),
                           float(t[k] + shift * (t[1] - t[0])))


def media_indices(phantom: Phantom, spec: ChannelSpec) -> tuple[complex, np.ndarray]:
    """Complex indices at the carrier at the transmitter and each receiver (the tracer's media)."""
    from raytrace.solver.media import MediaTable

    resolved = spec.resolve(phantom)
    table = MediaTable.build(phantom, np.array([spec.frequency_hz]), spec.homogeneous)
    n = table.n[0]
    return complex(n[resolved.tx_medium + 1]), np.array([n[m + 1] for m in resolved.rx_medium])


__all__ = ["Metrics", "fdtd_gains", "frequencies", "media_indices", "tracer_gains", "tracer_spec"]
