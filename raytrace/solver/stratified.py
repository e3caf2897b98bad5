"""The exact field of one generalized ray through planar layers: a dipole's plane-wave spectrum
carried through the ray's own interfaces and integrated (a Sommerfeld integral), instead of its
stationary-phase (geometric-optics) value (docs/validation.md, "Stratified paths").

Geometric optics evaluates each path by the stationary phase of its plane-wave spectrum: exact far
from the source and the interfaces in wavelengths, and away from critical angles. A capsule a few
centimetres under the skin is neither: the source sits within a wavelength of the interfaces (its
reactive near field reaches them), and the paths to contact sensors aside refract close to the fat's
critical cone, where the spectrum's branch point (the lateral wave along the layer) is as strong as
the ray. The generalized ray integral has all of it: in a planar stack the field at the receiver is
exactly the sum over the rays (every order of reflection) of

    E(rho) = 1/(2 pi)^2 int int  E~(kx, ky)  exp(-j (kx x + ky y))  dkx dky

where ``E~`` is the dipole's spectrum ``-(w mu0 / (2 kz_s)) p_perp`` (the ``exp(+j w t)`` Weyl
expansion of the Hertzian dipole of moment ``I dl = 1``, ``p_perp`` the part of ``p`` transverse to
the plane wave), split into TE and TM (transverse to the layers' axis ``z``), each carried as the
tangential field ("voltage") of a transmission line: ``exp(-j kz_i l_i)`` over a segment crossing
``l_i`` of its layer's thickness, ``tau = 2 Z_b / (Z_a + Z_b)`` at a refraction and ``Gamma = (Z_b -
Z_a) / (Z_b + Z_a)`` at a reflection (``Z_TE = w mu0 / kz``, ``Z_TM = kz / (w eps0 eps_r)``; ``Gamma_TE``
is the Fresnel ``r_TE``, and these are the coefficients of any transfer-matrix code); at the
receiver the TM wave's normal component is ``-kr / (sigma kz_r)`` times its tangential one (sigma =
+-1: travelling up or down). The integrand's dependence on the azimuth ``alpha`` of ``(kx, ky)`` is
a trigonometric polynomial of degree 2 (one factor from each dipole), so with ``alpha`` sampled 8
times its Fourier coefficients ``c_m`` are exact and

    E(rho) = 1/(2 pi) int_0^inf  kr  sum_m  c_m(kr) (-j)^m J_m(kr rho) exp(j m phi)  dkr.

The ``kr`` integral runs on Gauss-Legendre panels along a path lifted into the first quadrant up to
beyond the largest Re k (above the branch points and poles, which lie in the fourth quadrant for
``exp(+j w t)``, on the axis when lossless), then along the real axis until ``exp(-kr dz)`` (``dz``
the ray's total crossing of the layers) is below 1e-16. ``kz = sqrt(k^2 - kr^2)`` with ``Im kz <=
0`` (the proper sheet on that path).

Normalised as the tracer's gains (:mod:`raytrace.solver.field`): ``a = lambda0 / (4 pi sqrt(Re n_tx
Re n_rx)) (q . E) / (-j w mu0 / (4 pi))``, which in one medium is the exact dipole field the
tracer's near-field term gives (Jackson 9.18); it replaces both the near-field factor (exact only in
one medium) and the stationary-phase tube and Fresnel coefficients (whose lossy oblique form is a
convention) for the paths it is used on (:func:`stack_ray`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

from raytrace.physics.em import C0, EPS0, MU0

#: Largest angle between an interface's normal on the path and the stack's axis [deg] for the path to
#: be evaluated on a stack of planar layers (:func:`stack_ray`). Exact at 0 (planar, parallel layers);
#: on the torso's curved layers the integral on the stack built along the last interface's normal beat
#: geometric optics against gprMax up to a 34 deg tilt (a contact sensor 40 deg aside: 1.1 dB off, 6.8 dB
#: by geometric optics; docs/validation.md), so tilted stacks are used and flagged ``curved_layers``
#: (raytrace.solver.validity) beyond 20 deg.
PARALLEL_DEG = 40.0
#: Gauss-Legendre points per panel of the ``kr`` integral.
GL_POINTS = 16
_GL_X, _GL_W = np.polynomial.legendre.leggauss(GL_POINTS)
#: The integral stops where ``exp(-kr dz)`` falls below ``exp(-DECAY)``.
DECAY = 37.0
#: Azimuth samples (exact for the degree-2 trigonometric polynomial of two dipoles).
AZIMUTHS = 8


@dataclass(frozen=True)
class StackRay:
    """One ray through planar layers, in the stack's frame (``z`` its axis).

    ``n``: (F, S) complex indices of the S segments' media at each frequency; ``dz``: (S,) the
    thickness each segment crosses (>= 0); ``up``: (S,) +1 travelling along ``z``, -1 against it;
    ``reflect``: (S - 1,) True where the interface between segments s and s + 1 reflects (the medium
    beyond it is ``beyond[s]``), False where it refracts into segment s + 1's medium; ``beyond``: (S -
    1, F) complex index on the far side of each interface; ``rho``: (2,) the receiver's lateral offset
    from the transmitter; ``p``, ``q``: (3,) the transmitting and receiving dipoles."""

    n: np.ndarray
    dz: np.ndarray
    up: np.ndarray
    reflect: np.ndarray
    beyond: np.ndarray
    rho: np.ndarray
    p: np.ndarray
    q: np.ndarray
    tilt_deg: float = 0.0  # the largest angle between an interface's normal and the stack's axis


def _kz(k: np.ndarray, kr: np.ndarray) -> np.ndarray:
    kz = np.sqrt(k * k - kr * kr + 0j)
    return np.where(kz.imag > 0.0, -kz, kz)


def _bessel012(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """J0, J1, J2 of ``x`` (complex on the lifted part of the path, real beyond it: scipy's real
    kernels are ~20 times faster); J2 from the recurrence ``2 J1 / x - J0`` (0 at x = 0)."""
    real = x.imag == 0.0
    j0, j1 = np.empty(x.shape, complex), np.empty(x.shape, complex)
    j0[real], j1[real] = special.j0(x[real].real), special.j1(x[real].real)
    j0[~real], j1[~real] = special.jv(0, x[~real]), special.jv(1, x[~real])
    with np.errstate(invalid="ignore", divide="ignore"):
        j2 = np.where(x == 0.0, 0.0, 2.0 * j1 / x - j0)
    return j0, j1, j2


def _nodes(k_re_max: float, rho: float, dz: float) -> tuple[np.ndarray, np.ndarray]:
    """(kr, weight * dkr/dt) of the Gauss-Legendre panels (module docstring)."""
    k1 = 1.2 * k_re_max
    k2 = k1 + DECAY / dz
    # panels: no wider than half a period of J_m(kr rho), nor than a few decay lengths 1 / dz; on the
    # lifted part, which passes the branch points and poles, also a sixth of it
    width = min(np.pi / max(rho, 1e-12), 4.0 / dz)
    edges = np.concatenate([np.linspace(0.0, k1, max(int(np.ceil(k1 / min(width, k1 / 6.0))), 2) + 1),
                            np.linspace(k1, k2, max(int(np.ceil((k2 - k1) / width)), 1) + 1)[1:]])
    a, b = edges[:-1, None], edges[1:, None]
    t = (0.5 * (b - a) * _GL_X + 0.5 * (b + a)).ravel()
    w = (0.5 * (b - a) * _GL_W).ravel()
    lift = min(0.05 * k1, 0.5 / max(rho, 1e-3))
    bump = np.where(t < k1, np.sin(np.pi * t / k1), 0.0)
    dbump = np.where(t < k1, np.pi / k1 * np.cos(np.pi * t / k1), 0.0)
    return t + 1j * lift * bump, w * (1.0 + 1j * lift * dbump)


def field(ray: StackRay, frequencies_hz: np.ndarray) -> np.ndarray:
    """(F,) ``q . E`` at the receiver of the dipole ``p`` (``I dl = 1``) along ``ray`` (module docstring)."""
    f = np.asarray(frequencies_hz, float)
    w = 2.0 * np.pi * f  # (F,)
    k = (w / C0)[:, None] * ray.n  # (F, S)
    rho = float(np.hypot(*ray.rho))
    phi = float(np.arctan2(ray.rho[1], ray.rho[0])) if rho > 0 else 0.0
    dz = float(np.sum(ray.dz))
    kr, wt = _nodes(float(np.max(k.real)), rho, dz)  # (K,)
    kr3 = kr[None, :]
    alpha = 2.0 * np.pi * np.arange(AZIMUTHS) / AZIMUTHS
    ca, sa = np.cos(alpha), np.sin(alpha)
    kz = _kz(k[:, :, None], kr3[:, None, :])  # (F, S, K)
    eps = (ray.n * ray.n)[:, :, None]
    w3 = w[:, None, None]
    # transfer of the tangential field, TE and TM, through the segments and interfaces
    phase = np.exp(-1j * np.einsum("fsk,s->fk", kz, ray.dz))
    t_te, t_tm = phase.copy(), phase.copy()
    z_te = MU0 * w3 / kz
    z_tm = kz / (w3 * EPS0 * eps)
    for s, refl in enumerate(ray.reflect):
        if refl:
            kb = _kz((w / C0)[:, None] * ray.beyond[s][:, None], kr3)
            zb_te = MU0 * w[:, None] / kb
            zb_tm = kb / (w[:, None] * EPS0 * (ray.beyond[s] ** 2)[:, None])
            t_te *= (zb_te - z_te[:, s]) / (zb_te + z_te[:, s])
            t_tm *= (zb_tm - z_tm[:, s]) / (zb_tm + z_tm[:, s])
        else:
            t_te *= 2.0 * z_te[:, s + 1] / (z_te[:, s] + z_te[:, s + 1])
            t_tm *= 2.0 * z_tm[:, s + 1] / (z_tm[:, s] + z_tm[:, s + 1])
    ks, kzs = k[:, 0, None, None], kz[:, 0, :, None]  # source medium (F, K, 1)
    kzr = kz[:, -1, :, None]
    s0, sr = float(ray.up[0]), float(ray.up[-1])
    p, q = np.asarray(ray.p, float), np.asarray(ray.q, float)
    kr4 = kr[None, :, None]
    amp = -MU0 * w[:, None, None] / (2.0 * kzs)  # (F, K, 1)
    p_te = -sa * p[0] + ca * p[1]  # (A,)
    p_tm = (s0 * kzs * (ca * p[0] + sa * p[1]) - kr4 * p[2]) / ks  # (F, K, A)
    q_te = -sa * q[0] + ca * q[1]
    q_tm = ca * q[0] + sa * q[1] - kr4 / (sr * kzr) * q[2]
    out = amp * (p_te * t_te[:, :, None] * q_te + p_tm * (s0 * kzs / ks) * t_tm[:, :, None] * q_tm)
    # Fourier coefficients over the azimuth: fft's bin m (mod AZIMUTHS) is the coefficient of exp(+j m alpha)
    cm = np.fft.fft(out, axis=2) / AZIMUTHS
    bessel = _bessel012(kr * rho)
    total = np.zeros(len(f), complex)
    for m in range(-2, 3):
        jm = bessel[abs(m)] * (-1.0 if m < 0 and m % 2 else 1.0)  # J_-m = (-1)^m J_m
        total += ((-1j) ** m * np.exp(1j * m * phi)) * (cm[:, :, m % AZIMUTHS] @ (kr * jm * wt))
    return total / (2.0 * np.pi)


def gain(ray: StackRay, frequencies_hz: np.ndarray, n_tx: np.ndarray, n_rx: np.ndarray) -> np.ndarray:
    """(F,) the path gain in the tracer's normalisation (module docstring); ``n_tx``, ``n_rx``: (F,)."""
    f = np.asarray(frequencies_hz, float)
    w = 2.0 * np.pi * f
    lam0 = C0 / f
    e = field(ray, f)
    return e / (-1j * w * MU0 / (4.0 * np.pi)) * lam0 / (4.0 * np.pi) / np.sqrt(np.real(n_tx) * np.real(n_rx))


