"""The localization figures drawn from known data, read back from the artists: the CDF steps sit at
the sorted errors (in mm) with heights k/n, the tract lines at (s, error), the fitted path-loss line
is the least-squares line through (10 log10(d/d0), PL) computed here with numpy.polyfit (not the
project's fit), and the CM2 curves are the published model (thesis Table 2.2) typed here."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from matplotlib.image import imread

from plots import PlotInputError, localization_cdf, path_loss, render, tract_errors


def _line(ax, label_start: str):
    return next(line for line in ax.get_lines() if line.get_label().startswith(label_start))


def test_cdf_steps_are_the_sorted_errors():
    errors = [0.004, 0.001, 0.003, 0.002]
    fig = localization_cdf([{"method": "model_based", "errors_m": errors, "crlb_m": 0.0005},
                            {"method": "nonlinear", "errors_m": [0.07, None, 0.08, 0.09]}])
    ax = fig.axes[0]
    mb = _line(ax, "model_based")
    assert mb.get_xdata() == pytest.approx([1.0, 2.0, 3.0, 4.0])  # mm, sorted
    assert mb.get_ydata() == pytest.approx([0.25, 0.5, 0.75, 1.0])
    # median of 1..4 mm is 2.5 mm, 90th percentile (linear interpolation) 3.7 mm
    assert "CEP50 2.5, CEP90 3.7 mm" in mb.get_label()
    nl = _line(ax, "nonlinear")
    assert nl.get_ydata()[-1] == pytest.approx(0.75)  # one of four trials failed: the curve tops out at 3/4
    assert "1 failed" in nl.get_label()
    dashed = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert [line.get_xdata()[0] for line in dashed] == pytest.approx([0.5])  # the CRLB, mm


def test_cdf_bad_input_named():
    with pytest.raises(PlotInputError) as err:
        localization_cdf([{"method": "a", "errors_m": [None, None]}])
    assert err.value.field == "methods[0].errors_m"
    with pytest.raises(PlotInputError) as err:
        localization_cdf([{"method": "a", "errors_m": [0.1]}, {"method": "a", "errors_m": [0.2]}])
    assert err.value.field == "methods[1].method"


def test_tract_lines_follow_s_in_order():
    rows = [{"method": "nonlinear", "s_m": s, "error_m": e, "along_tract_error_m": a, "capsule": "x"}
            for s, e, a in ((0.4, 0.03, -0.01), (0.1, 0.02, 0.005), (0.7, 0.05, 0.02))]
    rows.append({"method": "nonlinear", "s_m": None, "error_m": 0.01})  # off the centreline: left out
    fig = tract_errors(rows, junctions_s_m=[0.25], columns=["method", "s_m"])
    top, bottom = fig.axes[:2]
    line = _line(top, "nonlinear")
    assert line.get_xdata() == pytest.approx([0.1, 0.4, 0.7])
    assert line.get_ydata() == pytest.approx([20.0, 30.0, 50.0])
    assert _line(bottom, "nonlinear").get_ydata() == pytest.approx([5.0, -10.0, 20.0])
    assert "1 rows without s_m" in fig._suptitle.get_text()
    assert "s [m]" in bottom.get_xlabel()
    with pytest.raises(PlotInputError) as err:
        tract_errors([{"method": "a", "s_m": None, "error_m": 0.1}])
    assert err.value.field == "rows"


def test_path_loss_fit_and_cm2_curves():
    rng = np.random.default_rng(4)
    d = np.linspace(0.04, 0.2, 30)
    pl = 40.0 + 10 * 3.5 * np.log10(d / 0.05) + rng.normal(0.0, 2.0, d.size)
    fig = path_loss(d.tolist(), pl.tolist())
    ax = fig.axes[0]
    lines = {line.get_gid(): line for line in ax.get_lines()}
    x = np.asarray(lines["fit"].get_xdata()) / 1e3
    slope, intercept = np.polyfit(10 * np.log10(d / 0.05), pl, 1)  # the oracle: numpy's least squares
    assert lines["fit"].get_ydata() == pytest.approx(intercept + slope * 10 * np.log10(x / 0.05), abs=1e-9)
    # IEEE 802.15.6 CM2 (thesis Table 2.2): deep tissue 47.14 dB + 10 * 4.26 log10(d / 50 mm)
    deep = lines["cm2_deep_tissue"]
    assert deep.get_ydata() == pytest.approx(47.14 + 42.6 * np.log10(np.asarray(deep.get_xdata()) / 50.0))
    near = lines["cm2_near_surface"]
    assert near.get_ydata() == pytest.approx(49.81 + 42.2 * np.log10(np.asarray(near.get_xdata()) / 50.0))
    assert ax.get_xscale() == "log" and "[mm]" in ax.get_xlabel() and "[dB]" in ax.get_ylabel()
    offsets = ax.collections[0].get_offsets()
    assert np.asarray(offsets)[:, 0] == pytest.approx(d * 1e3)
    with pytest.raises(PlotInputError) as err:
        path_loss([0.1, 0.2, 0.3, 0.4], [50.0, 60.0, 65.0])
    assert err.value.field == "path_loss_db"
    with pytest.raises(PlotInputError) as err:
        path_loss([0.1, 0.1, 0.1], [50.0, 60.0, 70.0])
    assert err.value.field == "distances_m"


@pytest.mark.parametrize("kind, body", [
    ("localization_cdf", {"methods": [{"method": "m", "errors_m": [0.01, 0.02, 0.05]}]}),
    ("tract_errors", {"rows": [{"method": "m", "s_m": 0.1, "error_m": 0.01}, {"method": "m", "s_m": 0.3,
                                                                              "error_m": 0.02}]}),
    ("path_loss", {"distances_m": [0.05, 0.1, 0.15], "path_loss_db": [47.0, 60.0, 68.0]}),
])
def test_renders_at_the_requested_size_and_not_blank(kind, body):
    png = render(kind, {**body, "width_in": 6.0, "height_in": 4.0, "dpi": 100})
    rgba = imread(io.BytesIO(png), format="png")
    assert rgba.shape[:2] == (400, 600)
    assert np.any(rgba[..., :3] < 0.9, axis=-1).mean() > 0.01
    assert math.isfinite(float(rgba.mean()))
