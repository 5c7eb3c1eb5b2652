"""One layer's tiles: a single store `(slots, T*T, S)` that grows by reserved address space.

`LayerTiles` keeps, for one layer, the tiles `(tx, ty)` in the slots of one float64 store (a cell's S
stats adjacent, so a merge touches one or two cache lines per cell), the map-wide tile number -> slot
directory, and per-slot flags: `dirty` (changed since the last snapshot) and `touched` (changed since
the last `take_touched`). Tile addressing across layers lives in `tiled.TiledMap`.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence

import numpy as np

from protocol.layers import Layer, empty_value, merge_op
from psrmap_mapcore.memory import reserve_float64

__all__ = ["RESERVE_TILES", "LayerTiles", "TileKey"]

TileKey = tuple[int, int]

_GROW_MIN = 16  # tiles added at least when a store grows without a reservation
RESERVE_TILES = 4096  # tiles of address space a layer's store reserves at first (pages come on use)


class _TileView(Mapping[TileKey, np.ndarray]):
    """Read-only `(tx, ty) -> (S, T*T)` view of a layer's tiles (views into the layer's store)."""

    def __init__(self, grid: LayerTiles) -> None:
        self._g = grid

    def __getitem__(self, key: TileKey) -> np.ndarray:
        return self._g.store[self._g.slots[key]].T  # (S, T*T) view of the (T*T, S) block

    def __iter__(self) -> Iterator[TileKey]:
        return iter(self._g.keys)

    def __len__(self) -> int:
        return len(self._g.keys)

    def __contains__(self, key: object) -> bool:
        return key in self._g.slots


class LayerTiles:
    """One layer's tiles, kept in one store `(capacity, T*T, S)` so a batch merges with one `ufunc.at`
    per merge operation over linear indices. `slots[(tx, ty)]` is a tile's row in the store; `tiles`
    is a `(tx, ty) -> (S, T*T)` mapping of (transposed) views. A cell's stats are adjacent, so a merge
    touches one or two cache lines per cell. The store sits in reserved address space (`_reserve`):
    pages of slots never used are never touched, so resident memory follows the tiles in use.
    """

    def __init__(self, layer: Layer, cells: int = 64 * 64) -> None:
        self.layer = layer
        ops = [merge_op(s) for s in layer.stats]
        rows = {
            op: np.array([i for i, o in enumerate(ops) if o == op], dtype=np.intp)
            for op in ("add", "min", "max")
        }
        self.add_rows, self.min_rows, self.max_rows = rows["add"], rows["min"], rows["max"]
        self.ops = [
            (ufunc, rows[op].tolist())
            for op, ufunc in (("add", np.add), ("min", np.minimum), ("max", np.maximum))
            if rows[op].size
        ]
        self.empty = np.array([[empty_value(s)] for s in layer.stats])  # (S, 1) merge identities
        self.n_row = layer.stats.index("n")
        self.cells = cells
        self.slots: dict[TileKey, int] = {}
        self.keys: list[TileKey] = []
        self.store = np.empty((0, cells, len(layer.stats)))
        self.of_global = np.full(0, -1, dtype=np.int64)  # map-wide tile number -> slot (-1: none)
        self.dirty = np.zeros(0, dtype=bool)  # per slot: changed since the last snapshot
        self.touched = np.zeros(0, dtype=bool)  # per slot: changed since `take_touched`

    @property
    def tiles(self) -> _TileView:
        return _TileView(self)

    def add_tiles(self, keys: Sequence[TileKey], gids: Sequence[int]) -> None:
        """New tiles (identity values) for `keys`, whose map-wide numbers are `gids`."""
        n0, k = len(self.keys), len(keys)
        if n0 + k > self.store.shape[0]:
            cap = max(n0 + k, 4 * self.store.shape[0], RESERVE_TILES)
            store = reserve_float64((cap, *self.store.shape[1:]))
            if store is None:  # no overcommit: grow geometrically with ordinary memory
                cap = max(n0 + k, 2 * self.store.shape[0], _GROW_MIN)
                store = np.empty((cap, *self.store.shape[1:]))
            if n0:  # only when the reservation is exhausted (or could not be made)
                store[:n0] = self.store[:n0]
            self.store = store
            for name in ("dirty", "touched"):
                flags = np.zeros(cap, dtype=bool)
                flags[:n0] = getattr(self, name)[:n0]
                setattr(self, name, flags)
        self.store[n0 : n0 + k] = self.empty.T[None, :, :]
        for j, key in enumerate(keys):
            self.slots[key] = n0 + j
        self.keys.extend(keys)
        top = max(gids) + 1 if k else 0
        if top > self.of_global.size:
            og = np.full(max(top, 2 * self.of_global.size), -1, dtype=np.int64)
            og[: self.of_global.size] = self.of_global
            self.of_global = og
        self.of_global[np.asarray(gids, dtype=np.int64)] = np.arange(n0, n0 + k)

    def used(self) -> np.ndarray:
        return self.store[: len(self.keys)]
