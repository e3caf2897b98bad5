"""A Kalman filter on the centreline: state (s, ds/dt, roll), RF fixes projected onto the line,
visual advance and roll as relative measurements (docs/tracking.md, "The Kalman filter").

State x = (s, v, phi): arc length [m], its rate [m/s], roll [deg]. Prediction over dt
(Bar-Shalom, Li & Kirubarajan 2001, Eq 6.2.2-12/13, continuous white-noise acceleration):

    s' = s + v dt,  v' = v,  phi' = phi
    Q = [[q dt^3/3, q dt^2/2, 0], [q dt^2/2, q dt, 0], [0, 0, q_r dt]]

The frame pair measures the motion between two steps, not a state: ``advance = s_k - s_{k-1}``,
``roll = phi_k - phi_{k-1}``. The filter keeps a copy of (s, phi) of the previous step in the
state during the prediction (stochastic cloning; Roumeliotis & Burdick 2002), so the state is
(s, v, phi, s_{k-1}, phi_{k-1}) while step k is updated, with

    H_visual = [[1, 0, 0, -1, 0], [0, 0, 1, 0, -1]],  R = diag(sigma_advance^2, sigma_roll^2)

An RF fix p with covariance C is projected onto the centreline: z = argmin_s |p - c(s)|
(``Centreline.project``, the nonlinear measurement function), measuring s with the variance of
the fix along the tangent t there, R = t^T C t (the perpendicular part tells nothing about s);
H_rf = [1, 0, 0, 0, 0]. A fix whose normalised innovation squared y^2 / S exceeds the
``gate_probability`` quantile of chi-square(1) is ignored (an outlier, or a fix projected onto a
neighbouring loop of the tract while the filter knows better); after ``max_consecutive_gated``
refusals in a row the next one is used with var(s) widened by y^2 - S (the filter, not the fix,
is then the likelier outlier; the same for visual advances). A fix closer than
``rf_min_spacing_m`` along the tract to where the last used fix was taken is not used (its error
is mostly the same body bias: measurements/TrackerConfig). Updates in Joseph form
(Bar-Shalom Eq 5.2.3-18).

The reported 3-D point is the expected point E[c(s)] under s ~ N(s_hat, var(s)) (quadrature split
at the junctions: :func:`expected_point`), with the points' covariance about it: on a smooth stretch of the line
this is c(s_hat) with var(s) t t^T, and near an organ junction, where c(s) jumps by centimetres,
it weighs both sides as the filter's own uncertainty says (the minimum mean-square 3-D point for
that estimate of s, rather than the point at its mean). ``Track.extra``: ``state_covariance``
(n, 3, 3) of (s, v, phi), ``nis_rf`` (y^2 / S of each used fix, chi-square(1)) and ``nis_visual``
(of each used advance).

Where the tract folds back near itself, a fix may project onto the wrong loop; a single Gaussian
cannot hold both hypotheses (tracking.particle can).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from .measurements import Observation, Track, TrackerConfig, check_observations

__all__ = ["kalman_track"]

_H_VISUAL = np.array([[1.0, 0.0, 0.0, -1.0, 0.0], [0.0, 0.0, 1.0, 0.0, -1.0]])
_H_RF = np.array([[1.0, 0.0, 0.0, 0.0, 0.0]])


def _update(x: np.ndarray, P: np.ndarray, H: np.ndarray, z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    S = H @ P @ H.T + R
    K = np.linalg.solve(S.T, (P @ H.T).T).T
    x = x + K @ (z - H @ x)
    A = np.eye(len(x)) - K @ H
    P = A @ P @ A.T + K @ R @ K.T
    return x, 0.5 * (P + P.T)


_GH_NODES, _GH_WEIGHTS = np.polynomial.hermite_e.hermegauss(20)
_GH_WEIGHTS = _GH_WEIGHTS / _GH_WEIGHTS.sum()
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(32)


def expected_point(line, s: float, var: float) -> tuple[np.ndarray, np.ndarray]:
    """(E[c(S)], Cov[c(S)]) for S ~ N(s, var) restricted to the line and to +-6 sigma (module
    docstring). Where neither a junction (within 6 sigma) nor an end (within the nodes' 7.6 sigma) lies
near: 20-node Gauss-Hermite
    (exact on a straight stretch). Else the integral is split at the junctions (c jumps there) and
    the ends, 32-node Gauss-Legendre on each piece weighted by the normal density."""
    L = line.length_m
    if var <= 0.0:
        return np.asarray(line.point_m(min(max(s, 0.0), L)), float), np.zeros((3, 3))
    sd = float(np.sqrt(var))
    lo, hi = s - 6.0 * sd, s + 6.0 * sd
    inner = [j for j in line.junctions_s_m if lo < j < hi]
    reach = sd * float(_GH_NODES[-1])  # the outermost Gauss-Hermite node (7.6 sigma)
    if not inner and s - reach > 0.0 and s + reach < L:
        nodes, w = s + sd * _GH_NODES, _GH_WEIGHTS
    else:
        cuts = np.array([max(lo, 0.0), *inner, min(hi, L)])
        if cuts[-1] <= cuts[0]:  # the whole mass beyond an end
            return np.asarray(line.point_m(min(max(s, 0.0), L)), float), np.zeros((3, 3))
        a, b = cuts[:-1, None], cuts[1:, None]
        nodes = (0.5 * (a + b) + 0.5 * (b - a) * _GL_NODES).ravel()
        w = (0.5 * (b - a) * _GL_WEIGHTS).ravel() * np.exp(-0.5 * ((nodes - s) / sd) ** 2)
        w = w / w.sum()
    pts = np.asarray(line.point_m(nodes), float)
    mean = w @ pts
    d = pts - mean
    return mean, (d * w[:, None]).T @ d


def kalman_track(line, observations: list[Observation], config: TrackerConfig | None = None,
                 *, name: str = "kalman") -> Track:
    """Filter ``observations`` along ``line`` (a :class:`raytrace.body.centreline.Centreline`);
    see the module docstring. Raises :class:`~tracking.errors.TrackingInputError` naming the field."""
    cfg = config or TrackerConfig()
    obs = check_observations(observations)
    L = line.length_m
    if cfg.initial_s_m is None:
        s0, s0_var = 0.5 * L, L * L / 12.0
    else:
        s0, s0_var = float(np.clip(cfg.initial_s_m, 0.0, L)), cfg.initial_s_sigma_m ** 2
    x = np.array([s0, cfg.initial_v_m_per_s, 0.0])
    P = np.diag([s0_var, cfg.initial_v_sigma_m_per_s ** 2, cfg.initial_roll_sigma_deg ** 2])
    gate = None if cfg.gate_probability is None else float(chi2.ppf(cfg.gate_probability, 1))
    vgate = None if cfg.visual_gate_probability is None else float(chi2.ppf(cfg.visual_gate_probability, 1))
    q, qr = cfg.accel_psd_m2_per_s3, cfg.roll_psd_deg2_per_s

    n = len(obs)
    out = {k: np.empty(n) for k in ("s", "ss", "v", "vs", "r", "rs")}
    nis_rf = np.full(n, np.nan)
    nis_vis = np.full(n, np.nan)
    pos = np.empty((n, 3))
    pcov = np.empty((n, 3, 3))
    used = np.zeros(n, bool)
    states = np.empty((n, 3, 3))
    rf_refused = vis_refused = 0
    s_last_fix = None
    for k, o in enumerate(obs):
        if k == 0:
            X, PX = np.concatenate([x, [x[0], x[2]]]), None
        else:
            dt = o.t_s - obs[k - 1].t_s
            J = np.array([[1.0, dt, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
            X = J @ x
            PX = J @ P @ J.T
            PX[:3, :3] += np.array([[q * dt**3 / 3, q * dt**2 / 2, 0.0], [q * dt**2 / 2, q * dt, 0.0],
                                    [0.0, 0.0, qr * dt]])
            vm = o.visual
            if vm is not None:
                h = _H_VISUAL[0]
                y = vm.advance_m - float(h @ X)
                S = float(h @ PX @ h + vm.advance_sigma_m ** 2)
                if vgate is not None and y * y / S > vgate:  # an outlier pair: its advance far off the prediction
                    if vis_refused < cfg.max_consecutive_gated:
                        vis_refused += 1
                        vm = None
                    else:  # refused too often: the prediction is the outlier; widen s to explain y
                        PX[0, 0] += y * y - S
                        S = y * y
            if vm is not None:
                vis_refused = 0
                nis_vis[k] = y * y / S
                if vm.roll_deg is None:
                    X, PX = _update(X, PX, _H_VISUAL[:1], np.array([vm.advance_m]),
                                    np.array([[vm.advance_sigma_m ** 2]]))
                else:
                    X, PX = _update(X, PX, _H_VISUAL, np.array([vm.advance_m, vm.roll_deg]),
                                    np.diag([vm.advance_sigma_m ** 2, vm.roll_sigma_deg ** 2]))
        if PX is None:
            PX = np.zeros((5, 5))
            PX[:3, :3] = P
        if o.rf is not None and (s_last_fix is None or abs(X[0] - s_last_fix) >= cfg.rf_min_spacing_m):
            z = float(line.project(o.rf.position_m))
            t = line.tangent(z)
            R = float(t @ o.rf.covariance_m2 @ t)
            S = float(PX[0, 0] + R)
            y = z - X[0]
            accept = gate is None or y * y / S <= gate
            if not accept:
                if rf_refused < cfg.max_consecutive_gated:
                    rf_refused += 1
                else:  # refused too often: the filter is the likelier outlier; widen s to explain y
                    PX[0, 0] += y * y - S
                    S = y * y
                    accept = True
            if accept:
                rf_refused = 0
                nis_rf[k] = y * y / S
                X, PX = _update(X, PX, _H_RF, np.array([z]), np.array([[R]]))
                used[k] = True
                s_last_fix = float(X[0])
        x, P = X[:3].copy(), PX[:3, :3].copy()
        if not 0.0 <= x[0] <= L:  # the capsule is on the tract: project the estimate back onto it
            x[0] = min(max(x[0], 0.0), L)
        states[k] = P
        out["s"][k], out["v"][k], out["r"][k] = x
        out["ss"][k], out["vs"][k], out["rs"][k] = np.sqrt(np.maximum(np.diag(P), 0.0))
        pos[k], pcov[k] = expected_point(line, x[0], P[0, 0])
    return Track(tracker=name, t_s=np.array([o.t_s for o in obs]), s_m=out["s"], s_sigma_m=out["ss"],
                 v_m_per_s=out["v"], v_sigma_m_per_s=out["vs"], roll_deg=out["r"], roll_sigma_deg=out["rs"],
                 position_m=pos, position_cov_m2=pcov, rf_used=used,
                 extra={"state_covariance": states, "nis_rf": nis_rf, "nis_visual": nis_vis, "nis_rf_dof": 1})