#: At most this many ``kr`` nodes per ray (:func:`_nodes`); a ray needing more is left to geometric optics.
MAX_NODES = 20_000


def stack_ray(points: np.ndarray, normals: np.ndarray, reflect: np.ndarray, media: np.ndarray, beyond: np.ndarray,
              n: np.ndarray, p: np.ndarray, q: np.ndarray) -> StackRay | None:
    """The :class:`StackRay` of a traced path, or None when its interfaces are not planar and
    parallel enough (module docstring; :data:`PARALLEL_DEG`) or its integral would be too long.

    ``points``: (K + 2, 3) transmitter, the K interactions, receiver; ``normals``: (K, 3) the
    surfaces' normals there; ``reflect``: (K,) True at a reflection; ``media``: (K + 1,) the media of
    the K + 1 segments (indices into ``n``'s columns); ``beyond``: (K,) the medium on the far side of
    each interface (a reflection's); ``n``: (F, M) complex indices. The stack's axis is the normal of
    the path's last refraction (turned along the travel); every other normal must be within
    :data:`PARALLEL_DEG` of it, and every segment must keep its sense along it (a refraction goes on,
    a reflection turns back)."""
    normals = np.asarray(normals, float)
    legs = np.diff(points, axis=0)  # (K + 1, 3)
    if len(normals) == 0:
        return None
    # each normal turned along the leg arriving at it; reflections turn the legs back, so count each
    # normal with the sense of its leg relative to the first: in a planar stack all then agree
    signed = normals * np.sign(np.einsum("ij,ij->i", normals, legs[:-1]))[:, None]
    sense = np.cumprod(np.concatenate([[1.0], np.where(reflect, -1.0, 1.0)]))  # (K + 1,) each leg's sense
    aligned = signed * sense[:-1, None]
    # the axis: the normal of the last refraction (the layer the receiver is in), so that a direct path
    # and its echoes inside that layer share one stack; a path of reflections only: its first normal
    refr = np.flatnonzero(~np.asarray(reflect, bool))
    axis = aligned[refr[-1] if len(refr) else 0]
    axis = axis / np.linalg.norm(axis)
    tilt = float(np.degrees(np.arccos(np.clip(aligned @ axis, -1.0, 1.0))).max())
    if tilt > PARALLEL_DEG:
        return None
    along = legs @ axis  # (K + 1,)
    if np.any(np.sign(along) * sense < 0.0):
        return None
    dz = np.abs(along)
    total = float(dz.sum())
    if total <= 0.0:
        return None
    rx = points[-1] - points[0]
    lateral = rx - (rx @ axis) * axis
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    frame = np.array([e1, e2, axis])
    return StackRay(n=n[:, media], dz=dz, up=sense, reflect=np.asarray(reflect, bool),
                    beyond=n[:, beyond].T, rho=frame[:2] @ lateral, p=frame @ p, q=frame @ q, tilt_deg=tilt)


def node_count(ray: StackRay, frequencies_hz: np.ndarray) -> int:
    """How many ``kr`` nodes :func:`field` would use."""
    k_re = float(np.max((2.0 * np.pi * np.max(frequencies_hz) / C0) * ray.n.real))
    return len(_nodes(k_re, float(np.hypot(*ray.rho)), float(np.sum(ray.dz)))[0])
