"""Small validators of request values (plain JSON types in, typed values out); every failure is a
:class:`~design.errors.DesignInputError` naming the dotted field."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from design.errors import DesignInputError


def number(value: Any, field: str, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise DesignInputError(f"must be a number, got {value!r}", field)
    x = float(value)
    if not math.isfinite(x):
        raise DesignInputError(f"must be finite, got {value!r}", field)
    if lo is not None and (x < lo or (lo_open and x == lo)):
        raise DesignInputError(f"must be {'>' if lo_open else '>='} {lo:g}, got {x:g}", field)
    if hi is not None and x > hi:
        raise DesignInputError(f"must be <= {hi:g}, got {x:g}", field)
    return x


def integer(value: Any, field: str, *, lo: int = 0, hi: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise DesignInputError(f"must be an integer, got {value!r}", field)
    if value < lo or (hi is not None and value > hi):
        raise DesignInputError(f"must be an integer in [{lo}, {hi if hi is not None else 'inf'}], got {value}", field)
    return int(value)


def vector(value: Any, field: str) -> np.ndarray:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 3:
        raise DesignInputError("must be three numbers (metres)", field)
    return np.array([number(v, f"{field}[{i}]") for i, v in enumerate(value)])


def mapping(value: Any, field: str, known: set[str]) -> Mapping:
    if not isinstance(value, Mapping):
        raise DesignInputError(f"must be an object, got {type(value).__name__}", field)
    unknown = set(value) - known
    if unknown:
        name = sorted(unknown)[0]
        raise DesignInputError(f"unknown field {name!r} (known: {', '.join(sorted(known))})",
                               f"{field}.{name}" if field else name)
    return value


def boolean(value: Any, field: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise DesignInputError(f"must be true or false, got {value!r}", field)
    return bool(value)
