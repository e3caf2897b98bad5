"""Typed input errors of the vision package.

Same shape as :class:`raytrace.errors.InputError` and :class:`estimators.errors.EstimatorInputError`
(``field`` names the offending input, ``reason`` says why), without importing either package, so
the service can map all three to an HTTP 422 naming the field.
"""

from __future__ import annotations


class VisionInputError(ValueError):
    """The caller asked the vision package for something invalid (HTTP 422).

    ``field`` is the dotted input name it is about (``reference``, ``camera.fov_deg``,
    ``pose.position_m``), ``reason`` a human sentence.
    """

    def __init__(self, reason: str, field: str | None = None) -> None:
        self.reason = reason
        self.field = field
        super().__init__(f"{field}: {reason}" if field else reason)
