"""The thesis' Fig 5.6 channel: a transmitter 76 mm from a receiver in a lossless eps_r 27.9 slab,
three paths (the direct one at 1.339 ns and two reflections); prints them and draws the
power-delay profile.

    python examples/fig_5_6_channel.py [--rays 20000] [--out DIR]
"""

from __future__ import annotations

import dataclasses

from _common import parser, profile_json, save

import raytrace as rt
from plots import power_delay_profile


def main(argv=None) -> None:
    p = parser(__doc__)
    p.add_argument("--rays", type=int, default=20_000, help="rays launched (default 20000)")
    args = p.parse_args(argv)
    spec = dataclasses.replace(rt.get_scenario("thesis-fig-5-6").spec, rays=args.rays)  # the scenario, fewer rays
    result = rt.trace_channel(spec)
    profile = result.profiles[0]
    for path in profile.paths:
        print(f"path: delay {path.delay_s * 1e9:.4f} ns, gain {path.gain_db:.2f} dB, "
              f"{[i.kind for i in path.interactions] or 'direct'}")
    save(power_delay_profile(profile_json(profile, spec.frequency_hz), relative_permittivity=27.9,
                             title="Thesis Fig 5.6: the three-path slab"), args.out, "fig_5_6_pdp.png")


if __name__ == "__main__":
    main()
