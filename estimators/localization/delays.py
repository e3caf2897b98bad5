"""Which delay a measurement is (docs/localization.md, "Delay kinds"; docs/science.md (S21), (S22), (S26)).

A path through dispersive tissue has two delays: its **phase** delay (the carrier's phase,
``sum L_i Re n_i / c``, a traced path's ``delay_s``) and its **group** delay (the envelope's,
``sum L_i n_g,i / c`` with ``n_g = d(w Re n)/dw``, a traced path's ``group_delay_s``). On the
default torso they differ by ~10 %: tens of millimetres of range. A position fix on travel-time
fields must build its fields with the index of the delays it is given.

What each ranging method measures (docs/science.md, (S26)):

============================================  =========  ======================================
ranging                                       kind       why
============================================  =========  ======================================
TOA ``envelope``                              group      the correlation envelope's peak
PDOA ``two_tone``, ``regression``             group      the phase slope across the tones
TOA ``gcc``, ``all_peaks``, ``first_peak``    phase      the carrier's phase on the envelope's
                                                         cycle (plus the interfaces' Fresnel
                                                         phase)
============================================  =========  ======================================

A receiver that times a pulse's envelope or a correlation peak (the usual TOA receiver) measures
the group delay, so ``group`` is the default wherever nothing says otherwise.
"""

from __future__ import annotations

from typing import Any

from ..errors import EstimatorInputError

__all__ = ["DEFAULT_DELAY_KIND", "DELAY_KINDS", "check_delay_kind", "measured_delay_kind"]

#: The kinds of delay: the envelope's (group) and the carrier phase's (phase).
DELAY_KINDS = ("group", "phase")
#: What a TOA receiver timing an envelope or a correlation peak measures.
DEFAULT_DELAY_KIND = "group"

_MEASURES = {"envelope": "group", "pdoa": "group", "two_tone": "group", "regression": "group",
             "gcc": "phase", "all_peaks": "phase", "first_peak": "phase"}


def check_delay_kind(value: Any, field: str = "delay_kind") -> str:
    """``value`` if it is one of :data:`DELAY_KINDS`; else EstimatorInputError naming ``field``."""
    if not isinstance(value, str) or value not in DELAY_KINDS:
        raise EstimatorInputError(f"must be one of {' | '.join(DELAY_KINDS)}, got {value!r}", field)
    return value


def measured_delay_kind(ranging: str, field: str = "ranging") -> str:
    """The kind of delay a ranging method measures (module docstring). ``ranging`` is a method
    name (``gcc``, ``envelope``, ``pdoa``, ``regression``...) or a sweep's column prefix
    (``toa_gcc``, ``pdoa_regression``). RSS measures no delay: EstimatorInputError."""
    name = str(ranging)
    for prefix in ("toa_", "pdoa_"):
        if name.startswith(prefix):
            name = name[len(prefix):]
    kind = _MEASURES.get(name)
    if kind is None:
        raise EstimatorInputError(f"{ranging!r} measures no delay (delay methods: {', '.join(sorted(_MEASURES))})",
                                  field)
    return kind
