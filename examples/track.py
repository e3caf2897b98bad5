"""A track along the GI tract: a simulated capsule journey on the default torso's centreline, RF
fixes from traced channels and the video's motion estimates (their error model), fused by a
Kalman filter and a particle filter (docs/tracking.md); prints each tracker's RMSE along the
tract and draws the arc length over time, truth and trackers with their +-2 sigma.

    python examples/track.py [--steps 120] [--rays 20000] [--seed 0] [--out DIR]
"""

from __future__ import annotations

from _common import parser, save

from evaluation.tracking import evaluate_tracking
from plots.tracking import tracking_trajectory
from tracking import JourneySpec


def main(argv=None) -> None:
    p = parser(__doc__)
    p.add_argument("--steps", type=int, default=120)
    p.add_argument("--rays", type=int, default=20_000)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    ev = evaluate_tracking(JourneySpec(steps=args.steps, seed=args.seed), ["rf", "video", "fused", "fused_pf"],
                           rays=args.rays)
    for name, rmse in ev.rmse_along_m.items():
        print(f"{name}: RMSE along the tract {rmse * 1e3:.1f} mm")
    series = [{"name": n, "s_m": t.s_m.tolist(), "s_sigma_m": t.s_sigma_m.tolist()} for n, t in ev.tracks.items()]
    save(tracking_trajectory(ev.journey.t_s.tolist(), ev.journey.s_m.tolist(), series,
                             title=f"Tracking along the GI tract, {args.steps} frames"), args.out, "track.png")


if __name__ == "__main__":
    main()
