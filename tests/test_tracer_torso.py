"""Tracer on the default torso (many nested, curved, faceted organs): integration checks.

Oracles: the phantom's own point-in-organ lookup (``Phantom.medium_index``, an
independent Embree probe) for every segment's medium; the delay/length sums
recomputed from the segments; geometry-only invariants. Modest ray counts keep
the test fast; it checks consistency, not the channel's values.
"""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.em import C0
from raytrace.paths import Antenna
from raytrace.tracer import trace_channel

torso = pytest.importorskip("raytrace.torso")


@pytest.fixture(scope="module")
def phantom():
    return torso.default_torso()


def test_torso_paths_are_consistent_with_the_phantom(phantom):
    capsules = [s for s in phantom.sites.values() if s.kind == "capsule"][:3]
    sensors = [Antenna(s.position_m, name=s.name) for s in phantom.sites.values() if s.kind == "sensor"]
    total = 0
    for cap in capsules:
        # 6 interactions: leaving the torso alone takes 4 refractions (organ, muscle wall,
        # fat, skin), so reflections need at least 5.
        res = trace_channel(phantom, Antenna(cap.position_m), sensors, 402e6, rays=20000, max_interactions=6)
        assert res.transmitter_medium == cap.medium
        for prof in res.profiles:
            delays = [p.delay_s for p in prof.paths]
            assert delays == sorted(delays)
            for path in prof.paths:
                assert np.isfinite(path.gain) and abs(path.gain) > 0
                assert len(path.interactions) <= 6 or all(i.kind == "refraction" for i in path.interactions)
                starts = np.array([s.start_m for s in path.segments])
                ends = np.array([s.end_m for s in path.segments])
                assert np.allclose(starts[0], cap.position_m) and np.allclose(ends[-1], prof.position_m)
                assert np.allclose(starts[1:], ends[:-1])
                mids = 0.5 * (starts + ends)
                assert phantom.medium_names(phantom.medium_index(mids)) == [s.medium for s in path.segments]
                assert abs(sum(s.length_m for s in path.segments) - path.length_m) < 1e-12
                # the delay is sum L_i Re(n_i) / c: at least the geometric length / c
                assert path.delay_s > path.length_m / C0
                total += 1
    assert total > 10
