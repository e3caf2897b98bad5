"""The sweep spec: every rule names its field (as the requests' do), defaults are explicit, YAML
reads numbers as numbers, limits hold, and the phantom-dependent checks happen at planning."""

from __future__ import annotations

import json

import numpy as np
import pytest

from raytrace.body.torso import default_torso
from raytrace.errors import InputError, NotFoundError
from sweeps.experiments import builtin_specs
from sweeps.plan import make_plan
from sweeps.spec import Limits, SweepSpec, SweepSpecError, load_spec, parse_text

BASE = {"capsule_positions": [{"site": "stomach"}], "receivers": [{"site": "belt_anterior"}]}


def spec(**changes):
    return SweepSpec.from_dict({**BASE, **changes})


@pytest.mark.parametrize("changes,field", [
    ({"capsule_positions": []}, "capsule_positions"),
    ({"capsule_positions": [{"site": "a", "s_m": 0.1}]}, "capsule_positions[0]"),
    ({"capsule_positions": [{"position_m": [0, 0]}]}, "capsule_positions[0].position_m"),
    ({"capsule_positions": [{"s_m": -1}]}, "capsule_positions[0].s_m"),
    ({"capsule_positions": [{"site": "stomach", "colour": 1}]}, "capsule_positions[0].colour"),
    ({"capsule_positions": {"along_tract": {}}}, "capsule_positions.along_tract.ds_m"),
    ({"capsule_positions": {"along_tract": {"ds_m": 0}}}, "capsule_positions.along_tract.ds_m"),
    ({"receivers": []}, "receivers"),
    ({"receivers": [{"site": "a"}, {"site": "a"}]}, "receivers[1].name"),
    ({"receivers": [{"position_m": [0, 0, float("nan")]}]}, "receivers[0].position_m"),
    ({"frequencies_hz": [402e6, 1.0e12]}, "frequencies_hz[1]"),
    ({"frequencies_hz": [402e6, 402e6]}, "frequencies_hz"),
    ({"channel": {"rays": 0}}, "channel.rays"),
    ({"channel": {"rays": 10_000_000}}, "channel.rays"),
    ({"channel": {"max_interactions": 0}}, "channel.max_interactions"),
    ({"channel": {"dynamic_range_db": 400}}, "channel.dynamic_range_db"),
    ({"channel": {"band": {"start_hz": 4e8, "stop_hz": 3e8, "points": 3}}}, "channel.band.stop_hz"),
    ({"channel": {"band": {"span_hz": 20e6}}}, "channel.band.points"),
    ({"channel": {"homogeneous": {"tissue": "unobtainium"}}}, "channel.homogeneous.tissue"),
    ({"channel": {"capsule_polarization": [0, 0, 0]}}, "channel.capsule_polarization"),
    ({"channel": {"capsule_pattern": "horn"}}, "channel.capsule_pattern"),
    ({"channel": {"laser": True}}, "channel.laser"),
    ({"ranging": {"toa": {"methods": ["gcc", "magic"]}}}, "ranging.toa.methods[1]"),
    ({"ranging": {"toa": {"waveform": {"sample_rate_hz": 0.7e9}}}}, "ranging.toa.waveform.sample_rate_hz"),
    ({"ranging": {"toa": {"methods": ["first_peak"], "waveform": {"sample_rate_hz": 1.2e9}}}},
     "ranging.toa.waveform.sample_rate_hz"),
    ({"ranging": {"toa": {"waveform": {"carrier_hz": 1e9}}}}, "ranging.toa.waveform.carrier_hz"),
    ({"ranging": {"toa": {"snr_db": 500}}}, "ranging.toa.snr_db"),
    ({"ranging": {"pdoa": {"methods": ["regression"], "points": 2}}}, "ranging.pdoa.points"),
    ({"ranging": {"rss": {"model": "cm9"}}}, "ranging.rss.model"),
    ({"ranging": {"rss": {"model": {"exponent": 3, "shadowing_db": 1}}}}, "ranging.rss.model.path_loss_d0_db"),
    ({"ranging": {"relative_permittivity": 0.5}}, "ranging.relative_permittivity"),
    ({"localization": {"methods": [{"name": "telepathy"}]}}, "localization.methods[0].name"),
    ({"trials": 0}, "trials"),
    ({"trials": 10_001}, "trials"),
    ({"seed": -1}, "seed"),
    ({"seed": 1.5}, "seed"),
    ({"chunk_positions": 0}, "chunk_positions"),
    ({"unknown": 1}, "unknown"),
])
def test_invalid_specs_name_the_field(changes, field):
    with pytest.raises(SweepSpecError) as info:
        spec(**changes)
    assert info.value.field == field, info.value.reason
    assert isinstance(info.value, InputError)  # the service's 422


