"""The thesis' experiments as built-in sweep specs (``sweeps/specs/*.yaml``), each with its report.

``capsule-rt experiment NAME --out DIR`` runs an experiment's sweeps into ``DIR/<spec>/``
and writes ``DIR/report.md`` (our numbers beside the thesis') and ``DIR/report.json``;
``docs/sweeps.md`` quotes those reports and says why the numbers differ. Re-running an
experiment after a change of the tracer or the estimators is that one command.

=====================  ==========================================================  =======================
experiment             specs                                                       thesis
=====================  ==========================================================  =======================
``thesis-ch4-toa``     thesis-ch4-toa-homogeneous, thesis-ch4-toa-heterogeneous    Ch. 4, Figs 4.3-4.5
``thesis-ch5-pdoa``    thesis-ch5-pdoa, torso-pdoa-bands                           Sec 5.4, Table 5.2
``torso-path-loss``    torso-path-loss-402mhz                                      Table 2.2 (IEEE CM2)
``abdomen-ct-path-     abdomen-ct-path-loss-402mhz (the CT abdomen, every 50 mm)   Table 2.2 (IEEE CM2)
loss``
=====================  ==========================================================  =======================
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Callable

import pyarrow as pa
import pyarrow.compute as pc

from estimators.rss import CM2_MODELS
from sweeps.pathloss import fit_table, model_dict
from sweeps.report import SUMMARY_COLUMNS, format_table, method_summary

__all__ = ["EXPERIMENTS", "Experiment", "builtin_spec_path", "builtin_specs"]


def builtin_specs() -> dict[str, Path]:
    """Built-in spec name -> packaged file."""
    root = resources.files("sweeps") / "specs"
    return {Path(p.name).stem: Path(str(p)) for p in root.iterdir() if p.name.endswith((".yaml", ".yml", ".json"))}


def builtin_spec_path(name: str) -> Path | None:
    return builtin_specs().get(name)


# Published numbers (thesis text, docs/science.md "Key numbers").
THESIS_TOA_MAX_ERROR_M = {  # after removing the mean bias over the four positions, SNR 30 dB, 402 MHz
    "homogeneous": {"gcc": 1.85e-3, "all_peaks": 3.30e-3, "first_peak": 5.02e-3},
    "heterogeneous": {"gcc": 9.5e-3, "all_peaks": 14.2e-3, "first_peak": 17.7e-3},
}
#: The thesis' four capsule-sensor distances span 75.948-134.231 mm (Table 4.1).
THESIS_TOA_DISTANCES_M = (0.075948, 0.134231)
THESIS_PDOA = {410e6: {"mean_m": 0.081, "variance_m2": 1.3e-4, "error_m": 0.005},
               2450e6: {"mean_m": 0.0646, "variance_m2": 4.2e-5, "error_m": 0.0114}}
CM2 = CM2_MODELS["cm2_deep_tissue"]


@dataclass(frozen=True)
class Experiment:
    name: str
    specs: tuple[str, ...]
    report: Callable[[dict[str, pa.Table]], tuple[str, dict[str, Any]]]
    description: str


def _toa_report(tables: dict[str, pa.Table]) -> tuple[str, dict]:
    lines, data = [], {}
    methods = ["toa_first_peak", "toa_all_peaks", "toa_gcc"]
    lo, hi = THESIS_TOA_DISTANCES_M
    for case in ("homogeneous", "heterogeneous"):
        table = tables[f"thesis-ch4-toa-{case}"]
        distance = pc.field("distance_m")
        near = table.filter((distance >= lo - 1e-3) & (distance <= hi + 1e-3))
        for subset, label, t in (("all", "every link", table),
                                 ("thesis_range", f"links of {lo * 1e3:.0f}-{hi * 1e3:.0f} mm (the thesis' "
                                                  "distances)", near)):
            rows = method_summary(t, methods)
            for r in rows:
                r["thesis_max_debiased_error_m"] = (THESIS_TOA_MAX_ERROR_M[case][r["method"][4:]]
                                                    if r["frequency_hz"] == 402e6 else None)
            data[f"{case}_{subset}"] = rows
            lines += [f"### {case} tissue, {label}", "", "```",
                      format_table(rows, SUMMARY_COLUMNS + [("thesis_max_debiased_error_m", "thesis [mm]", "mm")]),
                      "```", ""]
    return "\n".join(lines), data


def _pdoa_report(tables: dict[str, pa.Table]) -> tuple[str, dict]:
    slab = tables["thesis-ch5-pdoa"].to_pydict()
    rows = []
    for i, f in enumerate(slab["frequency_hz"]):
        for m in ("pdoa_regression", "pdoa_two_tone"):
            std = slab[f"{m}_std_m"][i]
            rows.append({"frequency_hz": f, "method": m, "mean_m": slab[f"{m}_distance_m"][i],
                         "variance_m2": None if std is None else std ** 2, "error_m": slab[f"{m}_error_m"][i],
                         "thesis_mean_m": THESIS_PDOA[f]["mean_m"] if m == "pdoa_regression" else None,
                         "thesis_variance_m2": THESIS_PDOA[f]["variance_m2"] if m == "pdoa_regression" else None,
                         "thesis_error_m": THESIS_PDOA[f]["error_m"] if m == "pdoa_regression" else None})
    cols = [("frequency_hz", "MHz", "MHz"), ("method", "method", "{}"), ("mean_m", "mean [mm]", "mm"),
            ("variance_m2", "variance [m^2]", "{:.2g}"), ("error_m", "error [mm]", "mm"),
            ("thesis_mean_m", "thesis mean [mm]", "mm"), ("thesis_variance_m2", "thesis var [m^2]", "{:.2g}"),
            ("thesis_error_m", "thesis error [mm]", "mm")]
    torso = method_summary(tables["torso-pdoa-bands"], ["pdoa_regression"])
    text = "\n".join(["### the thesis' three-path case (thesis-fig-5-6 slab), 0.076 m", "", "```",
                      format_table(rows, cols), "```", "", "### along the default torso's GI tract", "", "```",
                      format_table(torso, SUMMARY_COLUMNS), "```", ""])
    return text, {"slab": rows, "torso": torso}


#: Distance bins of the path-loss reports' medians [m].
PATH_LOSS_BINS_M = ((0.07, 0.10), (0.10, 0.13), (0.13, 0.16), (0.16, 0.20), (0.20, 0.25), (0.25, 0.31), (0.31, 0.40))


def _median_path_loss(table: pa.Table) -> list[dict]:
    """Median path loss (-path_gain_db) of the links with a path, per distance bin."""
    cols = table.to_pydict()
    d = [x for x, g in zip(cols["distance_m"], cols["path_gain_db"]) if g is not None]
    loss = [-g for g in cols["path_gain_db"] if g is not None]
    out = []
    for lo, hi in PATH_LOSS_BINS_M:
        inside = sorted(v for x, v in zip(d, loss) if lo <= x < hi)
        if inside:
            mid = len(inside) // 2
            median = inside[mid] if len(inside) % 2 else 0.5 * (inside[mid - 1] + inside[mid])
            out.append({"bin": f"{lo * 1e3:.0f}-{hi * 1e3:.0f}", "links": len(inside), "median_db": median,
                        "cm2_db": float(CM2.path_loss_db(0.5 * (lo + hi)))})
    return out


def _path_loss_report(tables: dict[str, pa.Table], spec: str = "torso-path-loss-402mhz",
                      what: str = "the torso") -> tuple[str, dict]:
    table = tables[spec]
    model, links = fit_table(table, frequency_hz=402e6, name=spec.replace("-path-loss-", "_").replace("-", "_")
                             + "_fit")
    rows = [{"model": f"fitted to {what} (402 MHz)", "pl0": model.path_loss_d0_db, "n": model.exponent,
             "sigma": model.shadowing_db, "links": links},
            {"model": "IEEE 802.15.6 CM2 deep tissue", "pl0": CM2.path_loss_d0_db, "n": CM2.exponent,
             "sigma": CM2.shadowing_db, "links": None}]
    d = [r for r in table.to_pydict()["distance_m"]]
    cols = [("model", "model", "{}"), ("pl0", "PL(d0) [dB]", "{:.2f}"), ("n", "exponent n", "{:.2f}"),
            ("sigma", "sigma [dB]", "{:.2f}"), ("links", "links", "{}")]
    rss = method_summary(table, ["rss"])
    medians = _median_path_loss(table)
    bins = [("bin", "distance [mm]", "{}"), ("links", "links", "{}"), ("median_db", "median path loss [dB]", "{:.1f}"),
            ("cm2_db", "CM2 at the bin's centre [dB]", "{:.1f}")]
    text = "\n".join(["d0 = 50 mm; links with a path, distances "
                      f"{min(d) * 1e3:.0f}-{max(d) * 1e3:.0f} mm", "", "```", format_table(rows, cols), "```", "",
                      "Median path loss by distance:", "", "```", format_table(medians, bins), "```", "",
                      "RSS ranging with CM2 deep tissue on the same links:", "", "```",
                      format_table(rss, SUMMARY_COLUMNS), "```", ""])
    return text, {"fitted": model_dict(model), "links": links, "cm2_deep_tissue": model_dict(CM2), "rss": rss,
                  "median_by_distance": medians}


EXPERIMENTS: dict[str, Experiment] = {e.name: e for e in (
    Experiment("thesis-ch4-toa", ("thesis-ch4-toa-homogeneous", "thesis-ch4-toa-heterogeneous"), _toa_report,
               "TOA error (first peak, all peaks, GCC) vs frequency and distance, homogeneous vs heterogeneous"),
    Experiment("thesis-ch5-pdoa", ("thesis-ch5-pdoa", "torso-pdoa-bands"), _pdoa_report,
               "multi-tone PDOA at 400-420 MHz vs 2440-2460 MHz"),
    Experiment("torso-path-loss", ("torso-path-loss-402mhz",), _path_loss_report,
               "a path-loss model fitted to the torso beside IEEE 802.15.6 CM2"),
    Experiment("abdomen-ct-path-loss", ("abdomen-ct-path-loss-402mhz",),
               lambda tables: _path_loss_report(tables, "abdomen-ct-path-loss-402mhz", "the CT abdomen"),
               "a path-loss model fitted to the CT abdomen beside IEEE 802.15.6 CM2"),
)}


def write_report(name: str, out: Path, tables: dict[str, pa.Table]) -> str:
    """Write ``report.md`` / ``report.json`` (and a fitted model's ``path_loss_model.json``); returns the text."""
    exp = EXPERIMENTS[name]
    text, data = exp.report(tables)
    text = f"## {exp.name}: {exp.description}\n\n{text}"
    (out / "report.md").write_text(text)
    (out / "report.json").write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    if "fitted" in data:
        (out / "path_loss_model.json").write_text(json.dumps(data["fitted"], indent=2) + "\n")
    return text
