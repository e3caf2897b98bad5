"""The manifest: the issue's example (its exact keys) reads; the shipped JSON schema lists exactly the keys the
checks allow and the options' defaults; the docs' tissue map is the code's; the TotalSegmentator numbering."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from raytrace.body.anatomy import tissuemap
from raytrace.body.anatomy.manifest import KEYS, Options, load_manifest

ROOT = Path(__file__).resolve().parents[3]
SCHEMA = json.loads((ROOT / "raytrace/body/anatomy/manifest.schema.json").read_text())

ISSUE_EXAMPLE = """
name: my-abdomen
units: mm                        # or m; or scale: 0.001
body:
  surface: body.vtk              # the skin surface (or label: N of the volume); layers generated inward
  layers: [{tissue: skin_dry, thickness_m: 0.002}, {tissue: fat_average_infiltrated, thickness_m: 0.015},
           {tissue: muscle, thickness_m: 0.010}]
  fill: muscle                   # the rest of the body
volume: labels.nii.gz            # optional labelled volume; organs may then name a label
organs:
  colon: {files: [a.vtk, b.vtk], tissue: colon}
  liver: {label: 5}              # tissue from the built-in map of TotalSegmentator class names when omitted
tracts:
  colon: {file: large_intestine_path.jsn, organ: colon, reverse: false, landmarks: {anus: 0}}
sensors:
  belts: [{height_m: 0.20, count: 8}]   # rings on the skin, heights along the body axis from the body's lowest point
"""


def test_the_issue_example_reads_with_its_exact_keys() -> None:
    m = load_manifest(yaml.safe_load(ISSUE_EXAMPLE))
    assert m.scale == 1e-3 and [layer.name for layer in m.body.layers] == ["skin", "subcutaneous_fat", "muscle_wall"]
    assert m.organs["colon"].files == ("a.vtk", "b.vtk") and m.organs["liver"].label == 5
    assert m.label_names[5] == "liver" and tissuemap.tissue_for(m.label_names[5]) == "liver"
    assert m.tracts["colon"].landmarks == {"anus": 0} and m.belts[0].count == 8


def test_the_docs_worked_example_reads() -> None:
    m = load_manifest(yaml.safe_load((ROOT / "docs/anatomy/gca-00090.yaml").read_text()))
    assert len(m.tracts["small_intestine"].landmarks) + len(m.tracts["large_intestine"].landmarks) == 16


def _props(node: dict) -> set[str]:
    return set(node["properties"])


def test_the_schema_lists_exactly_the_allowed_keys() -> None:
    p = SCHEMA["properties"]
    assert _props(SCHEMA) == KEYS["manifest"]
    assert _props(p["transform"]) == KEYS["transform"]
    assert _props(p["body"]) == KEYS["body"]
    assert _props(p["body"]["properties"]["layers"]["items"]) == KEYS["layer"]
    assert _props(p["organs"]["additionalProperties"]) == KEYS["organ"]
    assert _props(p["tracts"]["additionalProperties"]) == KEYS["tract"]
    assert _props(p["sensors"]) == KEYS["sensors"]
    assert _props(p["sensors"]["properties"]["belts"]["items"]) == KEYS["belt"]
    defaults = Options()
    assert {k: v["default"] for k, v in p["options"]["properties"].items()} == \
        {k: getattr(defaults, k) for k in Options.__dataclass_fields__}


def test_the_docs_tissue_map_is_the_code_s() -> None:
    text = (ROOT / "docs/phantoms.md").read_text()
    start = text.index("<!-- tissue map")
    table = text[text.index("\n", start) + 1:text.index("<!-- end tissue map -->")].strip()
    assert table == tissuemap.markdown_table(), "regenerate with raytrace.body.anatomy.tissuemap.markdown_table()"


@pytest.mark.parametrize("number, name", [(1, "spleen"), (5, "liver"), (18, "small_bowel"), (20, "colon"),
                                          (26, "vertebrae_S1"), (51, "heart"), (117, "costal_cartilages")])
def test_totalsegmentator_v2_numbering(number, name) -> None:
    # Published class map of TotalSegmentator's `total` task, v2 (its map_to_binary.class_map["total"])
    assert tissuemap.TOTAL_V2_CLASSES[number] == name
