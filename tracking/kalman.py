"""A Kalman filter on the centreline: state (s, ds/dt, roll), RF fixes projected onto the line,
visual advance and roll as relative measurements (docs/tracking.md, "The Kalman filter").

State x = (s, v, phi): arc length [m], its rate [m/s], roll [deg]. Prediction over dt
(Bar-Shalom, Li & Kirubarajan 2001, Eq 6.2.2-12/13, continuous white-noise acceleration):

    s' = s + v dt,  v' = v,  phi' = phi
    Q = [[q dt^3/3, q dt^2/2, 0], [q dt^2/2, q dt, 0], [0, 0, q_r dt]]

The frame pair measures the motion between two steps, not a state: ``advance = s_k - s_{k-1}``,
``roll = phi_k - phi_{k-1}``. The filter keeps a copy of (s, phi) of the previous step in the
state during the prediction (stochastic cloning; Roumeliotis & Burdick 2002), so the state is
(s, v, phi, b, db/ds, s_{k-1}, phi_{k-1}) while step k is updated (b: the RF bias, below), with

    H_visual = [[1, 0, 0, 0, 0, -1, 0], [0, 0, 1, 0, 0, 0, -1]],  R = diag(sigma_advance^2, sigma_roll^2)

An RF fix p with covariance C is projected onto the centreline: z = argmin_s |p - c(s)|
(``Centreline.project``, the nonlinear measurement function), measuring s with the variance of
the fix along the tangent t there, R = t^T C t (the perpendicular part tells nothing about s);
H_rf = [1, 0, 0, 0, 0, 0, 0]. A fix whose normalised innovation squared y^2 / S exceeds the
``gate_probability`` quantile of chi-square(1) is ignored (an outlier, or a fix projected onto a
neighbouring loop of the tract while the filter knows better); after ``max_consecutive_gated``
refusals in a row the next one is used with var(s) widened by y^2 - S (the filter, not the fix,
is then the likelier outlier; the same for visual advances). An advance outside
``speed_range_m_per_s`` times dt is dropped before any gate (not a motion the capsule can make).

Correlated RF errors. A fix's error is mostly the body's bias where the capsule is, shared by the
fixes of the next millimetres. A fix that declares ``bias_covariance_m2`` B, with
``rf_correlation_length_m`` ell set, measures z = s + b + w, H_rf = [1, 0, 0, 1, 0, 0, 0]: b, the bias
along the tract, is a state (coloured measurement noise by state augmentation, as in Gelb, Applied
Optimal Estimation, 1974), a smooth second-order Gauss-Markov process in the distance travelled
(state (b, db/ds), autocorrelation (1 + d/ell) exp(-d/ell), stationary variance t^T B t:
:func:`bias_transition`); over a step the capsule moves |v| dt. w ~ N(0, t^T C t) is the fix's white
part (``covariance_m2``). A stopped capsule's repeated fixes then tell nothing new, a moving one's
average out over ell; the bias is smooth (a first-order process would decorrelate it between fixes a
millimetre apart and let a filter that knows the motion from the video average it away too fast).
Without ell the bias counts as white noise (R = t^T (C + B) t). A fix is not used while neither the
estimate nor the fix's projection has moved ``rf_min_spacing_m`` from the last used one, unless the
filter's own 3-D point is less certain than the fix (near an organ junction, where c(s) jumps and a
fix tells the side). Updates in
Joseph form (Bar-Shalom Eq 5.2.3-18).

The reported 3-D point is the expected point E[c(s)] under s ~ N(s_hat, var(s)) (quadrature split
at the junctions: :func:`expected_point`), with the points' covariance about it: on a smooth stretch
of the line this is c(s_hat) with var(s) t t^T, and near an organ junction, where c(s) jumps by centimetres,
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

# state during a step: (s, v, roll, b, db/ds, s_prev, roll_prev)
_H_VISUAL = np.array([[1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0], [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0]])
_H_RF = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
_H_RF_BIAS = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])


def bias_transition(distance_m: float, ell: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of the smooth bias (b, db/ds), unit stationary variance, over ``distance_m`` along the
    tract: the second-order Gauss-Markov process whose autocorrelation is (1 + d/ell) exp(-d/ell)
    (Matern 3/2 in the distance; state-space form as in Hartikainen & Sarkka 2010): P_inf =
    diag(1, 1/ell^2), F = exp(-d/ell) [[1 + d/ell, d], [-d/ell^2, 1 - d/ell]], Q = P_inf - F P_inf F^T."""
    d = abs(float(distance_m))
    x = d / ell
    F = np.exp(-x) * np.array([[1.0 + x, d], [-x / ell, 1.0 - x]])
    P = np.diag([1.0, 1.0 / (ell * ell)])
    return F, P - F @ P @ F.T


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


