"""Earlier (untraced) arrivals stated per link in the profile (evaluation/arrivals.py).

Oracle: the eikonal first arrival (scikit-fmm on the phantom's voxels), which shares no code with
the tracer; docs/localization.md lists the four torso links (402 MHz, 4 mm cells, 1e5 rays) where it
precedes every traced path by 0.5-2.3 ns (a head wave along the subcutaneous fat)."""

from __future__ import annotations

import pytest

import raytrace as rt
from evaluation.arrivals import FLAG, annotate

#: (capsule, sensor) -> the eikonal lead over the first traced path [ns] (docs/localization.md).
HEAD_WAVES = {("stomach", "upper_right"): 0.65, ("ascending_colon", "belt_left"): 0.51,
              ("ascending_colon", "upper_left"): 2.12, ("descending_colon", "upper_right"): 2.31}


@pytest.mark.slow
def test_the_torsos_head_wave_links_say_so_in_their_profiles():
    """Each capsule of the four head-wave links to its sensors and to belt_anterior (a link whose
    first traced path is the first arrival): the head-wave links carry ``earlier_arrival`` with the
    documented lead (within 0.15 ns: the 4 mm grid's stated error is 0.12 ns), the others only
    ``first_arrival_s`` within that error of their first path."""
    torso = rt.get_phantom("torso")
    for capsule in ("stomach", "ascending_colon", "descending_colon"):
        sensors = [s for (c, s) in HEAD_WAVES if c == capsule] + ["belt_anterior"]
        spec = rt.ChannelSpec(rt.Antenna(site=capsule), [rt.Antenna(site=s) for s in sensors], frequency_hz=402e6,
                              rays=100_000, max_interactions=6)
        result = annotate(rt.trace_channel(spec, torso), torso)
        for prof, sensor in zip(result.profiles, sensors):
            assert prof.first_arrival_s is not None
            lead = HEAD_WAVES.get((capsule, sensor))
            if lead is None:
                assert FLAG not in prof.validity and prof.earlier_arrival_s is None
                assert abs(prof.first_path_delay_s - prof.first_arrival_s) < 0.15e-9
            else:
                assert FLAG in prof.validity, (capsule, sensor)
                assert abs(prof.earlier_arrival_s - lead * 1e-9) < 0.15e-9, (capsule, sensor, prof.earlier_arrival_s)
