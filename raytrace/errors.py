"""Typed errors of the physics core.

Every error carries the request ``field`` it is about and a human ``reason``.
``field`` is a dotted path (``receivers[2].position_m``) or, where a part is a
user-chosen name that may itself hold a dot (an organ or site of an upload
manifest), a tuple of parts (``("manifest", "sites", "Sphere.001")``);
:func:`field_text` writes either as text. The service maps
:class:`InputError` subclasses to HTTP 4xx and :class:`BudgetExceededError`
to 503/504; nothing here knows about HTTP.
"""

from __future__ import annotations

Field = str | tuple[str | int, ...]


def field_text(field: Field | None) -> str:
    """A field as dotted text (tuple parts joined with dots)."""
    if isinstance(field, tuple):
        return ".".join(str(part) for part in field)
    return field or ""


class CapsuleRTError(Exception):
    """Base of every error raised on purpose by CapsuleRT."""

    def __init__(self, reason: str, field: Field | None = None) -> None:
        self.reason = reason
        self.field = field
        super().__init__(f"{field_text(field)}: {reason}" if field else reason)


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
    """A request ran past its wall-time deadline, its work or its memory budget (HTTP 503/504).

    ``kind`` is ``"deadline"``, ``"work"``, ``"memory"`` or ``"cancelled"``.
    """

    def __init__(self, reason: str, kind: str = "deadline", field: Field | None = None) -> None:
        self.kind = kind
        super().__init__(reason, field)
