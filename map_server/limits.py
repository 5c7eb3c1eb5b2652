"""Resource limits of a map server: every one configurable (`psrmap server --limit-*`), and a message or query
over one is rejected whole with a reason naming the limit and its value.

Worst-case memory follows from them: a tile holds 64×64 cells of every stat of a layer (≈ 1.5 MiB over all
layers), so one delta may allocate at most `max_new_tiles_per_delta` × 1.5 MiB, one scout at most
`max_new_tiles_per_scout_minute` × 1.5 MiB a minute, and the map's tiles in memory at most the tile budget
(`default_tile_budget_mib`: paging moves the rest to the store; without a store the budget caps `max_tiles`);
a query reply at most `max_reply_bytes`.
"""

from __future__ import annotations

from dataclasses import dataclass

from map_server.errors import MapServerConfigError
from protocol.errors import DEFAULT_MAX_BYTES

# Imports inside functions here are deliberate: `psrmap router --help` loads no numpy (tests/test_cli.py).


@dataclass(frozen=True)
class Limits:
    max_message_bytes: int = DEFAULT_MAX_BYTES  # a delta's payload, checked before it is copied [bytes]
    max_cells_per_delta: int = 50_000  # cells over all layers of one delta (a 5 Hz scout sends ~100)
    max_new_tiles_per_delta: int = 16  # tiles (64×64 cells) one delta may create
    max_tiles: int = 4096  # tiles in the whole map (≈ 2.8 km² at 0.4 m): the map's extent budget
    # fairness between scouts: the tiles one scout may create in all (its share of max_tiles) and per minute
    # (a token bucket holding at most a minute's worth); a walking scout creates a few tiles a minute
    max_tiles_per_scout: int = 1024
    max_new_tiles_per_scout_minute: int = 128
    max_reply_bytes: int = 64 << 20  # statistics in one query reply [bytes]
    max_query_cells: int = 4_000_000  # cells in one query box

    def __post_init__(self) -> None:
        for name, v in self.__dict__.items():
            if not isinstance(v, int) or v < 1:
                raise MapServerConfigError(f"limit {name}={v!r}; need an integer >= 1")


TILE_BUDGET_MIB_MIN, TILE_BUDGET_MIB_MAX = 64, 256


def default_tile_budget_mib(total_bytes: int | None = None) -> float:
    """The hot-tile budget a server takes when none is given: 1/16 of the machine's physical memory, within
    [64, 256] MiB (256 MiB ≈ 170 tiles of 64×64 cells, all layers: far more than the scouts' working set)."""
    if total_bytes is None:
        import psutil

        total_bytes = int(psutil.virtual_memory().total)
    return float(min(TILE_BUDGET_MIB_MAX, max(TILE_BUDGET_MIB_MIN, total_bytes / 16 / 2**20)))


def tile_bytes(tile: int) -> int:
    """Memory of one tile of `tile`×`tile` cells holding every layer (8-byte stats + an occupancy byte)."""
    from protocol.layers import LAYERS

    return tile * tile * (8 * sum(len(layer.stats) for layer in LAYERS.values()) + 1)


__all__ = ["tile_bytes", "TILE_BUDGET_MIB_MAX", "TILE_BUDGET_MIB_MIN", "Limits", "default_tile_budget_mib"]
