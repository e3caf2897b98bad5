"""Path completeness of the default launch: what a denser launch finds that it misses.

Speed can always be bought by finding fewer paths; this benchmark keeps that trade
visible. The same request is traced at ``rays`` and at ``dense_factor`` x ``rays``;
every path of both is exact (Newton-refined), so the same path has the same delay to
1e-15 s. Reported: how many receivers miss the strongest path the dense launch finds,
and the fraction of the dense launch's paths within 10 dB of a receiver's strongest
that the default launch finds.
"""

from __future__ import annotations

from bench import scenes

SAME_PATH_S = 1e-15
STRONG_DB = 10.0


def completeness(rays: int, interactions: int = 6, dense_factor: int = 4) -> dict:
    phantom = scenes.torso()
    tx = scenes.transmitter(phantom)
    rx = scenes.receivers(phantom)
    base = scenes.trace(phantom, tx, rx, 402e6, rays=rays, max_interactions=interactions)
    dense = scenes.trace(phantom, tx, rx, 402e6, rays=dense_factor * rays, max_interactions=interactions)
    strongest_missed, strong, found = 0, 0, 0
    for lo, hi in zip(base.profiles, dense.profiles):
        if not hi.paths:
            continue
        have = [p.delay_s for p in lo.paths]

        def seen(path) -> bool:
            return any(abs(d - path.delay_s) < SAME_PATH_S for d in have)

        top = max(hi.paths, key=lambda p: abs(p.gain))
        strongest_missed += not seen(top)
        for p in hi.paths:
            if abs(p.gain) >= abs(top.gain) * 10 ** (-STRONG_DB / 20):
                strong += 1
                found += seen(p)
    return {"rays": rays, "dense_rays": dense_factor * rays, "receivers": len(rx),
            "strongest_missed": strongest_missed, "strong_paths": strong, "strong_found": found,
            "strong_found_fraction": found / strong if strong else 1.0}
