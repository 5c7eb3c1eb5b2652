"""Resource limits of a map server: every one configurable (`psrmap server --limit-*`), and a message or query
over one is rejected whole with a reason naming the limit and its value.

Worst-case memory follows from them: a tile holds 64×64 cells of every stat of a layer (≈ 0.9 MiB over all
layers), so one delta may allocate at most `max_new_tiles_per_delta` × 0.9 MiB and the whole map at most
`max_tiles` × 0.9 MiB; a query reply at most `max_reply_bytes`.
"""

from __future__ import annotations

from dataclasses import dataclass

from map_server.errors import MapServerConfigError
from protocol.errors import DEFAULT_MAX_BYTES


@dataclass(frozen=True)
class Limits:
    max_message_bytes: int = DEFAULT_MAX_BYTES  # a delta's payload, checked before it is copied [bytes]
    max_cells_per_delta: int = 50_000  # cells over all layers of one delta (a 5 Hz scout sends ~100)
    max_new_tiles_per_delta: int = 16  # tiles (64×64 cells) one delta may create
    max_tiles: int = 4096  # tiles in the whole map (≈ 2.8 km² at 0.4 m): the map's extent budget
    max_reply_bytes: int = 64 << 20  # statistics in one query reply [bytes]
    max_query_cells: int = 4_000_000  # cells in one query box

    def __post_init__(self) -> None:
        for name, v in self.__dict__.items():
            if not isinstance(v, int) or v < 1:
                raise MapServerConfigError(f"limit {name}={v!r}; need an integer >= 1")


__all__ = ["Limits"]
