"""The layout criterion: the position error bound along the tract (docs/design.md, "The criterion").

For a capsule position x_p and a set S of sensors, each usable link (p, c) measures a delay
tau_pc = T_c(x_p) + e, e ~ N(0, sigma_pc^2), with T_c the heterogeneity-aware travel-time model
(:mod:`design.model`) and sigma_pc the ranging method's delay bound at the link's SNR. The
position Fisher information is (docs/localization.md, "Bounds", model-based rows)

    F_p(S) = sum_{c in S, usable} u_pc u_pc^T,   u_pc = grad_x T_c(x_p) / sigma_pc,

and the position bound b_p(S) = sqrt(trace((F_p(S) + I / sigma_0^2)^-1)), the RMS 3-D error bound
(the ``crlb_m`` of the localization endpoints). The small prior term I / sigma_0^2, sigma_0 the
phantom's size (its bounding-box diagonal: the capsule is somewhere in the body), keeps b_p
finite for every set; where F_p is well conditioned it changes b_p by (b_p / sigma_0)^2 relative,
below 1e-8 for bounds under 0.1 mm.

A position is *covered* when at least ``min_sensors`` of S have a usable link there (4: the
model-based fix needs four delays). The criterion is a statistic of b_p over the positions, with
b_p = infinity at an uncovered position: ``mean``, or ``p90`` (the nearest-rank 90th percentile:
the ceil(0.9 P)-th smallest). The search minimises the pair (uncovered positions, statistic of
the prior-regularised b_p) lexicographically: first cover the whole tract, then lower the bound.

With ``mismatch`` (the layout's ``model_error: bias``) the criterion also carries the delay model's
own error: each link's mismatch m_pc (its noiseless ranging delay minus its eikonal delay, over sigma_pc)
biases the weighted fix by dx_p = F_p^-1 sum_c u_pc m_pc to first order, and b_p becomes
sqrt(trace(F_p^-1) + |dx_p|^2), a mean-square error rather than a bound.

A link is usable when the coverage found a path (with ``require_direct_path``, a refraction-only
one: the first arrival the model predicts) and its SNR is at least ``min_snr_db`` (when given).
The delay bound is the TOA bound of the coverage's waveform (docs/science.md (S15); a tone burst:
the single-tone bound over W = fs / 2, the per-sample SNR's bandwidth), which scales as
10^(-snr_db / 20).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.bounds import waveform_toa_crlb

STATISTICS = ("mean", "p90")
#: Candidate columns scored together (P x block x 3 floats at a time).
_BLOCK_ELEMENTS = 2_000_000


def toa_sigma_s(snr_db: np.ndarray, waveform) -> np.ndarray:
    """Delay bound [s] of the TOA waveform at each SNR [dB] (per sample, W = fs / 2)."""
    s0 = waveform_toa_crlb(waveform, 0.0, waveform.sample_rate_hz / 2.0).sigma_s
    return s0 * 10.0 ** (-np.asarray(snr_db, float) / 20.0)


def statistic(values: np.ndarray, kind: str, axis: int = 0) -> np.ndarray:
    """``mean`` or nearest-rank ``p90`` of ``values`` along ``axis`` (infinities allowed)."""
    if kind == "mean":
        with np.errstate(invalid="ignore"):
            return np.mean(values, axis=axis)
    n = values.shape[axis]
    k = int(np.ceil(0.9 * n)) - 1
    return np.take(np.partition(values, k, axis=axis), k, axis=axis)


@dataclass
class Problem:
    """What the search needs: per (position, candidate) the information vector ``info`` (P, C, 3)
    [1/m] (zero where the link is not usable), ``usable`` (P, C), the statistic, the sensors a
    position needs to be covered and the prior ``prior_m``."""

    info: np.ndarray
    usable: np.ndarray
    kind: str = "p90"
    min_sensors: int = 4
    prior_m: float = 1.0
    #: (P, C) each link's model mismatch over its sigma (zero where unusable), or None: the bound alone
    mismatch: np.ndarray | None = None

    @property
    def positions(self) -> int:
        return self.info.shape[0]

    @property
    def candidates(self) -> int:
        return self.info.shape[1]

    def information(self, subset) -> np.ndarray:
        """(P, 3, 3) F_p(S) + I / sigma_0^2."""
        u = self.info[:, np.asarray(subset, np.int64), :]
        return np.einsum("pki,pkj->pij", u, u) + np.eye(3) / self.prior_m**2

    def counts(self, subset) -> np.ndarray:
        return self.usable[:, np.asarray(subset, np.int64)].sum(axis=1)

    def bounds_m(self, subset) -> np.ndarray:
        """(P,) the regularised bounds b_p (module docstring), with the linearised bias when the
        problem has link mismatches: sqrt(b_p^2 + |F^-1 sum u_pc m_pc|^2)."""
        inv = np.linalg.inv(self.information(subset))
        var = np.clip(np.trace(inv, axis1=1, axis2=2), 0.0, None)
        if self.mismatch is not None:
            idx = np.asarray(subset, np.int64)
            dx = np.einsum("pij,pj->pi", inv, np.einsum("pki,pk->pi", self.info[:, idx, :], self.mismatch[:, idx]))
            var = var + np.einsum("pi,pi->p", dx, dx)
        return np.sqrt(var)

    def key(self, subset) -> tuple[int, float]:
        """(uncovered positions, statistic of the regularised bounds): what the search minimises."""
        uncovered = int(np.sum(self.counts(subset) < self.min_sensors))
        return uncovered, float(statistic(self.bounds_m(subset), self.kind))

    def evaluate(self, subset) -> dict:
        """The criterion of ``subset``: per-position bounds (inf where uncovered), the statistic
        (None when infinite), the uncovered count and the search key."""
        b = self.bounds_m(subset)
        covered = self.counts(subset) >= self.min_sensors
        strict = np.where(covered, b, np.inf)
        value = float(statistic(strict, self.kind))
        return {"bounds_m": strict, "criterion_m": value if np.isfinite(value) else None,
                "uncovered": int((~covered).sum()), "key": self.key(subset), "counts": self.counts(subset)}

    def scores(self, base, cands: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The key of ``base + [c]`` for every c of ``cands`` (vectorised: Sherman-Morrison on the
        base's information): (uncovered (K,), statistic (K,))."""
        cands = np.asarray(cands, np.int64)
        inv = np.linalg.inv(self.information(base))
        tr = np.trace(inv, axis1=1, axis2=2)
        cnt = self.counts(base)
        base_idx = np.asarray(base, np.int64)
        if self.mismatch is not None:
            rhs = np.einsum("pki,pk->pi", self.info[:, base_idx, :], self.mismatch[:, base_idx])
            dx = np.einsum("pij,pj->pi", inv, rhs)
        out_u = np.empty(len(cands), np.int64)
        out_v = np.empty(len(cands))
        block = max(1, _BLOCK_ELEMENTS // max(self.positions, 1))
        for lo in range(0, len(cands), block):
            idx = cands[lo:lo + block]
            u = self.info[:, idx, :]  # (P, K, 3)
            v = np.einsum("pij,pkj->pki", inv, u)
            num = np.einsum("pki,pki->pk", v, v)
            den = 1.0 + np.einsum("pki,pki->pk", u, v)
            var = np.clip(tr[:, None] - num / den, 0.0, None)
            if self.mismatch is not None:  # Sherman-Morrison on F^-1 (b + u m): dx + v m - v (v.b + (v.u) m) / den
                m = self.mismatch[:, idx]
                vb = np.einsum("pki,pi->pk", v, rhs)
                uv = den - 1.0
                coef = m - (vb + uv * m) / den
                new = dx[:, None, :] + v * coef[:, :, None]
                var = var + np.einsum("pki,pki->pk", new, new)
            b = np.sqrt(var)
            covered = (cnt[:, None] + self.usable[:, idx]) >= self.min_sensors
            out_u[lo:lo + block] = self.positions - covered.sum(axis=0)
            out_v[lo:lo + block] = statistic(b, self.kind, axis=0)
        return out_u, out_v
