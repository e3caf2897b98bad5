"""A particle filter on the centreline: many hypotheses of (s, v), weighted by the RF fixes' 3-D
likelihood, so that where the tract folds back near itself both loops stay alive until the
motion tells them apart (docs/tracking.md, "The particle filter").

Particles i = 1..N carry (s_i, v_i) with weights w_i (Gordon, Salmond & Smith 1993; Arulampalam
et al. 2002). Prior: s ~ N(initial_s_m, sigma^2), or uniform on [0, L] when ``initial_s_m`` is None.

* **Propagation** over dt with the Kalman filter's motion model (tracking.kalman): per particle
  (s, v) is Gaussian, mean (s + v dt, v), covariance Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]. With a
  visual advance d (sigma_d), linear in the new s, the particle is drawn from the optimal proposal
  p(s', v' | s, v, d) (Doucet, Godsill & Andrieu 2000, Sec II.D): innovation y = d - v dt,
  S = Q_00 + sigma_d^2, K = Q[:, 0] / S, mean (s + v dt, v) + K y, covariance Q - K K^T S, and its
  weight is multiplied by N(y; 0, S). s is reflected into [0, L].
* **RF fix** p with covariance C: w_i *= N(p; c(s_i), C + lateral_sigma^2 I), the fix's full 3-D
  likelihood at the particle's point -- not its projection, so a fix between two loops favours
  both equally, and the sequence of fixes picks the loop whose motion matches.
* **Resampling**: systematic (Kitagawa 1996) when the effective sample size 1 / sum w_i^2 falls
  below ``resample_fraction`` N, regularised (each copy jittered by the kernel of Musso, Oudjane & Le
  Gland 2001, bandwidth (1/N)^(1/6) of the weighted spread), so that duplicated particles do not
  shrink the reported spread below the posterior's.
* **Roll** depends on no RF measurement, only on the visual roll increments: it is filtered
  exactly by a scalar Kalman filter beside the particles (a Rao-Blackwellised component).

Correlated RF errors (a fix's ``bias_covariance_m2`` B with ``rf_correlation_length_m`` ell, as in
the Kalman filter): each particle carries the mean of the bias and its rate along s, (b_i, b'_i) in
3-D, given its own path, with one (6, 6) covariance P_b for all (Rao-Blackwellised: given the path
the bias is linear-Gaussian). A fix p weighs particle i by N(p; c(s_i) + b_i, C + P_bb) and updates
(b_i, b'_i) by the Kalman gain; between steps both follow the smooth second-order process of
:func:`tracking.kalman.bias_transition` over d, the
particles' mean distance travelled. Without ell the bias counts as white noise (C + B). A fix is
not used while neither the mean s nor the fix's projection has moved ``rf_min_spacing_m`` from the
last used one, unless the particles' points are more spread than the fix (near a junction). An advance
refused by the visual gate is dropped until ``max_consecutive_gated`` refusals in a row (then it is
used: the particles, not the frame pair, are the likelier outlier); one outside ``speed_range_m_per_s``
times dt always.

Reported per step: s = sum w_i s_i and its weighted standard deviation, the same for v; the 3-D
point = sum w_i c(s_i) with the particles' weighted covariance (which keeps the two loops'
spread when both are alive). ``extra``: ``ess`` per step, ``state_covariance`` (the weighted
covariance of (s, v) and the roll's variance), ``nis_rf`` (the fix's innovation against the
particles' mean point, y^T (Cov[c(s) + b] + C + P_b + lateral^2 I)^-1 y, ~chi-square(3) when
consistent),
``nis_visual`` (the advance's innovation against the particles' predicted advance, chi-square(1));
with ``keep_particles=True`` also ``particles_s_m`` and ``weights`` (n, N).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.stats import chi2

from .kalman import bias_transition
from .measurements import Observation, Track, TrackerConfig, check_observations

__all__ = ["particle_track"]


def _reflect(s: np.ndarray, length: float) -> np.ndarray:
    s = np.abs(s)
    return np.where(s > length, np.maximum(2.0 * length - s, 0.0), s)


def _systematic(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    n = len(weights)
    c = np.cumsum(weights)
    c[-1] = 1.0
    return np.searchsorted(c, (rng.random() + np.arange(n)) / n)


def particle_track(line, observations: list[Observation], config: TrackerConfig | None = None, *,
                   name: str = "particle", keep_particles: bool = False,
                   check: Callable[[], None] | None = None) -> Track:
    """Filter ``observations`` along ``line`` with ``config.particles`` particles, seeded by
    ``config.seed`` (module docstring). Raises :class:`~tracking.errors.TrackingInputError`.
    ``check`` (e.g. a request budget's) is called before each step and may raise to stop."""
    cfg = config or TrackerConfig()
    obs = check_observations(observations)
    rng = np.random.default_rng(cfg.seed)
    L = line.length_m
    N = cfg.particles
    if cfg.initial_s_m is None:
        s = rng.uniform(0.0, L, N)
    else:
        s = _reflect(rng.normal(cfg.initial_s_m, cfg.initial_s_sigma_m, N), L)
    v = rng.normal(cfg.initial_v_m_per_s, cfg.initial_v_sigma_m_per_s, N)
    logw = np.full(N, -np.log(N))
    roll, roll_var = 0.0, cfg.initial_roll_sigma_deg ** 2
    q, lat2 = cfg.accel_psd_m2_per_s3, cfg.lateral_sigma_m ** 2
    vgate = None if cfg.visual_gate_probability is None else float(chi2.ppf(cfg.visual_gate_probability, 1))
    rfgate = None if cfg.gate_probability is None else float(chi2.ppf(cfg.gate_probability, 3))
    rf_refused = 0

    n = len(obs)
    cols = {k: np.empty(n) for k in ("s", "ss", "v", "vs", "r", "rs", "ess")}
    nis_rf = np.full(n, np.nan)
    nis_vis = np.full(n, np.nan)
    states = np.zeros((n, 3, 3))
    vis_refused = 0
    ell = cfg.rf_correlation_length_m
    bias = np.zeros((N, 6))  # per particle the mean of the RF bias and its rate along s given its path
    bias_cov = None  # their (6, 6) covariance, shared by the particles, once a fix declared a bias
    bias_stat = None  # the stationary covariance of the bias (the last fix's organ)
    last_fix = None  # (mean s, the fix's projection) when the last fix was used
    pos = np.empty((n, 3))
    pcov = np.empty((n, 3, 3))
    used = np.zeros(n, bool)
    keep_s = np.empty((n, N)) if keep_particles else None
    keep_w = np.empty((n, N)) if keep_particles else None
    for k, o in enumerate(obs):
        if check is not None:
            check()
        if k > 0:
            dt = o.t_s - obs[k - 1].t_s
            Q = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
            mean_s, mean_v = s + v * dt, v
            visual = o.visual
            if visual is not None and cfg.speed_range_m_per_s is not None and not (
                    cfg.speed_range_m_per_s[0] * dt <= visual.advance_m <= cfg.speed_range_m_per_s[1] * dt):
                visual = None  # not a motion the capsule can make
            if visual is not None:
                w = np.exp(logw - logw.max())
                w /= w.sum()
                pred = float(w @ (v * dt))
                spread = float(w @ (v * dt - pred) ** 2)
                y0 = visual.advance_m - pred
                nis0 = y0 * y0 / (spread + Q[0, 0] + visual.advance_sigma_m ** 2)
                if vgate is not None and nis0 > vgate and vis_refused < cfg.max_consecutive_gated:
                    vis_refused += 1  # an outlier pair (Kalman's gate)
                    visual = None
            if visual is not None:
                vis_refused = 0
                nis_vis[k] = nis0
                S = Q[0, 0] + visual.advance_sigma_m ** 2
                y = visual.advance_m - v * dt
                K = Q[:, 0] / S
                mean_s, mean_v = mean_s + K[0] * y, mean_v + K[1] * y
                Q = Q - np.outer(K, K) * S
                logw += -0.5 * y * y / S
                if visual.roll_deg is not None:
                    r_var = roll_var + cfg.roll_psd_deg2_per_s * dt
                    gain = r_var / (r_var + visual.roll_sigma_deg ** 2)
                    roll = roll + gain * visual.roll_deg
                    roll_var = (1.0 - gain) * r_var
                else:
                    roll_var += cfg.roll_psd_deg2_per_s * dt
            else:
                roll_var += cfg.roll_psd_deg2_per_s * dt
            vals, vecs = np.linalg.eigh(0.5 * (Q + Q.T))
            Lq = vecs * np.sqrt(np.maximum(vals, 0.0))
            e = rng.standard_normal((N, 2)) @ Lq.T
            s_before = s
            s = _reflect(mean_s + e[:, 0], L)
            v = mean_v + e[:, 1]
            if bias_cov is not None:  # the bias decorrelates with the distance travelled (one for all)
                w = np.exp(logw - logw.max())
                Fb, Qb = bias_transition(float((w / w.sum()) @ np.abs(s - s_before)), ell)
                F6 = np.kron(Fb, np.eye(3))
                bias = bias @ F6.T
                bias_cov = F6 @ bias_cov @ F6.T + np.kron(Qb, bias_stat)
        rf = o.rf
        if rf is not None and last_fix is not None and cfg.rf_min_spacing_m > 0.0:
            w = np.exp(logw - logw.max())
            z = float(line.project(rf.position_m))
            w = w / w.sum()
            pts0 = line.point_m(s)
            spread = float(w @ np.sum((pts0 - w @ pts0) ** 2, axis=1))
            fix_spread = float(np.trace(rf.covariance_m2) + (0.0 if rf.bias_covariance_m2 is None
                                                              else np.trace(rf.bias_covariance_m2)))
            if abs(float(w @ s) - last_fix[0]) < cfg.rf_min_spacing_m \
                    and abs(z - last_fix[1]) < cfg.rf_min_spacing_m and spread < fix_spread:
                rf = None  # too close to the last used fix (the same bias), and the particles know the point
        if rf is not None:
            w = np.exp(logw - logw.max())
            w /= w.sum()
            C = rf.covariance_m2 + lat2 * np.eye(3)
            B = rf.bias_covariance_m2
            if B is not None and ell is None:  # no correlation model: the bias counts as white noise
                C = C + B
            elif B is not None:
                if bias_cov is None:
                    bias_cov = np.kron(np.diag([1.0, 1.0 / (ell * ell)]), B)
                bias_stat = B
            S = C if bias_cov is None else C + bias_cov[:3, :3]
            pts = line.point_m(s) + bias[:, :3]
            mean_p = w @ pts
            dp = pts - mean_p
            y = rf.position_m - mean_p
            nis = float(y @ np.linalg.solve((dp * w[:, None]).T @ dp + S, y))
            if rfgate is not None and nis > rfgate:
                if rf_refused < cfg.max_consecutive_gated:  # far off every particle: one would take all the weight
                    rf_refused += 1
                    rf = None
        if rf is not None:
            rf_refused = 0
            nis_rf[k] = nis
            d = rf.position_m - pts
            logw += -0.5 * np.einsum("ij,ij->i", d, np.linalg.solve(S, d.T).T)
            if bias_cov is not None:
                K = np.linalg.solve(S, bias_cov[:3, :]).T  # (6, 3): Cov(bias, b) S^-1
                bias = bias + d @ K.T
                bias_cov = bias_cov - K @ bias_cov[:3, :]
                bias_cov = 0.5 * (bias_cov + bias_cov.T)
            used[k] = True
            w = np.exp(logw - logw.max())
            last_fix = (float((w / w.sum()) @ s), float(line.project(rf.position_m)))
        logw -= logw.max()
        w = np.exp(logw)
        w /= w.sum()
        cols["s"][k] = float(w @ s)
        cols["ss"][k] = float(np.sqrt(max(w @ (s - cols["s"][k]) ** 2, 0.0)))
        cols["v"][k] = float(w @ v)
        cols["vs"][k] = float(np.sqrt(max(w @ (v - cols["v"][k]) ** 2, 0.0)))
        cols["r"][k], cols["rs"][k] = roll, np.sqrt(roll_var)
        ds, dv = s - cols["s"][k], v - cols["v"][k]
        states[k, :2, :2] = [[w @ (ds * ds), w @ (ds * dv)], [w @ (ds * dv), w @ (dv * dv)]]
        states[k, 2, 2] = roll_var
        pts = line.point_m(s)
        pos[k] = w @ pts
        dp = pts - pos[k]
        pcov[k] = (dp * w[:, None]).T @ dp
        ess = 1.0 / float(w @ w)
        cols["ess"][k] = ess
        if keep_particles:
            keep_s[k], keep_w[k] = s, w
        if ess < cfg.resample_fraction * N:
            idx = _systematic(w, rng)
            s, v, bias = s[idx], v[idx], bias[idx]
            logw = np.full(N, -np.log(N))
        else:
            logw = np.log(np.maximum(w, 1e-300))
    extra = {"ess": cols["ess"], "state_covariance": states, "nis_rf": nis_rf, "nis_visual": nis_vis,
             "nis_rf_dof": 3}
    if keep_particles:
        extra.update(particles_s_m=keep_s, weights=keep_w)
    return Track(tracker=name, t_s=np.array([o.t_s for o in obs]), s_m=cols["s"], s_sigma_m=cols["ss"],
                 v_m_per_s=cols["v"], v_sigma_m_per_s=cols["vs"], roll_deg=cols["r"], roll_sigma_deg=cols["rs"],
                 position_m=pos, position_cov_m2=pcov, rf_used=used, extra=extra)
