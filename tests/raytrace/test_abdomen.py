"""The built-in ``abdomen-ct`` phantom (raytrace/body/abdomen.py): its vendored sources, organs, journey, sites
and sensors, and its disk cache.

Oracles independent of the pipeline: the model's own landmark indices (its configuration file), the mid-lines'
length computed here from the raw path files, checksums recorded when the files were vendored, and traced
channels (the tracer, not the pipeline, says which sensors a capsule reaches by a direct path). The phantom is
built once per machine (the cache) and loaded once per test process.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from raytrace.body import abdomen
from raytrace.body.abdomen import DATA_DIR, abdomen_ct
from raytrace.body.centreline import GI_TRACT

REPO = Path(__file__).resolve().parents[2]
DOI = "10.1186/s12911-023-02111-9"
#: The journey's organs, in the order a capsule passes them.
JOURNEY = ["oesophagus", "stomach", "small_intestine", "large_intestine"]
#: Capsule sites the issue names (landmarks of the model, and places in the stomach and the caecum).
REQUIRED_SITES = {"small_intestine_DJJ", "small_intestine_JIJ", "small_intestine_ITIJ", "small_intestine_ICVi",
                  "large_intestine_ICVc", "large_intestine_caecum", "large_intestine_HF", "large_intestine_SF",
                  "large_intestine_DSJ", "large_intestine_RSJ", "stomach_body", "stomach_OGJ"}


@pytest.fixture(scope="module")
def phantom():
    return abdomen_ct()


def _manifest() -> dict:
    return yaml.safe_load((DATA_DIR / "manifest.yaml").read_text())


def test_the_vendored_files_are_the_model_s_unchanged() -> None:
    lines = (DATA_DIR / "SHA256SUMS").read_text().split("\n")
    sums = dict(reversed(line.split("  ", 1)) for line in lines if line.strip())
    assert len(sums) == 12
    for name, digest in sums.items():
        assert hashlib.sha256((DATA_DIR / name).read_bytes()).hexdigest() == digest, name
    manifest = _manifest()
    named = {f for o in manifest["organs"].values() for f in o["files"]} | {manifest["body"]["surface"]} | \
        {t["file"] for t in manifest["tracts"].values()}
    assert named <= set(sums), named - set(sums)  # every file the build reads is a checked one


def test_the_licence_and_the_attribution_ship_with_it() -> None:
    assert "Attribution 4.0 International" in (DATA_DIR / "LICENSE").read_text()
    for path in (DATA_DIR / "ATTRIBUTION.md", REPO / "README.md", REPO / "docs/phantoms.md"):
        text = path.read_text()
        assert DOI in text and "Burger" in text and "CC BY 4.0" in text, path


def test_the_landmarks_are_the_model_s() -> None:
    """Every landmark named by its abbreviation in the manifest is the model's point index on that path
    (EdinGCA_3D_00090_1_1.json: path 160 is the small intestine's, 150 the large intestine's)."""
    config = json.loads((DATA_DIR / "EdinGCA_3D_00090_1_1.json").read_text())
    model = {}
    for mark in config["landmarks"]:
        path = {"GUT_ATLAS_PAT:160": "small", "GUT_ATLAS_PAT:150": "large"}[mark["paths"][0]]
        model[(path, mark["anatomy"][0]["abbreviated_name"])] = mark["position"][0]
    assert len(model) == 16
    checked = 0
    for tract in _manifest()["tracts"].values():
        path = "small" if "small" in tract["file"] else "large"
        for name, index in tract["landmarks"].items():
            if (path, name) in model:
                assert index == model[(path, name)], name
                checked += 1
    assert checked == 14  # all but the appendix's two (AO, AT), which are not on the capsule's way


def test_organs_are_separate_and_nested_in_the_generated_wall(phantom) -> None:
    names = [o.name for o in phantom.organs]
    assert names == ["skin", "subcutaneous_fat", "muscle_wall", "visceral_cavity", *JOURNEY]
    tissue = {o.name: o.material.tissue for o in phantom.organs}
    assert tissue == {"skin": "skin_dry", "subcutaneous_fat": "fat_average_infiltrated", "muscle_wall": "muscle",
                      "visceral_cavity": "muscle", "oesophagus": "stomach", "stomach": "stomach",
                      "small_intestine": "small_intestine", "large_intestine": "colon"}
    parents = {o.name: phantom.medium_name(int(p)) for o, p in zip(phantom.organs, phantom.parent)}
    assert parents == {"skin": "air", "subcutaneous_fat": "skin", "muscle_wall": "subcutaneous_fat",
                       "visceral_cavity": "muscle_wall", **{n: "visceral_cavity" for n in JOURNEY}}
    # metres, the project's frame: the body is 512 mm wide (x) and 296 mm deep (y) in the files
    lo, hi = phantom.bounds_m
    assert hi[0] - lo[0] == pytest.approx(0.5116, abs=2e-3) and hi[1] - lo[1] == pytest.approx(0.2957, abs=2e-3)
    # the stomach lies anterior (-y) and to the subject's left (+x) of the rectum's sites
    stomach, rectum = phantom.sites["stomach_body"].position_m, phantom.sites["large_intestine_rectum"].position_m
    assert stomach[1] < rectum[1] and stomach[2] > rectum[2] + 0.15


def _midline_length_m() -> float:
    """The mid-lines the capsule follows, from the raw path files (in mm): the whole small-intestine path
    (ileocaecal valve to oesophagus), and the large-intestine path from the anus (point 0) to the
    ileocaecal valve (point 1314), without the caecal pouch and the appendix beyond it."""
    small = np.array(json.loads((DATA_DIR / "Paths/small_intestine_path.jsn").read_text())["points"])
    large = np.array(json.loads((DATA_DIR / "Paths/large_intestine_path.jsn").read_text())["points"])[:1315]
    return sum(float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) for p in (small, large)) * 1e-3


def test_the_journey_is_the_mid_lines(phantom) -> None:
    line = phantom.centrelines[GI_TRACT]
    # within 1 %: the journey leaves out the few mid-line points the body wall clipped off the oesophagus
    # at the top of the scan and the jumps across the cuts between organs
    assert line.length_m == pytest.approx(_midline_length_m(), rel=0.01)
    assert [p.organ for p in line.pieces] == JOURNEY
    sites = phantom.metadata["journey"]["sites_s_m"]
    order = ["oesophagus_mid", "stomach_OGJ", "stomach_body", "small_intestine_GDJ", "small_intestine_duodenum",
             "small_intestine_DJJ", "small_intestine_jejunum", "small_intestine_JIJ", "small_intestine_ileum",
             "small_intestine_ITIJ", "small_intestine_ICVi", "large_intestine_ICVc", "large_intestine_caecum",
             "large_intestine_CCJ", "large_intestine_ascending", "large_intestine_HF", "large_intestine_transverse",
             "large_intestine_SF", "large_intestine_descending", "large_intestine_DSJ", "large_intestine_sigmoid",
             "large_intestine_RSJ", "large_intestine_rectum", "large_intestine_anus"]
    assert list(sites) == order and np.all(np.diff([sites[n] for n in order]) >= 0)
    for name in order:  # every landmark site lies on the journey, at its arc length, in its tract's organ
        site = phantom.sites[name]
        assert site.kind == "capsule" and site.medium == name.rsplit("_", 1)[0]
        assert line.distance_m(site.position_m) < 1e-9  # (a piece's end projects 1e-12 of the length short)
        assert line.project(site.position_m) == pytest.approx(sites[name], abs=1e-9)
    line.check_inside(phantom)


def test_capsule_sites_include_the_landmarks(phantom) -> None:
    capsules = {n for n, s in phantom.sites.items() if s.kind == "capsule"}
    assert REQUIRED_SITES <= capsules
    sensors = [s for s in phantom.sites.values() if s.kind == "sensor"]
    assert len(sensors) >= 16 and {s.medium for s in sensors} == {"skin"}


#: Capsule sites re-traced against the committed reach table: the stomach, the jejunum, the colon's hepatic
#: flexure (one per organ kind; ~2 s of CPU each).
RETRACED = ("stomach_body", "small_intestine_jejunum", "large_intestine_HF")


def test_every_capsule_site_reaches_every_sensor_and_eight_directly(phantom) -> None:
    """A channel from every capsule site to every sensor answers, and each capsule site has a direct
    (refraction-only) path to at least 8 sensors (the belts were placed for that: tools/
    abdomen_sensor_reachability.py). Checked on the committed reach table (evaluation.anatomy: all 24 sites
    take ~1 min of CPU), which must have been made on this very phantom and these settings; three sites
    are traced afresh here and must give the table's sets exactly (the tracer is deterministic: same
    request, same paths)."""
    from evaluation.anatomy import reach_rows, reach_table

    table = reach_table(phantom)["sites"]
    sensors = [n for n, s in phantom.sites.items() if s.kind == "sensor"]
    capsules = [n for n, s in phantom.sites.items() if s.kind == "capsule"]
    assert list(table) == capsules
    assert all(row["answered"] == sensors for row in table.values())
    short = {name: len(row["direct"]) for name, row in table.items() if len(row["direct"]) < 8}
    assert not short, short
    assert reach_rows(phantom, RETRACED) == {name: table[name] for name in RETRACED}


def test_the_cache_reloads_the_same_phantom(phantom, tmp_path) -> None:
    report = json.loads((abdomen.cached_path() / "report.json").read_text())
    abdomen._write(phantom, report, tmp_path / "entry")
    again = abdomen._read(tmp_path / "entry")
    for a, b in zip(phantom.organs, again.organs):
        assert a.name == b.name and a.material.label == b.material.label
        np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
        np.testing.assert_array_equal(a.mesh.faces, b.mesh.faces)
    np.testing.assert_array_equal(phantom.parent, again.parent)
    np.testing.assert_array_equal(phantom.vertex_normals, again.vertex_normals)
    assert {n: (s.kind, s.medium, s.position_m.tolist()) for n, s in phantom.sites.items()} == \
        {n: (s.kind, s.medium, s.position_m.tolist()) for n, s in again.sites.items()}
    for name, line in phantom.centrelines.items():
        for p, q in zip(line.pieces, again.centrelines[name].pieces):
            assert p.organ == q.organ
            np.testing.assert_array_equal(p.points_m, q.points_m)
    # the reloaded phantom's media are its own (not only the cache's word for them)
    capsules = np.array([s.position_m for s in again.sites.values()])
    assert again.medium_names(again.medium_index(capsules)) == [s.medium for s in again.sites.values()]


def test_the_cache_key_follows_every_source_file(tmp_path, monkeypatch) -> None:
    copy = tmp_path / "abdomen-ct"
    shutil.copytree(DATA_DIR, copy)
    key = abdomen.source_key()
    abdomen.source_key.cache_clear()
    try:
        monkeypatch.setattr(abdomen, "DATA_DIR", copy)
        assert abdomen.source_key() == key  # the same bytes: the same key
        abdomen.source_key.cache_clear()
        path = copy / "Paths/large_intestine_path.jsn"
        path.write_bytes(path.read_bytes().replace(b"1", b"2", 1))
        assert abdomen.source_key() != key
        monkeypatch.setenv("CAPSULE_RT_CACHE_DIR", str(tmp_path / "cache"))
        assert abdomen.cached_path().parent == tmp_path / "cache" / "phantoms"
    finally:
        abdomen.source_key.cache_clear()

