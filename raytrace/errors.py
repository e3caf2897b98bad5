"""Typed errors of the physics core.

Every error carries the request ``field`` it is about (dotted path, e.g.
``receivers[2].position_m``) and a human ``reason``. The service maps
:class:`InputError` subclasses to HTTP 4xx and :class:`BudgetExceededError`
to 503/504; nothing here knows about HTTP.
"""

from __future__ import annotations


class CapsuleRTError(Exception):
    """Base of every error raised on purpose by CapsuleRT."""

    def __init__(self, reason: str, field: str | None = None) -> None:
        self.reason = reason
        self.field = field
        super().__init__(f"{field}: {reason}" if field else reason)


class InputError(CapsuleRTError, ValueError):
    """The caller asked for something invalid (maps to HTTP 422)."""


class UnknownTissueError(InputError, KeyError):
    """A tissue name that is not in the Gabriel 1996 table (nor ``air``)."""

    def __str__(self) -> str:  # KeyError would otherwise repr() the message
        return Exception.__str__(self)


class FrequencyOutOfRangeError(InputError):
    """A frequency outside the validity range of the tissue model."""


class InvalidGeometryError(InputError):
    """Non-finite coordinates, a point outside the phantom, coincident antennas..."""


class AmbiguousPositionError(InvalidGeometryError):
    """A point lies on (within tolerance of) an organ surface: its medium is ambiguous."""


class PhantomValidationError(InputError):
    """An uploaded or constructed phantom is not a valid set of closed, nested organs."""


class NotFoundError(CapsuleRTError, LookupError):
    """An unknown phantom, scenario or site id (maps to HTTP 404)."""


class BudgetExceededError(CapsuleRTError):
    """A request ran past its wall-time deadline or its work budget (HTTP 503/504).

    ``kind`` is ``"deadline"`` or ``"work"``.
    """

    def __init__(self, reason: str, kind: str = "deadline", field: str | None = None) -> None:
        self.kind = kind
        super().__init__(reason, field)
