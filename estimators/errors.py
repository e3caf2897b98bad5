"""Typed input errors of the estimators package.

Mirrors :class:`raytrace.errors.InputError` (same ``field`` / ``reason``
attributes and message shape) without importing the tracer, so the estimators
stay a pure, independent package. The service maps both to HTTP 422 with a
``detail`` naming ``field``.
"""

from __future__ import annotations


class EstimatorInputError(ValueError):
    """The caller asked the estimators for something invalid (HTTP 422).

    ``field`` is the dotted request path it is about (e.g. ``profile.paths[2].delay_s``,
    ``waveform.sample_rate_hz``), ``reason`` a human sentence.
    """

    def __init__(self, reason: str, field: str | None = None) -> None:
        self.reason = reason
        self.field = field
        super().__init__(f"{field}: {reason}" if field else reason)
