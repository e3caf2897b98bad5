"""Localization accuracy in the literature's format, our rows beside the published ones
(docs/localization.md, "Beside the literature"; the README's localization section).

    python -m evaluation.literature

Columns as the capsule-localization literature tabulates them (e.g. Table 4 of the 2023 comparison
cited below): method, band, sensors, 2-D / 3-D, RMSE (and CEP90 where known), how it was validated.
Our rows are computed by this command (the localization acceptance run of evaluation.localization and
the journey evaluation of evaluation.tracking, ~2 min once the numba kernels are compiled); the
published rows are quoted with their sources. Ranging rows (the thesis') are 1-D distance errors of
one link, not positions: they say what a sensor contributes, and are marked so.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class Row:
    method: str
    band: str
    sensors: str
    dims: str
    rmse: str
    cep90: str
    validated: str
    source: str


#: Published numbers, quoted with where they come from.
PUBLISHED = (
    Row("TOA ranging, GCC, one link (thesis Ch. 4)", "MICS 402 MHz tone, 25 ns", "1 (ranging)", "1-D range",
        "max 1.85 homogeneous / 9.5 heterogeneous", "", "FDTD body model, 4 capsule-sensor distances, 30 dB",
        "[T] Sec. 4.4, Figs. 4.4-4.5"),
    Row("TOA ranging, first peak / all peaks (thesis Ch. 4)", "MICS 402 MHz", "1 (ranging)", "1-D range",
        "max 5.02 / 3.30 homogeneous, 17.7 / 14.2 heterogeneous", "", "FDTD body model, 30 dB",
        "[T] Sec. 4.4, Figs. 4.4-4.5"),
    Row("PDOA ranging, 21-tone regression (thesis Ch. 5)", "400-420 MHz / 2440-2460 MHz", "1 (ranging)", "1-D range",
        "error 5 / 11.4", "", "ray tracing, the three-path eps_r 27.9 slab case, 76 mm", "[T] Table 5.2"),
    Row("UWB path-loss weighted centroid (SPLD-WCL)", "UWB", "48", "3-D", "6.83", "",
        "in-body to on-body in vivo measurements", "[H23] Tables 3-4"),
    Row("RSSI maximum likelihood with a particle filter", "MICS", "8", "3-D", "7.0", "",
        "FDTD simulation, small intestine", "[H23] Table 4 (its ref. [11])"),
    Row("Hybrid video + RF (data fusion)", "MICS", "16", "3-D", "23", "",
        "partially: PillCam image dataset", "[B15] as tabulated in [H23] Table 4 (its ref. [5])"),
    Row("Hybrid RF + image processing, posterior CRLB", "MICS", "many", "3-D", "bound: within 30", "",
        "bound (PCRLB), numerical", "[G15]"),
)

REFERENCES = """\
[T] M. Zhou, "On the Accuracy of Wireless Capsule Endoscope RF and Visual Localization", MSc thesis,
    Worcester Polytechnic Institute, 2015 (advisor K. Pahlavan).
[H23] "Accuracy of UWB Path Loss-Based Localization of Wireless Capsule Endoscopy", Journal of
    Healthcare Engineering, 2023, article 3156013 (Hindawi), Tables 3 and 4.
[B15] G. Bao, K. Pahlavan, L. Mi, "Hybrid localization of microrobotic endoscopic capsule inside small
    intestine by data fusion of vision and RF sensors" (IEEE Sensors Journal, 2015; the thesis' ref. [73]).
[G15] "On the accuracy of RF and image processing based hybrid localization for wireless capsule
    endoscopy" (Pahlavan's group at WPI, 2015): the 3-D posterior CRLB of hybrid localization; "the RMSE
    of hybrid WCE localization can be limited within 3 cm" with accurate enough image processing or
    enough on-body receivers."""


def our_rows(trials: int = 20, seed: int = 0, runs: int = 20) -> list[Row]:
    """Our rows, computed (module docstring)."""
    from evaluation.localization import acceptance_rows
    from evaluation.tracking import evaluate_tracking
    from tracking import JourneySpec

    rows = acceptance_rows(trials=trials, seed=seed)

    def pooled(method: str) -> tuple[float, float]:
        err = np.concatenate([np.linalg.norm(r.methods[method].estimates_m - r.capsule_position_m, axis=1)
                              for r in rows])
        err = err[np.isfinite(err)]
        return float(np.sqrt(np.mean(err**2))), float(np.percentile(err, 90))

    first = np.array([r.methods["model_based"].extra["first_path_error_m"] for r in rows])
    validated = f"ray-traced torso (this repository), 6 capsule sites x {trials} trials"
    out = []
    for method, label in (("model_based", "TOA (GCC, 30 dB), model-based fix on travel-time fields"),
                          ("joint_velocity", "TOA (GCC, 30 dB), joint position and velocity"),
                          ("nonlinear", "TOA (GCC, 30 dB), least squares at eps_r 27.9")):
        rmse, cep90 = pooled(method)
        out.append(Row(f"**ours**: {label}", "MICS 402 MHz tone, 25 ns", "12", "3-D", f"{rmse * 1e3:.1f}",
                       f"{cep90 * 1e3:.1f}", validated, "this repository"))
    out.append(Row("**ours**: model-based fix from the exact first arrivals (phase delays)", "402 MHz", "12", "3-D",
                   f"{np.sqrt(np.mean(first**2)) * 1e3:.1f}", f"{np.percentile(first, 90) * 1e3:.1f}",
                   "ray-traced torso, 6 capsule sites (no ranging noise)", "this repository"))
    ev = evaluate_tracking(JourneySpec(steps=120, seed=seed), runs=runs)
    for name, label in (("fused_pf", "hybrid video + RF, particle filter"), ("fused", "hybrid video + RF, Kalman")):
        out.append(Row(f"**ours**: {label}", "MICS 402 MHz", "12", "3-D", f"{ev.rmse_3d_m[name] * 1e3:.1f}",
                       f"{ev.cep90_3d_m[name] * 1e3:.1f}",
                       f"ray-traced RF and the torso's measured video error model, 120-frame journey x {runs} runs",
                       "this repository"))
    return out


def markdown(rows: Sequence[Row]) -> str:
    head = ("| method | band | sensors | 2-D / 3-D | RMSE [mm] | CEP90 [mm] | how validated | source |\n"
            "|---|---|---|---|---|---|---|---|")
    return "\n".join([head] + [f"| {r.method} | {r.band} | {r.sensors} | {r.dims} | {r.rmse} | {r.cep90} | "
                               f"{r.validated} | {r.source} |" for r in rows])


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="The localization table of docs/localization.md and the README.")
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--runs", type=int, default=20)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    print(markdown([*our_rows(args.trials, args.seed, args.runs), *PUBLISHED]))
    print()
    print(REFERENCES)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
