"""The one root exception of `psrmap_interop`: a map, option or message that cannot be written in a field format."""

from __future__ import annotations

__all__ = ["InteropError"]


class InteropError(ValueError):
    """Bad input to an exporter or bridge (an origin, a GID, an empty region); names what would be valid."""
