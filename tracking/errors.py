"""Typed input errors of the tracking package.

:class:`TrackingInputError` is a :class:`raytrace.errors.InputError` (``field`` names the offending
input, ``reason`` says why), so the service answers it with a 422 whose ``loc`` is that field.
"""

from __future__ import annotations

from raytrace.errors import InputError


class TrackingInputError(InputError):
    """The caller asked the trackers or the journey for something invalid (HTTP 422)."""
