"""The scout's exceptions: one root, `ScoutError`."""

from __future__ import annotations

__all__ = ["ScoutConfigError", "ScoutError", "ScoutLinkError"]


class ScoutError(Exception):
    """Root of every error the scout raises on purpose."""


class ScoutConfigError(ScoutError, ValueError):
    """A configuration, argument or input file the scout cannot run with; the message names what
    would be valid."""


class ScoutLinkError(ScoutError, ConnectionError):
    """The scout cannot reach the map service (no router answers on the given endpoints)."""
