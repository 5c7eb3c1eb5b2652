"""TiledMap: a tiled, multi-layer map of sufficient statistics in pure numpy (no transport).

Tile addressing (a map-wide tile number per `(tx, ty)`, a dense directory over the tiles' bounding box),
merging (`merge` of per-layer cell dicts, `merge_columns` of a decoded batch: one `ufunc.at` per stat
over the whole batch, never a Python loop per cell or per tile, by the merge rule of
`protocol.layers.merge_op`), region reads into dense arrays (`region`) and change tracking for
persistence (`dirty`, `take_touched`, `tile_blob`/`load_tile`). Each layer's tiles live in a
`layer_tiles.LayerTiles` store, so memory follows the visited area. Scouts, the map server, the planner
and the experiments all merge and read maps through this class.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from protocol.layers import LAYERS, derived_names, get_layer, layer_derived, merge_op, pack_pair, unpack_pair
from psrmap_mapcore.dense import LayerGrid
from psrmap_mapcore.errors import MapRequestError
from psrmap_mapcore.layer_tiles import LayerTiles, TileKey

__all__ = ["TiledMap"]

_DIR_LIMIT = 1 << 22  # entries of the dense tile directory (int32) before falling back to a dict lookup
_GROW_MIN = 16  # tiles added at least when the occupancy array grows


class _Cells:
    """Where a list of cells lies in the map (see `TiledMap._cell_ids`)."""

    __slots__ = ("g", "gu", "ix", "iy", "local", "marked", "pos")

    def __init__(
        self,
        ix: np.ndarray,
        iy: np.ndarray,
        g: np.ndarray,
        local: np.ndarray,
        pos: np.ndarray,
        gu: np.ndarray,
    ):
        self.ix, self.iy, self.g, self.local, self.pos, self.gu = ix, iy, g, local, pos, gu
        self.marked = False  # occupancy set for every one of these cells


class TiledMap:
    """Multi-layer tiled map of merged statistics.

    res: cell size [m]; tile: tile side [cells], a power of two. Tiles have map-wide numbers (a dense
    directory over the tiles' bounding box finds them without sorting); each layer stores its own tiles.
    """

    def __init__(self, res: float, tile: int = 64, layers: Iterable[str] | None = None) -> None:
        if tile <= 0 or tile & (tile - 1):
            raise ValueError(f"tile={tile}; need a power of two (e.g. 32, 64, 128)")
        self.res = float(res)
        self.tile = tile
        self.shift = tile.bit_length() - 1
        cells = tile * tile
        self.grids = {name: LayerTiles(get_layer(name), cells) for name in (layers or LAYERS)}
        self.gslots: dict[TileKey, int] = {}  # map-wide tile number of every tile of any layer
        self.gkeys: list[TileKey] = []  # number -> (tx, ty)
        self.occ = np.zeros((0, cells), dtype=bool)  # per map-wide tile: cell holds data in some layer
        self._dir = np.full((0, 0), -1, dtype=np.int32)  # dense directory: [ty - ty0, tx - tx0] -> number
        self._dir0 = (0, 0)  # (tx0, ty0) of the directory
        self._bbox: tuple[int, int, int, int] | None = None  # (tx0, ty0, tx1, ty1) of every tile, inclusive
        self._cells: int | None = 0
        self._last_cells: _Cells | None = None

    # ------------------------------------------------------------------ bookkeeping

    @property
    def cells(self) -> int:
        """Cells holding data in any layer."""
        if self._cells is None:
            self._cells = int(np.count_nonzero(self.occ[: len(self.gslots)]))
        return self._cells

    def _flagged(self, attr: str, clear: bool) -> set[tuple[str, int, int]]:
        out: set[tuple[str, int, int]] = set()
        for name, grid in self.grids.items():
            flags = getattr(grid, attr)
            for s in np.flatnonzero(flags[: len(grid.keys)]).tolist():
                kx, ky = grid.keys[s]
                out.add((name, kx, ky))
            if clear:
                flags[:] = False
        return out

    @property
    def dirty(self) -> set[tuple[str, int, int]]:
        """(layer, tx, ty) changed since `clear_dirty` (a copy; assign to replace)."""
        return self._flagged("dirty", False)

    @dirty.setter
    def dirty(self, value: set[tuple[str, int, int]]) -> None:
        for grid in self.grids.values():
            grid.dirty[:] = False
        for name, kx, ky in value:
            grid = self.grids[name]
            grid.dirty[grid.slots[(kx, ky)]] = True

    @property
    def touched(self) -> set[tuple[str, int, int]]:
        return self._flagged("touched", False)

    def _new_global(self, keys: Sequence[TileKey]) -> list[int]:
        g0 = len(self.gslots)
        gids = list(range(g0, g0 + len(keys)))
        for key, g in zip(keys, gids, strict=True):
            self.gslots[key] = g
        self.gkeys.extend(keys)
        if g0 + len(keys) > self.occ.shape[0]:
            occ = np.zeros((max(g0 + len(keys), 2 * self.occ.shape[0], _GROW_MIN), self.occ.shape[1]), bool)
            occ[:g0] = self.occ[:g0]
            self.occ = occ
        # the dense directory covers the bounding box of *all* tiles (with a margin, so a walking fleet does
        # not rebuild it at every new tile) while that box stays small; beyond, lookups go through the dict
        kx = [k[0] for k in keys]
        ky = [k[1] for k in keys]
        if self._bbox is None:
            bx0, by0, bx1, by1 = min(kx), min(ky), max(kx), max(ky)
        else:
            bx0, by0, bx1, by1 = self._bbox
            bx0, by0, bx1, by1 = min(bx0, *kx), min(by0, *ky), max(bx1, *kx), max(by1, *ky)
        self._bbox = (bx0, by0, bx1, by1)
        (tx0, ty0), (h, w) = self._dir0, self._dir.shape
        if h and tx0 <= bx0 and ty0 <= by0 and bx1 < tx0 + w and by1 < ty0 + h:
            self._dir[np.array(ky) - ty0, np.array(kx) - tx0] = gids
            return gids
        mx, my = max(4, (bx1 - bx0 + 1) // 2), max(4, (by1 - by0 + 1) // 2)
        nx0, nx1, ny0, ny1 = bx0 - mx, bx1 + mx, by0 - my, by1 + my
        if (nx1 - nx0 + 1) * (ny1 - ny0 + 1) <= _DIR_LIMIT:
            d = np.full((ny1 - ny0 + 1, nx1 - nx0 + 1), -1, dtype=np.int32)
            allk = np.array(list(self.gslots), dtype=np.int64).reshape(-1, 2)
            d[allk[:, 1] - ny0, allk[:, 0] - nx0] = np.fromiter(self.gslots.values(), np.int32)
            self._dir, self._dir0 = d, (nx0, ny0)
        else:
            self._dir, self._dir0 = np.full((0, 0), -1, dtype=np.int32), (0, 0)
        return gids

    def _global_ids(self, tx: np.ndarray, ty: np.ndarray) -> np.ndarray:
        """Map-wide tile numbers of cells' tiles (int64), creating numbers for new tiles."""
        for _ in range(2):
            (tx0, ty0), (h, w) = self._dir0, self._dir.shape
            if h:
                cx, cy = tx - tx0, ty - ty0
                inside = (cx >= 0) & (cx < w) & (cy >= 0) & (cy < h)
                if inside.all():
                    g = self._dir[cy, cx].astype(np.int64)
                    miss = g < 0
                    if not miss.any():
                        return g
                    keys = np.unique(pack_pair(tx[miss], ty[miss]))
                    self._new_global([unpack_pair(k) for k in keys])
                    continue
            break
        tkey = pack_pair(tx, ty)
        uniq, inv = np.unique(tkey, return_inverse=True)
        tiles = [unpack_pair(k) for k in uniq.tolist()]
        fresh = [k for k in tiles if k not in self.gslots]
        if fresh:
            self._new_global(fresh)
        return np.array([self.gslots[k] for k in tiles], dtype=np.int64)[inv.reshape(-1)]

    # ------------------------------------------------------------------ merging

    def merge(self, layers: Mapping[str, Mapping[str, np.ndarray]]) -> int:
        """Merge one delta's (or a batch's concatenated) layers; cells may repeat. Returns updates applied."""
        done = 0
        for name, cells in layers.items():
            grid = self._grid(name)
            ix = np.asarray(cells["ix"], dtype=np.int64)
            if ix.size == 0:
                continue
            iy = np.asarray(cells["iy"], dtype=np.int64)
            vals = np.stack([np.asarray(cells[s], dtype=np.float64) for s in grid.layer.stats])  # (S, N)
            done += self._merge_layer(name, grid, ix, iy, vals)
        return done

    def _grid(self, name: str) -> LayerTiles:
        grid = self.grids.get(name)
        if grid is None:
            raise MapRequestError(
                "unknown_layer", f"map has no layer {name!r}; layers: {', '.join(self.grids)}"
            )
        return grid

    def merge_many(self, deltas: Sequence[Mapping[str, Mapping[str, np.ndarray]]]) -> int:
        """Merge several deltas at once: their cells are concatenated per layer, then merged together."""
        if len(deltas) == 1:
            return self.merge(deltas[0])
        by_layer: dict[str, list[Mapping[str, np.ndarray]]] = {}
        for d in deltas:
            for name, cells in d.items():
                by_layer.setdefault(name, []).append(cells)
        done = 0
        for name, parts in by_layer.items():
            grid = self._grid(name)
            ix = np.concatenate([np.asarray(p["ix"], dtype=np.int64) for p in parts])
            if ix.size == 0:
                continue
            iy = np.concatenate([np.asarray(p["iy"], dtype=np.int64) for p in parts])
            vals = np.stack(
                [
                    np.concatenate([np.asarray(p[s], dtype=np.float64) for p in parts])
                    for s in grid.layer.stats
                ]
            )
            done += self._merge_layer(name, grid, ix, iy, vals)
        return done

    def merge_columns(self, name: str, ix: np.ndarray, iy: np.ndarray, vals: np.ndarray) -> int:
        """Merge one layer's cells given as columns: ix, iy (N,), vals (S, N) in the layer's stat order."""
        grid = self._grid(name)
        if not ix.size:
            return 0
        return self._merge_layer(name, grid, ix, iy, vals)

    def _cell_ids(self, ix: np.ndarray, iy: np.ndarray) -> _Cells:
        """Map-wide tile number, cell within the tile and flat occupancy index of each cell (int64).
        The layers of a batch usually list the same cells: the last answer is reused when ix, iy are
        equal to its inputs (tile numbers never change once given, so equal inputs, equal answer)."""
        last = self._last_cells
        if (
            last is not None
            and last.ix.shape == ix.shape
            and last.iy.shape == iy.shape
            and last.ix.dtype == ix.dtype
            and last.iy.dtype == iy.dtype
            and (last.ix == ix).all()
            and (last.iy == iy).all()
        ):
            return last
        sh, mask = self.shift, self.tile - 1
        x = ix.astype(np.int64, copy=False)
        y = iy.astype(np.int64, copy=False)
        g = self._global_ids(x >> sh, y >> sh)  # arithmetic shift = floor, also for negative indices
        local = ((y & mask) << sh) | (x & mask)
        pos = g * (self.tile * self.tile)
        pos += local
        seen = np.zeros(len(self.gkeys), dtype=bool)
        seen[g] = True
        gu = np.flatnonzero(seen)  # the tiles touched, ascending
        # copies of the inputs: the caller may reuse its arrays
        self._last_cells = _Cells(ix.copy(), iy.copy(), g, local, pos, gu)
        return self._last_cells

    def _merge_layer(
        self, name: str, grid: LayerTiles, ix: np.ndarray, iy: np.ndarray, vals: np.ndarray
    ) -> int:
        cells = self.tile * self.tile
        c = self._cell_ids(ix, iy)
        g, gu = c.g, c.gu
        su = grid.of_global[gu] if int(gu[-1]) < grid.of_global.size else None  # the tiles' slots
        if su is None or (su < 0).any():
            new = gu if su is None else gu[su < 0]
            keys = [self.gkeys[v] for v in new.tolist()]
            keys_gids = [(k, v) for k, v in zip(keys, new.tolist(), strict=True) if k not in grid.slots]
            if keys_gids:
                grid.add_tiles([k for k, _ in keys_gids], [v for _, v in keys_gids])
            su = grid.of_global[gu]
        slot = grid.of_global[g]
        S = len(grid.layer.stats)
        lin = slot * cells
        lin += c.local
        lin *= S  # index of a cell's first stat in the flat store
        flat = grid.store.reshape(-1)
        vals = np.ascontiguousarray(vals, dtype=np.float64)
        for ufunc, rows in grid.ops:
            for r in rows:  # one pass over the cells per stat (stat r of a cell at flat[r:][lin])
                ufunc.at(flat[r:], lin, vals[r])
        # counts are >= 0, so a cell holds data after the merge iff it did or the delta brings n > 0
        # (occupancy never goes back to False, so cells marked once stay marked)
        has = vals[grid.n_row] > 0
        occ = self.occ.reshape(-1)
        if has.all():
            if not c.marked:
                occ[c.pos] = True
                c.marked = True
        else:
            occ[c.pos[has]] = True
        self._cells = None
        grid.dirty[su] = True
        grid.touched[su] = True
        return int(vals.size)

    # ------------------------------------------------------------------ reading

    def region(
        self,
        ix0: int,
        iy0: int,
        ix1: int,
        iy1: int,
        layers: Sequence[str] | None = None,
        stats: Sequence[str] = ("value", "n"),
    ) -> dict[str, dict[str, np.ndarray]]:
        """Stats of the inclusive cell box, per layer: name -> float64 (h, w), row = iy - iy0.

        stats: raw stat names, `value`, derived names (`protocol.layers.layer_derived`), or `all`
        (every raw stat); names a layer lacks are skipped. Empty cells: n = 0, value/min/max = NaN.
        """
        if ix1 < ix0 or iy1 < iy0:
            raise MapRequestError(
                "bad_value", f"empty box [{ix0}..{ix1}] x [{iy0}..{iy1}]; need ix0 <= ix1, iy0 <= iy1"
            )
        names = list(self.grids) if layers is None else list(layers)
        out: dict[str, dict[str, np.ndarray]] = {}
        for name in names:
            grid = self.grids.get(name)
            if grid is None:
                raise MapRequestError(
                    "unknown_layer", f"map has no layer {name!r}; layers: {', '.join(self.grids)}"
                )
            raw = self._raw_block(grid, ix0, iy0, ix1, iy1)  # (S, h, w)
            by_stat = dict(zip(grid.layer.stats, raw, strict=True))
            want: list[str] = []
            for s in stats:
                if s == "all":
                    want.extend(grid.layer.stats)
                elif s == "value" or s in grid.layer.stats or s in derived_names(name):
                    want.append(s)
            layer_out: dict[str, np.ndarray] = {}
            empty = by_stat["n"] <= 0
            for s in dict.fromkeys(want):
                if s in by_stat and s not in ("value",):
                    a = by_stat[s]
                    if merge_op(s) != "add":
                        a = np.where(empty, np.nan, a)
                    layer_out[s] = a
                else:
                    layer_out[s] = layer_derived(name, s, by_stat)
            out[name] = layer_out
        return out

    def dense(
        self, ix0: int, iy0: int, ix1: int, iy1: int, map_id: str = "local", x0: float = 0.0, y0: float = 0.0
    ) -> LayerGrid:
        """The inclusive cell box as a dense `LayerGrid` with every raw stat and `value` of every layer."""
        layers = self.region(ix0, iy0, ix1, iy1, stats=("all", "value"))
        return LayerGrid(map_id, self.res, ix0, iy0, iy1 - iy0 + 1, ix1 - ix0 + 1, layers, 0, x0, y0)

    def bounds(self) -> tuple[int, int, int, int] | None:
        """(ix0, iy0, ix1, iy1), inclusive, of the cells holding data in some layer; None when empty."""
        g, local = np.nonzero(self.occ[: len(self.gkeys)])
        if not g.size:
            return None
        keys = np.asarray(self.gkeys, dtype=np.int64)[g]  # (k, 2) tile (tx, ty) of each cell
        ix = keys[:, 0] * self.tile + (local & (self.tile - 1))
        iy = keys[:, 1] * self.tile + (local >> self.shift)
        return int(ix.min()), int(iy.min()), int(ix.max()), int(iy.max())

    def layer_cells(self, name: str) -> dict[str, np.ndarray]:
        """Every cell of a layer with data (n > 0) as arrays: `ix`, `iy` (int32) and each raw stat,
        sorted by (iy, ix)."""
        grid = self._grid(name)
        used = grid.used()  # (slots, T*T, S)
        slot, local = np.nonzero(used[:, :, grid.n_row] > 0)
        keys = np.asarray(grid.keys, dtype=np.int64).reshape(-1, 2)[slot]
        ix = keys[:, 0] * self.tile + (local & (self.tile - 1))
        iy = keys[:, 1] * self.tile + (local >> self.shift)
        order = np.lexsort((ix, iy))
        out = {"ix": ix[order].astype(np.int32), "iy": iy[order].astype(np.int32)}
        vals = used[slot[order], local[order]]  # (k, S)
        for r, stat in enumerate(grid.layer.stats):
            out[stat] = vals[:, r].copy()
        return out

    def _raw_block(self, grid: LayerTiles, ix0: int, iy0: int, ix1: int, iy1: int) -> np.ndarray:
        T, sh = self.tile, self.shift
        h, w = iy1 - iy0 + 1, ix1 - ix0 + 1
        S = len(grid.layer.stats)
        out = np.empty((S, h, w))
        out[:] = grid.empty[:, :, None]
        if not grid.tiles:
            return out
        for ty in range(iy0 >> sh, (iy1 >> sh) + 1):
            for tx in range(ix0 >> sh, (ix1 >> sh) + 1):
                slot = grid.slots.get((tx, ty))
                if slot is None:
                    continue
                cx0, cx1 = max(ix0, tx * T), min(ix1, tx * T + T - 1)
                cy0, cy1 = max(iy0, ty * T), min(iy1, ty * T + T - 1)
                block = grid.store[slot].reshape(T, T, S)  # (row, column, stat)
                out[:, cy0 - iy0 : cy1 - iy0 + 1, cx0 - ix0 : cx1 - ix0 + 1] = block[
                    cy0 - ty * T : cy1 - ty * T + 1, cx0 - tx * T : cx1 - tx * T + 1, :
                ].transpose(2, 0, 1)
        return out

    def totals(self) -> dict[str, dict[str, float]]:
        """Per layer, the sum of every additive stat over all cells (for exactness checks)."""
        out: dict[str, dict[str, float]] = {}
        for name, grid in self.grids.items():
            out[name] = {}
            for i, s in enumerate(grid.layer.stats):
                if merge_op(s) == "add":
                    out[name][s] = float(sum(float(t[i].sum()) for t in grid.tiles.values()))
        return out

    def nbytes(self) -> int:
        """Bytes of the tiles in use (statistics + occupancy); spare store capacity is never touched."""
        return sum(g.used().nbytes for g in self.grids.values()) + self.occ[: len(self.gslots)].nbytes

    def equals(self, other: TiledMap) -> bool:
        """Same tiles and bit-identical statistics in every layer."""
        if set(self.grids) != set(other.grids):
            return False
        for name, grid in self.grids.items():
            og = other.grids[name]
            if set(grid.tiles) != set(og.tiles):
                return False
            for k, t in grid.tiles.items():
                if not np.array_equal(t, og.tiles[k]):
                    return False
        return True

    # ------------------------------------------------------------------ persistence helpers

    def tile_blob(self, layer: str, tx: int, ty: int) -> bytes:
        return self.grids[layer].tiles[(tx, ty)].astype("<f8", copy=False).tobytes()

    def load_tile(self, layer: str, tx: int, ty: int, blob: bytes) -> None:
        grid = self.grids[layer]
        cells = self.tile * self.tile
        data = np.frombuffer(blob, dtype="<f8").reshape(len(grid.layer.stats), cells)
        key = (tx, ty)
        gid = self.gslots.get(key)
        if gid is None:
            gid = self._new_global([key])[0]
        if key not in grid.slots:
            grid.add_tiles([key], [gid])
        s = grid.slots[key]
        grid.store[s] = data.T
        self.occ[gid] |= data[grid.n_row] > 0
        self._cells = None

    def take_touched(self) -> set[tuple[str, int, int]]:
        return self._flagged("touched", True)

    def clear_dirty(self) -> set[tuple[str, int, int]]:
        return self._flagged("dirty", True)
