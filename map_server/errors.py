"""The map server's exceptions: one root, `MapServerError`.

Malformed messages and queries are `protocol.ProtocolError`s (answered on the wire with their reason);
requests the map cannot answer are `mapcore.MapRequestError`s. What is wrong with the server itself
(its configuration, its store) is a `MapServerError`.
"""

from __future__ import annotations

__all__ = ["MapServerConfigError", "MapServerError"]


class MapServerError(Exception):
    """Root of every error the map server raises on purpose."""


class MapServerConfigError(MapServerError, ValueError):
    """A configuration, limit or store that does not fit (e.g. a store file of another map)."""
