"""The literature table's published rows say what their sources say (quoted in the docs), and the
table is in the literature's columns. Our rows are computed by ``python -m evaluation.literature``
from the evaluations tested elsewhere (test_localization_pipeline, test_fusion)."""

from evaluation.literature import PUBLISHED, REFERENCES, Row, markdown


def test_published_rows_quote_their_sources():
    by = {(r.sensors, r.rmse): r for r in PUBLISHED}
    assert by["48", "6.83"].band == "UWB" and by["48", "6.83"].dims == "3-D"  # in-body UWB, 48 sensors
    assert by["8", "7.0"].method.startswith("RSSI") and "particle filter" in by["8", "7.0"].method
    assert by["16", "23"].method.startswith("Hybrid video + RF")
    assert any("within 30" in r.rmse for r in PUBLISHED)  # "within 3 cm": the hybrid bound
    # the thesis' numbers as docs/science.md states them (section 2)
    thesis = " ".join(r.rmse for r in PUBLISHED if r.source.startswith("[T]"))
    for number in ("1.85", "9.5", "5.02", "3.30", "17.7", "14.2", "5 / 11.4"):
        assert number in thesis
    for key in ("[T]", "[H23]", "[B15]", "[G15]"):
        assert key in REFERENCES and any(r.source.startswith(key) or key in r.source for r in PUBLISHED)


def test_the_table_has_the_literatures_columns():
    text = markdown([Row("m", "b", "1", "3-D", "1.0", "2.0", "v", "s")])
    assert text.splitlines()[0] == ("| method | band | sensors | 2-D / 3-D | RMSE [mm] | CEP90 [mm] | how validated "
                                    "| source |")
    assert text.splitlines()[2] == "| m | b | 1 | 3-D | 1.0 | 2.0 | v | s |"
