"""Typed errors of the design package: each names the request field it is about (docs/design.md)."""

from __future__ import annotations

from raytrace.errors import InputError


class DesignInputError(InputError):
    """A coverage or layout request that cannot be run as asked (HTTP 422 naming ``field``)."""
