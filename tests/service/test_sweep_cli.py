"""``capsule-rt sweep`` / ``experiment`` in process: help on every option, the built-in list, a run
with its summary table and exports, the refusal to overwrite a sweep, a spec error naming the field."""

from __future__ import annotations

import json

import pytest

from service.cli import build_parser, main

SPEC = {"name": "cli", "capsule_positions": [{"site": "stomach"}], "receivers": [{"site": "upper_anterior_left"}],
        "channel": {"rays": 1000, "max_interactions": 2}, "ranging": {"toa": {"methods": ["gcc"]}}, "trials": 3}


def test_every_option_has_help():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name in ("sweep", "experiment"):
        for action in sub.choices[name]._actions:
            if action.dest != "help":
                assert action.help, (name, action.dest)


def test_list_shows_the_builtin_specs(capsys):
    assert main(["sweep", "--list"]) == 0
    out = capsys.readouterr().out
    for name in ("thesis-ch4-toa-heterogeneous", "thesis-ch4-toa-homogeneous", "thesis-ch5-pdoa",
                 "torso-path-loss-402mhz", "torso-pdoa-bands"):
        assert name in out


def test_run_summary_exports_and_no_overwrite(tmp_path, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_text(json.dumps(SPEC))  # JSON is YAML
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "0", "--export", "csv,json"]) == 0
    text = capsys.readouterr().out
    assert "sweep cli: done, 1/1 traces, 1 rows" in text and "toa_gcc" in text and "max |err - mean|" in text
    assert (out / "results.parquet").exists() and (out / "results.csv").exists()
    assert json.loads((out / "results.json").read_text())["rows"][0]["capsule"] == "stomach"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "0"]) == 2
    err = json.loads(capsys.readouterr().err)
    assert err["detail"][0]["loc"] == ["spec", "out"]


@pytest.mark.parametrize("bad,loc", [({"trials": 0}, ["spec", "trials"]), ({"channel": {"rays": -1}},
                                                                             ["spec", "channel", "rays"])])
def test_spec_errors_name_the_field(tmp_path, capsys, bad, loc):
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({**SPEC, **bad}))
    assert main(["sweep", str(spec), "--out", str(tmp_path / "o")]) == 2
    assert json.loads(capsys.readouterr().err)["detail"][0]["loc"] == loc
