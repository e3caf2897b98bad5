"""The sweep's tables: their columns, and conversions to Parquet, CSV and JSON (``docs/sweeps.md``, "Results").

Results table: one row per (capsule position, frequency, receiver), sorted by
``position_index``, ``frequency_hz`` (the spec's order), ``receiver_index``. Columns, in
order: the position (``position_index``, ``capsule``, ``capsule_x_m`` / ``_y_m`` / ``_z_m``,
``s_m`` along the centreline, ``capsule_medium``), the link (``frequency_hz``,
``receiver_index``, ``receiver``, ``receiver_medium``, ``distance_m`` = the straight-line
capsule-receiver distance, the ranging truth), the channel (``paths``, ``first_delay_s``,
``first_group_delay_s`` when the tracer's paths carry a group delay, ``first_path_length_m``,
``direct_path``: a refraction-only path was found, ``path_gain_db``, ``rms_delay_spread_s``),
then per ranging method ``<m>_distance_m``, ``_error_m``, ``_std_m``, ``_rmse_m``, ``_crlb_m``
(PDOA adds ``_wrapped``) and ``note`` (why a value is missing). Missing values are nulls.

Localization table (when the spec asks for it): one row per (position, frequency, method),
see :mod:`sweeps.localization`.
"""

from __future__ import annotations

import io
import json
import math
from typing import Any, Iterable

import pyarrow as pa
import pyarrow.csv as pacsv

from raytrace.results import Path as TracedPath

__all__ = ["HAS_GROUP_DELAY", "LOCALIZATION_SCHEMA", "results_schema", "table_from_columns", "to_csv_bytes",
           "to_json_bytes"]

#: The tracer's paths carry a per-path group delay (the dispersion work); then the table has
#: ``first_group_delay_s``.
HAS_GROUP_DELAY = "group_delay_s" in getattr(TracedPath, "__dataclass_fields__", {})

_F64, _I32, _STR, _BOOL = pa.float64(), pa.int32(), pa.string(), pa.bool_()


def results_schema(methods: Iterable[str]) -> pa.Schema:
    fields = [
        ("position_index", _I32), ("capsule", _STR), ("capsule_x_m", _F64), ("capsule_y_m", _F64),
        ("capsule_z_m", _F64), ("s_m", _F64), ("capsule_medium", _STR),
        ("frequency_hz", _F64), ("receiver_index", _I32), ("receiver", _STR), ("receiver_medium", _STR),
        ("distance_m", _F64),
        ("paths", _I32), ("first_delay_s", _F64),
    ]
    if HAS_GROUP_DELAY:
        fields.append(("first_group_delay_s", _F64))
    fields += [("first_path_length_m", _F64), ("direct_path", _BOOL), ("path_gain_db", _F64),
               ("rms_delay_spread_s", _F64)]
    for m in methods:
        fields += [(f"{m}_{k}", _F64) for k in ("distance_m", "error_m", "std_m", "rmse_m", "crlb_m")]
        if m.startswith("pdoa_"):
            fields.append((f"{m}_wrapped", _BOOL))
    fields.append(("note", _STR))
    return pa.schema(fields)


LOCALIZATION_SCHEMA = pa.schema([
    ("position_index", _I32), ("capsule", _STR), ("frequency_hz", _F64), ("method", _STR),
    ("true_x_m", _F64), ("true_y_m", _F64), ("true_z_m", _F64),
    ("estimate_x_m", _F64), ("estimate_y_m", _F64), ("estimate_z_m", _F64),
    ("error_m", _F64), ("s_m", _F64), ("estimate_s_m", _F64), ("along_tract_error_m", _F64),
    ("receivers_used", _I32), ("note", _STR),
])


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def table_from_columns(columns: dict[str, list], schema: pa.Schema) -> pa.Table:
    """A table of ``schema`` from column lists (non-finite floats become nulls; missing columns nulls)."""
    n = len(next(iter(columns.values()))) if columns else 0
    arrays = []
    for f in schema:
        values = columns.get(f.name, [None] * n)
        arrays.append(pa.array([_clean(v) for v in values], type=f.type))
    return pa.Table.from_arrays(arrays, schema=schema)


def to_csv_bytes(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    return sink.getvalue()


def to_json_bytes(table: pa.Table) -> bytes:
    """``{"columns": [...], "rows": [{column: value}, ...]}`` (records), nulls for missing values."""
    columns = table.column_names
    rows = [{c: _clean(v) for c, v in row.items()} for row in table.to_pylist()]
    return json.dumps({"columns": columns, "rows": rows}, allow_nan=False, separators=(",", ":")).encode()
