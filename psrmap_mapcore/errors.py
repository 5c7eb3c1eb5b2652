"""The map core's exceptions: one root, `MapCoreError`."""

from __future__ import annotations

from protocol.errors import ProtocolError

__all__ = ["MapCoreError", "MapFileError", "MapRequestError"]


class MapCoreError(Exception):
    """Root of every error the map core raises."""


class MapRequestError(MapCoreError, ProtocolError):
    """A request the map cannot answer (unknown layer, empty box, ...). It is also a `ProtocolError`
    with a wire reason, so a server answers it to the client as it answers a malformed query."""


class MapFileError(MapCoreError, ValueError):
    """A map file (`.npz`) that is missing, unreadable or not in the `map_region` layout."""
