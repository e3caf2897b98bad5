"""A localization CDF: the capsule at a GI-tract site of the default torso, skin sensors, one
trace, TOA ranging by generalized cross-correlation over Monte Carlo trials, and a fix per trial
by each method (constant velocity, joint velocity, model-based on travel-time fields;
docs/localization.md); prints each method's RMSE beside its position CRLB and draws the CDFs of
the 3-D errors.

    python examples/localization_cdf.py [--site small_intestine_1] [--trials 20] [--rays 100000] [--out DIR]
"""

from __future__ import annotations

import numpy as np
from _common import parser, save

from evaluation.localization import evaluate_localization
from plots import localization_cdf
from raytrace.body.torso import default_torso

SENSORS = ["belt_anterior", "belt_left", "belt_posterior", "upper_right", "upper_anterior_left", "upper_left"]


def main(argv=None) -> None:
    p = parser(__doc__)
    p.add_argument("--site", default="small_intestine_1")
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--rays", type=int, default=100_000)
    p.add_argument("--methods", default="nonlinear,joint_velocity,model_based")
    args = p.parse_args(argv)
    ev = evaluate_localization(default_torso(), args.site, SENSORS, ranging="gcc", methods=args.methods.split(","),
                               trials=args.trials, rays=args.rays, seed=0)
    for name, m in ev.methods.items():
        print(f"{name}: RMSE {m.rmse_m * 1e3:.1f} mm, CEP50 {m.cep50_m * 1e3:.1f} mm, CRLB {m.crlb_m * 1e3:.3f} mm")
    methods = []
    for name, m in ev.methods.items():
        errors = np.linalg.norm(m.estimates_m - ev.capsule_position_m, axis=1)
        methods.append({"method": name, "errors_m": errors[np.isfinite(errors)].tolist(), "crlb_m": m.crlb_m})
    save(localization_cdf(methods, title=f"3-D error CDF, capsule at {args.site}, {len(SENSORS)} sensors"),
         args.out, "localization_cdf.png")


if __name__ == "__main__":
    main()
