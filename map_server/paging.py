"""A map bigger than memory: hot tiles in the `TiledMap`, within a budget; cold tiles only in the SQLite store.

`TilePager` is owned by the service and called under its lock:
- `page_in(keys)` before a batch is merged: the batch's cold tiles are loaded from the store's `tiles` table
  (their blob is complete: a tile is written there, with the log id it holds everything up to, before it
  leaves memory, and it is paged back in before any later delta touches it);
- `evict()` after the batch is durable: when the map's tiles exceed the budget, the least recently used tiles
  are written to the store and the map is rebuilt from the remaining ones (dirty flags carried over, so the
  next snapshot still writes them) down to `low_water` of the budget. The budget holds between batches; while
  a batch merges, its own tiles are in memory as well (at most `batch_max` deltas' tiles);
- `region(...)`: a query box's hot cells from the map and its cold tiles' cells read from the store one tile
  at a time (nothing is paged in for a query, so a large query cannot evict the merge's working set, and a
  query holds its reply and one tile beyond the budget).
Totals stay exact whatever the budget: `cells` counts the cold tiles' occupied cells too.
Reads go through a connection of their own (WAL: they see committed data only).
"""

from __future__ import annotations

import logging
import sqlite3
from collections.abc import Iterable, Sequence

import numpy as np

from map_server.store import MapStore
from protocol.layers import pack_pair, unpack_pair
from psrmap_mapcore import TiledMap

__all__ = ["TilePager"]

log = logging.getLogger(__name__)

TileKey = tuple[int, int]


class TilePager:
    def __init__(self, store: MapStore, budget_bytes: int, low_water: float = 0.8) -> None:
        if store.path == ":memory:":
            raise ValueError("a tile budget needs a database file (--db): cold tiles live there")
        if budget_bytes <= 0:
            raise ValueError(f"tile budget {budget_bytes} bytes; need > 0")
        self.store = store
        self.budget = int(budget_bytes)
        self.low_water = low_water
        self.cold: dict[TileKey, int] = {}  # tile -> its occupied cells (any layer)
        self.cold_cells = 0
        self._use: dict[TileKey, int] = {}  # tile -> last use (a counter): LRU order
        self._clock = 0
        self._reader = sqlite3.connect(store.path, check_same_thread=False)
        self.paged_in = 0
        self.evicted = 0

    # ---------------------------------------------------------------------- bookkeeping

    def touch(self, keys: Iterable[TileKey]) -> None:
        self._clock += 1
        for k in keys:
            self._use[k] = self._clock

    @staticmethod
    def tiles_of(tiled: TiledMap, ix: np.ndarray, iy: np.ndarray) -> list[TileKey]:
        sh = tiled.shift
        k = np.unique(pack_pair(np.asarray(ix, np.int64) >> sh, np.asarray(iy, np.int64) >> sh))
        return [unpack_pair(v) for v in k.tolist()]

    def _blobs(self, tiled: TiledMap, key: TileKey) -> list[tuple[str, bytes]]:
        out = []
        for layer in tiled.grids:
            row = self._reader.execute(
                "SELECT data FROM tiles WHERE layer = ? AND tx = ? AND ty = ?", (layer, key[0], key[1])
            ).fetchone()
            if row is not None:
                out.append((layer, row[0]))
        return out

    # ---------------------------------------------------------------------- paging

    def page_in(self, tiled: TiledMap, keys: Sequence[TileKey]) -> int:
        """Load the cold ones of `keys` into `tiled` (their stored content is complete); returns how many."""
        n = 0
        for key in keys:
            cells = self.cold.pop(key, None)
            if cells is None:
                continue
            for layer, blob in self._blobs(tiled, key):
                tiled.load_tile(layer, key[0], key[1], blob)
            self.cold_cells -= cells
            n += 1
        self.paged_in += n
        self.touch(keys)
        return n

    def evict(self, tiled: TiledMap, protect: Iterable[TileKey] = ()) -> TiledMap:
        """Keep the map's tiles within the budget: write the least recently used ones to the store and return
        the map rebuilt without them (or `tiled` itself when it fits)."""
        used = tiled.nbytes()
        if used <= self.budget:
            return tiled
        resident = list(tiled.gslots)
        keep_protected = set(protect)
        per_tile = used / max(1, len(resident))
        n_out = len(resident) - int(self.low_water * self.budget / per_tile)
        order = sorted((k for k in resident if k not in keep_protected), key=lambda k: self._use.get(k, 0))
        out = order[: max(0, n_out)]
        if not out:
            log.warning(
                "tile budget %d bytes holds less than one batch's tiles (%d bytes)", self.budget, used
            )
            return tiled
        out_set = set(out)
        layer_keys = [
            (name, kx, ky)
            for name, grid in tiled.grids.items()
            for kx, ky in grid.slots
            if (kx, ky) in out_set
        ]
        self.store.write_tiles(tiled, layer_keys)  # durable before the tiles leave memory
        for k in out:
            g = tiled.gslots[k]
            cells = int(np.count_nonzero(tiled.occ[g]))
            self.cold[k] = cells
            self.cold_cells += cells
            self._use.pop(k, None)
        fresh = TiledMap(tiled.res, tiled.tile, layers=tuple(tiled.grids))
        dirty = tiled.dirty
        for name, grid in tiled.grids.items():
            for kx, ky in grid.slots:
                if (kx, ky) not in out_set:
                    fresh.load_tile(name, kx, ky, tiled.tile_blob(name, kx, ky))
        fresh.dirty = {d for d in dirty if (d[1], d[2]) not in out_set}
        self.evicted += len(out)
        return fresh

    # ---------------------------------------------------------------------- queries

    def region(
        self,
        tiled: TiledMap,
        ix0: int,
        iy0: int,
        ix1: int,
        iy1: int,
        layers: Sequence[str] | None,
        stats: Sequence[str],
    ) -> dict[str, dict[str, np.ndarray]]:
        """`tiled.region(...)` with the cold tiles' cells read from the store."""
        out = tiled.region(ix0, iy0, ix1, iy1, layers, stats)
        sh = tiled.shift
        cold = [
            (tx, ty)
            for ty in range(iy0 >> sh, (iy1 >> sh) + 1)
            for tx in range(ix0 >> sh, (ix1 >> sh) + 1)
            if (tx, ty) in self.cold
        ]
        for kx, ky in cold:  # one cold tile at a time: a query holds its reply and one tile, not the cold map
            scratch = TiledMap(tiled.res, tiled.tile, layers=tuple(tiled.grids))
            for layer, blob in self._blobs(tiled, (kx, ky)):
                scratch.load_tile(layer, kx, ky, blob)
            cx0, cx1 = max(ix0, kx << sh), min(ix1, ((kx + 1) << sh) - 1)
            cy0, cy1 = max(iy0, ky << sh), min(iy1, ((ky + 1) << sh) - 1)
            part = scratch.region(cx0, cy0, cx1, cy1, layers, stats)
            rows, cols = slice(cy0 - iy0, cy1 - iy0 + 1), slice(cx0 - ix0, cx1 - ix0 + 1)
            for name, st in out.items():
                for s, a in st.items():
                    a[rows, cols] = part[name][s]
        return out

    def close(self) -> None:
        self._reader.close()
