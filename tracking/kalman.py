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
neighbouring loop of the tract while the filter knows better). Updates in Joseph form
(Bar-Shalom Eq 5.2.3-18). The reported 3-D point is c(s) with covariance var(s) t t^T (first order);
``Track.extra["state_covariance"]`` holds the (n, 3, 3) covariance of (s, v, phi) per step.

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
    pos = np.empty((n, 3))
    pcov = np.empty((n, 3, 3))
    used = np.zeros(n, bool)
    states = np.empty((n, 3, 3))
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
            if vm is not None and vgate is not None:  # an outlier pair: its advance far off the prediction
                h = _H_VISUAL[0]
                y = vm.advance_m - float(h @ X)
                if y * y / float(h @ PX @ h + vm.advance_sigma_m ** 2) > vgate:
                    vm = None
            if vm is not None:
                if vm.roll_deg is None:
                    X, PX = _update(X, PX, _H_VISUAL[:1], np.array([vm.advance_m]),
                                    np.array([[vm.advance_sigma_m ** 2]]))
                else:
                    X, PX = _update(X, PX, _H_VISUAL, np.array([vm.advance_m, vm.roll_deg]),
                                    np.diag([vm.advance_sigma_m ** 2, vm.roll_sigma_deg ** 2]))
        if PX is None:
            PX = np.zeros((5, 5))
            PX[:3, :3] = P
        if o.rf is not None:
            z = float(line.project(o.rf.position_m))
            t = line.tangent(z)
            R = float(t @ o.rf.covariance_m2 @ t)
            S = float(PX[0, 0] + R)
            y = z - X[0]
            if gate is None or y * y / S <= gate:
                X, PX = _update(X, PX, _H_RF, np.array([z]), np.array([[R]]))
                used[k] = True
        x, P = X[:3].copy(), PX[:3, :3].copy()
        if not 0.0 <= x[0] <= L:  # the capsule is on the tract: project the estimate back onto it
            x[0] = min(max(x[0], 0.0), L)
        states[k] = P
        out["s"][k], out["v"][k], out["r"][k] = x
        out["ss"][k], out["vs"][k], out["rs"][k] = np.sqrt(np.maximum(np.diag(P), 0.0))
        t = line.tangent(x[0])
        pos[k] = line.point_m(x[0])
        pcov[k] = P[0, 0] * np.outer(t, t)
    return Track(tracker=name, t_s=np.array([o.t_s for o in obs]), s_m=out["s"], s_sigma_m=out["ss"],
                 v_m_per_s=out["v"], v_sigma_m_per_s=out["vs"], roll_deg=out["r"], roll_sigma_deg=out["rs"],
                 position_m=pos, position_cov_m2=pcov, rf_used=used,
                 extra={"state_covariance": states})
