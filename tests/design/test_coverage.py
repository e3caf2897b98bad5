"""Coverage over the skin (docs/design.md, "Coverage"): candidates where contact sensors go, every
row the channel a single-receiver request gives, the link budget's SNR, the work bound."""

from __future__ import annotations

import numpy as np
import pytest

import raytrace as rt
from design.candidates import CandidateSpec, outer_organs, skin_candidates
from design.coverage import LIMITS, Limits, load, make_plan, normalise_spec
from design.errors import DesignInputError
from estimators.constants import velocity_m_per_s
from estimators.link import LinkBudget
from estimators.profile import PathProfile
from estimators.toa import estimate_toa
from estimators.waveforms import ToneBurst
from raytrace.body.torso import default_torso
from tests.design.conftest import TINY_COVERAGE


def test_candidates_lie_in_the_outer_organ_at_depth_and_at_least_the_spacing_apart():
    phantom = default_torso()
    assert [phantom.organs[i].name for i in outer_organs(phantom)] == ["skin"]
    c = skin_candidates(phantom, CandidateSpec(spacing_m=0.04, include_sites=False))
    assert len(c) > 100 and set(c.organ) == {"skin"}
    media = phantom.medium_index(c.positions_m)
    assert np.all(media == phantom.organ_index("skin"))
    # thinned on the surface, then moved 1 mm inwards: on a convex surface of radius R two points come
    # closer by the factor 1 - depth / R (the torso's rims: R >= 20 mm, so at most 5 %)
    d = np.linalg.norm(c.positions_m[:, None] - c.positions_m[None], axis=2) + np.eye(len(c)) * 9
    assert d.min() >= 0.04 * (1 - 0.001 / 0.02)
    again = skin_candidates(phantom, CandidateSpec(spacing_m=0.04, include_sites=False))
    assert np.array_equal(again.positions_m, c.positions_m)  # seeded: the same grid every time
    with_sites = skin_candidates(phantom, CandidateSpec(spacing_m=0.04))
    assert with_sites.site[-12:] == tuple(n for n, s in phantom.sites.items() if s.kind == "sensor")


def test_every_row_is_what_a_single_channel_request_answers(tiny_coverage):
    """One trace per capsule position serves every candidate; each row must equal the channel of a
    one-receiver request with the same knobs, exactly (the receivers of a trace are independent)."""
    record, plan, table = load(tiny_coverage)
    rows = table.to_pylist()
    C = len(plan.candidates)
    phantom = default_torso()
    link = LinkBudget()
    checked = 0
    for p in range(len(plan.positions)):
        for c in (0, C // 3, C - 12, C - 1):  # two grid candidates, two sensor sites
            row = rows[p * C + c]
            assert row["position_index"] == p and row["candidate_index"] == c
            spec = rt.ChannelSpec(rt.Antenna(plan.positions.positions_m[p]),
                                  (rt.Antenna(plan.candidates.positions_m[c]),), phantom="torso",
                                  rays=3000, max_interactions=2, dynamic_range_db=30.0)
            prof = rt.trace_channel(spec, phantom).profiles[0]
            assert row["paths"] == len(prof.paths)
            if prof.paths:
                assert row["first_delay_s"] == prof.paths[0].delay_s
                # the ranging column: what TOA (GCC) answers without noise on that channel, back to seconds
                toa = estimate_toa(PathProfile.from_traced(prof.paths, 402e6), method="gcc",
                                   waveform=ToneBurst(carrier_hz=402e6, duration_s=25e-9, sample_rate_hz=20e9),
                                   snr_db=None, trials=1, return_estimates=True)[0]
                assert row["ranging_delay_s"] == toa.estimates_m[0] / velocity_m_per_s(27.9)
                assert row["path_gain_db"] == prof.path_gain_db
                assert row["direct_path"] == any(all(i.kind == "refraction" for i in q.interactions)
                                                 for q in prof.paths)
                # S24 with the default link (MICS EIRP, 0 dB noise figure, 290 K) over fs / 2 = 10 GHz
                assert row["snr_db"] == pytest.approx(link.transmit_power_dbm + prof.path_gain_db
                                                      - link.noise_power_dbm(10e9), abs=1e-9)
                checked += 1
            else:
                assert row["first_delay_s"] is None and row["snr_db"] is None and row["ranging_delay_s"] is None
    assert checked >= 4


def test_bad_coverage_requests_name_the_field():
    phantom = default_torso()
    spec = normalise_spec({**TINY_COVERAGE, "candidates": {"region": {"min_m": [5, 5, 5], "max_m": [6, 6, 6]}}})
    with pytest.raises(DesignInputError) as e:
        make_plan(spec, phantom)
    assert e.value.field == "candidates.region"
    with pytest.raises(DesignInputError) as e:
        make_plan(normalise_spec({**TINY_COVERAGE, "positions": {"sites": ["nowhere"]}}), phantom)
    assert e.value.field == "positions.sites[0]"
    with pytest.raises(DesignInputError) as e:
        make_plan(normalise_spec({"positions": {"along_tract": {"ds_m": 0.01}}}), phantom, Limits(max_links=1000))
    assert e.value.field in ("positions", "candidates.spacing_m")
    for bad, field in (({"channel": {"rays": 0}}, "channel.rays"), ({"frequency_hz": "402e6"}, "frequency_hz"),
                       ({"surprise": 1}, "surprise"), ({"positions": {"sites": [], "positions_m": []}}, "positions"),
                       ({"link": {"noise_figure_db": -3}}, "link.noise_figure_db")):
        with pytest.raises(DesignInputError) as e:
            normalise_spec({**TINY_COVERAGE, **bad}, LIMITS)
        assert e.value.field == field, (bad, e.value.field)
