"""Golden channels: the same requests give the same paths across refactors.

Recorded from the tracer before the package was reorganised (issue 16) and
re-checked after every change that must not alter behaviour. Delays must agree
within 1e-15 s, complex gains within 1e-9 relative, interaction kinds exactly.
The tolerances are far below any physical meaning (1e-15 s is 0.3 um of path in
air) and above the last-bit noise of a different summation order.

Re-record only when a change is meant to alter answers, and say which in the
commit: ``python -m tests.raytrace.test_golden_channels --record``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

import raytrace as rt
from raytrace.body.torso import BELT_SITES, UPPER_SITES

GOLDEN = Path(__file__).parent / "data" / "golden_channels.json"
DELAY_TOL_S = 1e-15
GAIN_RTOL = 1e-9


def _torso_case(capsule, sensors, frequency_hz, band=None):
    spec = rt.ChannelSpec(rt.Antenna(site=capsule), [rt.Antenna(site=s) for s in sensors], frequency_hz=frequency_hz,
                          band=band, max_interactions=6, rays=100_000, dynamic_range_db=80.0)
    return rt.trace_channel(spec)


def _scenario_case(sid):
    return rt.trace_channel(rt.get_scenario(sid).spec)


CASES = {
    # the README's torso band request
    "readme-torso-band": lambda: _torso_case("small_intestine_1", ["belt_anterior", "belt_left"], 402e6,
                                             rt.Band(400e6, 420e6, 21)),
    "scenario-thesis-fig-5-6": lambda: _scenario_case("thesis-fig-5-6"),
    "scenario-layered-slab": lambda: _scenario_case("layered-slab"),
    # the other WCE band, every sensor
    "torso-2.45GHz": lambda: _torso_case("stomach", list(UPPER_SITES + BELT_SITES), 2.45e9),
}


def _summary(result) -> list[dict]:
    out = []
    for prof in result.profiles:
        paths = []
        for p in prof.paths:
            item = {
                "delay_s": p.delay_s,
                "gain": [p.gain.real, p.gain.imag],
                "kinds": [i.kind for i in p.interactions],
                "media": [s.medium for s in p.segments],
            }
            if p.band_gains is not None:
                item["band_gains"] = [[g.real, g.imag] for g in p.band_gains]
            paths.append(item)
        out.append({"receiver": prof.receiver, "paths": paths})
    return out


def record() -> None:
    GOLDEN.write_text(json.dumps({k: _summary(f()) for k, f in CASES.items()}, indent=1) + "\n")


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(CASES))
def test_same_paths_as_recorded(case):
    expected = json.loads(GOLDEN.read_text())[case]
    got = _summary(CASES[case]())
    assert [p["receiver"] for p in got] == [p["receiver"] for p in expected]
    for g_rx, e_rx in zip(got, expected):
        assert len(g_rx["paths"]) == len(e_rx["paths"]), g_rx["receiver"]
        for g, e in zip(g_rx["paths"], e_rx["paths"]):
            assert g["kinds"] == e["kinds"] and g["media"] == e["media"]
            assert abs(g["delay_s"] - e["delay_s"]) <= DELAY_TOL_S
            ge, ee = complex(*g["gain"]), complex(*e["gain"])
            assert abs(ge - ee) <= GAIN_RTOL * abs(ee)
            if "band_gains" in e:
                gb = np.array([complex(*x) for x in g["band_gains"]])
                eb = np.array([complex(*x) for x in e["band_gains"]])
                np.testing.assert_allclose(gb, eb, rtol=GAIN_RTOL, atol=0)


if __name__ == "__main__" and "--record" in sys.argv:
    record()
