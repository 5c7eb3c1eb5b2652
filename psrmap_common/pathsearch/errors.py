"""The path search's one exception."""

from __future__ import annotations

__all__ = ["PathSearchError"]


class PathSearchError(ValueError):
    """A search request that cannot be served (endpoint outside the grid or impassable, bad cost grid or
    cell size); the message names what would have been valid."""
