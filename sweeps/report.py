"""Summaries of a results table: per frequency and ranging method, how far the ranges are off.

``error`` is a link's mean range error over its trials (estimate - straight-line distance).
``max_debiased_error_m`` is the thesis' Ch. 4 statistic: the largest |error| after the mean
error over all the links of that frequency and method is removed (the thesis removes the
mean over its four capsule positions); it shows the spread a calibration of the velocity
could not remove.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import pyarrow as pa

__all__ = ["format_table", "method_summary"]


def _floats(values) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], float)


def method_summary(table: pa.Table, methods: Sequence[str]) -> list[dict[str, Any]]:
    """One dict per (frequency, method): links, ranged links and error statistics [m]."""
    data = table.to_pydict()
    freqs = _floats(data["frequency_hz"]) if table.num_rows else np.empty(0)
    out = []
    for f in dict.fromkeys(freqs.tolist()):
        sel = freqs == f
        for m in methods:
            err = _floats(data[f"{m}_error_m"])[sel]
            std = _floats(data[f"{m}_std_m"])[sel]
            ok = np.isfinite(err)
            row: dict[str, Any] = {"frequency_hz": f, "method": m, "links": int(sel.sum()), "ranged": int(ok.sum())}
            if ok.any():
                e = err[ok]
                row.update(mean_error_m=float(e.mean()), max_abs_error_m=float(np.abs(e).max()),
                           max_debiased_error_m=float(np.abs(e - e.mean()).max()),
                           rms_error_m=float(np.sqrt(np.mean(e ** 2))), median_std_m=float(np.median(std[ok])))
            out.append(row)
    return out


def format_table(rows: Sequence[dict], columns: Sequence[tuple[str, str, str]]) -> str:
    """A plain-text table: ``columns`` are (key, header, format) with format e.g. ``{:.2f}`` or ``mm``
    (metres shown in millimetres, 2 decimals), ``MHz`` (hertz in MHz)."""
    def cell(row, key, fmt):
        v = row.get(key)
        if v is None:
            return "-"
        if fmt == "mm":
            return f"{v * 1e3:.2f}"
        if fmt == "MHz":
            return f"{v / 1e6:g}"
        return fmt.format(v)

    cells = [[h for _, h, _ in columns]] + [[cell(r, k, f) for k, _, f in columns] for r in rows]
    widths = [max(len(c[i]) for c in cells) for i in range(len(columns))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(cells[0], widths)), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in cells[1:]]
    return "\n".join(lines)


SUMMARY_COLUMNS = [("frequency_hz", "MHz", "MHz"), ("method", "method", "{}"), ("links", "links", "{}"),
                   ("ranged", "ranged", "{}"), ("mean_error_m", "mean err [mm]", "mm"),
                   ("max_abs_error_m", "max |err| [mm]", "mm"),
                   ("max_debiased_error_m", "max |err - mean| [mm]", "mm"), ("rms_error_m", "RMS [mm]", "mm"),
                   ("median_std_m", "median std [mm]", "mm")]