def test_defaults_are_explicit_and_the_normal_form_round_trips():
    s = spec()
    d = s.to_dict()
    assert d["phantom"] == "torso" and d["frequencies_hz"] == [402e6] and d["trials"] == 100 and d["seed"] == 0
    assert d["channel"] == {"max_interactions": 6, "rays": 100_000, "dynamic_range_db": 80.0, "homogeneous": None,
                            "near_field": True,
                            "band": None, "capsule_polarization": [0.0, 0.0, 1.0], "capsule_pattern": "isotropic"}
    again = SweepSpec.from_dict(json.loads(json.dumps(d)))
    assert again.to_dict() == d and again.sha256 == s.sha256
    assert spec(seed=1).sha256 != s.sha256


def test_yaml_reads_exponent_numbers_as_numbers():
    data = parse_text("frequencies_hz: [402e6, 2.45e9, 1E9]\nseed: 3\n")
    assert data == {"frequencies_hz": [402e6, 2.45e9, 1e9], "seed": 3}


def test_size_limits():
    with pytest.raises(SweepSpecError) as info:
        SweepSpec.from_dict({**BASE, "capsule_positions": [{"site": "stomach"}] * 11}, Limits(max_positions=10))
    assert info.value.field == "capsule_positions"
    with pytest.raises(SweepSpecError) as info:
        SweepSpec.from_dict({**BASE, "capsule_positions": [{"site": "stomach"}] * 6, "frequencies_hz": [4e8, 5e8]},
                            Limits(max_traces=10))
    assert info.value.field == "capsule_positions"
    # along the tract, the count is known at planning: 0.688 m every mm is 689 positions
    along = spec(capsule_positions={"along_tract": {"ds_m": 0.001}})
    with pytest.raises(SweepSpecError) as info:
        make_plan(along, default_torso(), limits=Limits(max_positions=100))
    assert info.value.field == "capsule_positions.along_tract.ds_m"
    # a subnormal spacing makes the count infinite: still the same refusal, not an OverflowError (a 500)
    tiny = spec(capsule_positions={"along_tract": {"ds_m": 5e-324}})
    with pytest.raises(SweepSpecError) as info:
        make_plan(tiny, default_torso())
    assert info.value.field == "capsule_positions.along_tract.ds_m"


@pytest.mark.parametrize("changes,field,error", [
    ({"capsule_positions": [{"site": "nowhere"}]}, "capsule_positions[0].site", SweepSpecError),
    ({"capsule_positions": [{"site": "stomach"}, {"position_m": [5.0, 0, 0]}]}, "capsule_positions[1].position_m",
     InputError),
    ({"capsule_positions": [{"s_m": 5.0}]}, "capsule_positions[0].s_m", SweepSpecError),
    ({"capsule_positions": [{"s_m": 0.1, "centreline": "aorta"}]}, "capsule_positions[0].centreline", SweepSpecError),
    ({"receivers": [{"site": "belt_nowhere"}]}, "receivers[0].site", NotFoundError),
    ({"capsule_positions": {"along_tract": {"ds_m": 0.1, "start_m": 2.0}}}, "capsule_positions.along_tract.start_m",
     SweepSpecError),
])
def test_planning_checks_the_phantom_naming_the_field(changes, field, error):
    with pytest.raises(error) as info:
        make_plan(spec(**changes), default_torso())
    assert info.value.field == field


def test_plan_resolves_sites_arc_lengths_and_the_tract():
    torso = default_torso()
    line = torso.centrelines["gi_tract"]
    plan = make_plan(spec(capsule_positions=[{"site": "transverse_colon"}, {"s_m": 0.3, "name": "x"}],
                          receivers="sensors", channel={"capsule_polarization": "tangent"}), torso)
    np.testing.assert_array_equal(plan.positions_m[0], torso.sites["transverse_colon"].position_m)
    np.testing.assert_array_equal(plan.positions_m[1], line.point_m(0.3))
    assert plan.labels == ("transverse_colon", "x")
    assert plan.s_m[1] == 0.3 and abs(plan.s_m[0] - line.project(plan.positions_m[0])) == 0
    assert plan.media == ("transverse_colon", "small_intestine")
    np.testing.assert_array_equal(plan.polarizations[1], line.tangent(0.3))
    assert [r["name"] for r in plan.receivers] == [n for n, s in torso.sites.items() if s.kind == "sensor"]
    along = make_plan(spec(capsule_positions={"along_tract": {"ds_m": 0.1}}), torso)
    np.testing.assert_allclose(along.s_m, np.arange(7) * 0.1)
    assert along.labels[0] == "stomach@0.0mm" and along.n_tasks == 2  # 7 positions, chunks of 4


@pytest.mark.parametrize("name", sorted(builtin_specs()))
def test_builtin_specs_load_and_plan(name):
    from raytrace.body.library import get_phantom

    s = load_spec(name)
    assert s["name"] == name and s["description"]
    plan = make_plan(s, get_phantom(s["phantom"]))
    assert plan.total_traces >= 1