def _fix_spread(fix) -> float:
    """trace of a fix's whole covariance (white and bias) [m^2]."""
    return float(np.trace(fix.covariance_m2) + (0.0 if fix.bias_covariance_m2 is None
                                                 else np.trace(fix.bias_covariance_m2)))


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
    # (s, v, roll, b, db/ds): b the RF bias along the tract (zero and unused until a fix declares one)
    x = np.array([s0, cfg.initial_v_m_per_s, 0.0, 0.0, 0.0])
    P = np.diag([s0_var, cfg.initial_v_sigma_m_per_s ** 2, cfg.initial_roll_sigma_deg ** 2, 0.0, 0.0])
    gate = None if cfg.gate_probability is None else float(chi2.ppf(cfg.gate_probability, 1))
    vgate = None if cfg.visual_gate_probability is None else float(chi2.ppf(cfg.visual_gate_probability, 1))
    q, qr, ell = cfg.accel_psd_m2_per_s3, cfg.roll_psd_deg2_per_s, cfg.rf_correlation_length_m

    n = len(obs)
    out = {k: np.empty(n) for k in ("s", "ss", "v", "vs", "r", "rs")}
    nis_rf = np.full(n, np.nan)
    nis_vis = np.full(n, np.nan)
    pos = np.empty((n, 3))
    pcov = np.empty((n, 3, 3))
    used = np.zeros(n, bool)
    states = np.empty((n, 3, 3))
    rf_refused = vis_refused = 0
    last_fix = None  # (s, the fix's projection) when the last fix was used
    bias_var = None  # stationary variance of b along the tract (the last fix's organ), once a fix declared one
    for k, o in enumerate(obs):
        if k == 0:
            X, PX = np.concatenate([x, [x[0], x[2]]]), None
        else:
            dt = o.t_s - obs[k - 1].t_s
            J = np.zeros((7, 5))
            J[0, 0], J[0, 1], J[1, 1], J[2, 2], J[5, 0], J[6, 2] = 1.0, dt, 1.0, 1.0, 1.0, 1.0
            Fb, Qb = (np.eye(2), np.zeros((2, 2))) if bias_var is None else bias_transition(x[1] * dt, ell)
            J[3:5, 3:5] = Fb
            X = J @ x
            PX = J @ P @ J.T
            PX[:3, :3] += np.array([[q * dt**3 / 3, q * dt**2 / 2, 0.0], [q * dt**2 / 2, q * dt, 0.0],
                                    [0.0, 0.0, qr * dt]])
            if bias_var is not None:
                PX[3:5, 3:5] += bias_var * Qb
            vm = o.visual
            if vm is not None and cfg.speed_range_m_per_s is not None and not (
                    cfg.speed_range_m_per_s[0] * dt <= vm.advance_m <= cfg.speed_range_m_per_s[1] * dt):
                vm = None  # not a motion the capsule can make
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
            PX = np.zeros((7, 7))
            PX[:5, :5] = P
        z = None if o.rf is None else float(line.project(o.rf.position_m))
        if z is not None and last_fix is not None and abs(X[0] - last_fix[0]) < cfg.rf_min_spacing_m \
                and abs(z - last_fix[1]) < cfg.rf_min_spacing_m \
                and np.trace(expected_point(line, X[0], PX[0, 0])[1]) < _fix_spread(o.rf):
            z = None  # too close to the last used fix (the same bias), and the filter knows the point as well
        if z is not None:
            t = line.tangent(z)
            R = float(t @ o.rf.covariance_m2 @ t)
            H = _H_RF
            if o.rf.bias_covariance_m2 is not None:
                b2 = float(t @ o.rf.bias_covariance_m2 @ t)
                if ell is None:  # no correlation model: the bias counts as white noise
                    R += b2
                else:
                    if bias_var is None:  # the first fix with a bias: (b, db/ds) start at their stationary spread
                        PX[3, 3], PX[4, 4] = b2, b2 / (ell * ell)
                    bias_var = b2
                    H = _H_RF_BIAS
            S = float(H @ PX @ H + R)
            y = z - float(H @ X)
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
                X, PX = _update(X, PX, H[None, :], np.array([z]), np.array([[R]]))
                used[k] = True
                last_fix = (float(X[0]), z)
        x, P = X[:5].copy(), PX[:5, :5].copy()
        if not 0.0 <= x[0] <= L:  # the capsule is on the tract: project the estimate back onto it
            x[0] = min(max(x[0], 0.0), L)
        states[k] = P[:3, :3]
        out["s"][k], out["v"][k], out["r"][k] = x[:3]
        out["ss"][k], out["vs"][k], out["rs"][k] = np.sqrt(np.maximum(np.diag(P)[:3], 0.0))
        pos[k], pcov[k] = expected_point(line, x[0], P[0, 0])
    return Track(tracker=name, t_s=np.array([o.t_s for o in obs]), s_m=out["s"], s_sigma_m=out["ss"],
                 v_m_per_s=out["v"], v_sigma_m_per_s=out["vs"], roll_deg=out["r"], roll_sigma_deg=out["rs"],
                 position_m=pos, position_cov_m2=pcov, rf_used=used,
                 extra={"state_covariance": states, "nis_rf": nis_rf, "nis_visual": nis_vis, "nis_rf_dof": 1})
