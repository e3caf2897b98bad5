"""``capsule-rt fullwave --reuse``: a cell size whose identical input already ran to the end in --out
is not run again (its gprMax output stays as it was, the report says so and its numbers are the same);
a changed input is run. One tiny gprMax model (a 4 mm, 26 x 19 x 18-cell muscle box, ~1e7 cell
updates: a few seconds)."""

from __future__ import annotations

import json

from service.cli import main
from tests.e2e.test_fullwave_http import TINY

REQUEST = {k: v for k, v in TINY.items() if k not in ("cell_m", "margin_m", "pml_cells", "coarse_factor")}
ARGS = ["--cell-mm", "4", "--margin-mm", "12", "--pml-cells", "6", "--coarse-factor", "0", "--threads", "1"]


def test_reuse_skips_an_identical_finished_run(tmp_path, capsys):
    req, out = tmp_path / "req.json", tmp_path / "out"
    req.write_text(json.dumps(REQUEST))
    assert main(["fullwave", str(req), "--out", str(out), *ARGS]) == 0
    first = json.loads((out / "report.json").read_text())
    h5 = (out / "model_40.h5").stat().st_mtime_ns
    assert first["runs"][0]["ran"] and first["runs"][0]["reused"] is False
    capsys.readouterr()

    assert main(["fullwave", str(req), "--out", str(out), *ARGS, "--reuse"]) == 0
    assert "re-used" in capsys.readouterr().err
    again = json.loads((out / "report.json").read_text())
    assert (out / "model_40.h5").stat().st_mtime_ns == h5 and again["runs"][0]["reused"] is True
    assert again["runs"][0]["receivers"] == first["runs"][0]["receivers"]

    # another request (the receiver 1 cell further) in the same directory: a different input, run anew
    moved = {**REQUEST, "receivers": [{**REQUEST["receivers"][0], "position_m": [0.034, 0.5, 0.0]}]}
    req.write_text(json.dumps(moved))
    assert main(["fullwave", str(req), "--out", str(out), *ARGS, "--reuse"]) == 0
    third = json.loads((out / "report.json").read_text())
    assert third["runs"][0]["reused"] is False and (out / "model_40.h5").stat().st_mtime_ns != h5
