"""LayerGrid: a dense box of map layers (numpy, NaN = unknown) with map-frame <-> cell transforms.

The dense view of the map core: built from a `TiledMap.region` read, from one or several
`protocol.MapRegion` replies (several map-server shards answer one query; `stitch` puts their boxes
together) or from a saved `.npz` map (`psrmap_mapcore.npz`, the same `map_region` layout).
Arrays are (h, w), row = iy - iy0, column = ix - ix0; a cell's centre is x0 + (ix + 0.5) * res.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from protocol.errors import MAX_CLIENT_CELLS
from protocol.layers import LAYERS, cell_index, datum_clash, empty_value, layer_value, map_slope_deg
from protocol.messages import MapRegion
from psrmap_mapcore.errors import MapCoreError

__all__ = ["MAX_CLIENT_CELLS", "LayerGrid", "Layers", "check_replies", "stitch"]


Layers = dict[str, dict[str, np.ndarray]]

_PLANE_STATS = (
    "n",
    "sum",
    "sx",
    "sy",
    "sxx",
    "syy",
    "sxy",
    "sxz",
    "syz",
)  # what an elevation plane fit reads


@dataclass(frozen=True, eq=False)
class LayerGrid:
    """Layers over cells ix0 .. ix0+w-1, iy0 .. iy0+h-1 of a map with cell size `res` [m] and origin
    (x0, y0) [m]; `layers[layer][stat]` is float64 (h, w)."""

    map: str
    res: float
    ix0: int
    iy0: int
    h: int
    w: int
    layers: Layers = field(default_factory=dict)
    version: int = 0
    x0: float = 0.0
    y0: float = 0.0

    @property
    def shape(self) -> tuple[int, int]:
        return self.h, self.w

    @classmethod
    def from_region(cls, region: MapRegion, x0: float = 0.0, y0: float = 0.0) -> LayerGrid:
        return cls(region.map, region.res, region.ix0, region.iy0, region.h, region.w,
                   {k: dict(v) for k, v in region.layers.items()}, region.version, x0, y0)  # fmt: skip

    # --- transforms -------------------------------------------------------------------------
    def cell_of(self, x: float, y: float) -> tuple[int, int] | None:
        """(row, col) of the cell holding map-frame point (x, y) [m], or None when outside the box."""
        col = int(np.floor((x - self.x0) / self.res)) - self.ix0
        row = int(np.floor((y - self.y0) / self.res)) - self.iy0
        if 0 <= row < self.h and 0 <= col < self.w:
            return row, col
        return None

    def centers(self, cells: np.ndarray) -> np.ndarray:
        """Map-frame centres [m] (k, 2) as (x, y) of cells (k, 2) given as (row, col)."""
        cells = np.asarray(cells)
        x = self.x0 + (cells[:, 1] + self.ix0 + 0.5) * self.res
        y = self.y0 + (cells[:, 0] + self.iy0 + 0.5) * self.res
        return np.stack([x, y], axis=1)

    def bounds_m(self) -> tuple[float, float, float, float]:
        """Map-frame box covered [m]: (x_min, y_min, x_max, y_max)."""
        xa, ya = self.x0 + self.ix0 * self.res, self.y0 + self.iy0 * self.res
        return xa, ya, xa + self.w * self.res, ya + self.h * self.res

    # --- layers -----------------------------------------------------------------------------
    def stat(self, layer: str, stat: str) -> np.ndarray:
        """The (h, w) array of `layer`/`stat`; MapCoreError naming what the grid holds otherwise."""
        if layer not in self.layers:
            have = ", ".join(sorted(self.layers)) or "none"
            raise MapCoreError(f"no layer {layer!r} in map {self.map!r}; layers: {have}")
        stats = self.layers[layer]
        if stat not in stats:
            raise MapCoreError(f"layer {layer!r} has no stat {stat!r}; stats: {', '.join(sorted(stats))}")
        return stats[stat]

    def count(self, layer: str) -> np.ndarray:
        """Samples per cell of `layer` (its `n`; 1 where only a finite value is known); zeros if absent."""
        stats = self.layers.get(layer)
        if not stats:
            return np.zeros(self.shape)
        if "n" in stats:
            return np.nan_to_num(stats["n"], nan=0.0)
        return np.isfinite(stats.get("value", np.full(self.shape, np.nan))).astype(np.float64)

    def value(self, layer: str) -> np.ndarray:
        """The layer's value per cell (NaN = unknown), NaN everywhere when the layer is absent.

        Recomputed from raw stats with `protocol.layers.layer_value` when they are all present (so a
        reply with `stats=all` suffices), else the reply's `value`."""
        stats = self.layers.get(layer)
        if not stats:
            return np.full(self.shape, np.nan)
        spec = LAYERS.get(layer)
        if spec is not None and all(s in stats for s in spec.stats):
            return layer_value(layer, stats)
        if "value" in stats:
            return stats["value"]
        raise MapCoreError(
            f"layer {layer!r} has neither 'value' nor all raw stats; stats: {', '.join(stats)}"
        )

    def slip_rate(self) -> np.ndarray:
        """Slip events per stance phase (events / n), NaN where no stance was seen."""
        return self.value("slip")

    def slope_deg(self) -> np.ndarray:
        """Terrain slope [deg] per cell, `protocol.layers.map_slope_deg`: the σ-weighted plane fit of the height
        layer where the cell has one, else the elevation layer's plane fit (or a reply's `slope_deg`); NaN where
        the fit is ill conditioned or the plane-fit stats are absent."""
        layers = self._raw(_PLANE_STATS)
        if "elevation" in layers:
            return map_slope_deg(layers)
        stats = self.layers.get("elevation", {})
        return stats["slope_deg"] if "slope_deg" in stats else np.full(self.shape, np.nan)

    def datum_clash(self) -> np.ndarray:
        """Cells whose footholds disagree by far more than their stated vertical σ (`protocol.layers.datum_clash`:
        scouts' datums clash there; its plane is not terrain); all False without both layers' raw stats."""
        layers = self._raw((*_PLANE_STATS, "sumsq"))
        if "elevation" not in layers:
            return np.zeros(self.shape, dtype=bool)
        return datum_clash(layers)

    def _raw(self, elevation: tuple[str, ...]) -> dict[str, dict[str, np.ndarray]]:
        """`elevation` when it holds the stats `elevation` names, and `height` when it holds all its raw stats."""
        need = {"elevation": elevation, "height": LAYERS["height"].stats}
        return {
            k: self.layers[k] for k, stats in need.items() if all(s in self.layers.get(k, {}) for s in stats)
        }


def check_replies(
    regions: Iterable[MapRegion],
    box_m: tuple[float, float, float, float] | None = None,
    max_cells: int = MAX_CLIENT_CELLS,
) -> None:
    """Before anything is allocated for them: every reply lies within the box the client asked for (`box_m`,
    map frame [m], inclusive; None: not checked), and their union box holds at most `max_cells` cells.
    MapCoreError naming the reply's box and the limit otherwise (a bad or hostile reply is refused, never
    allocated)."""
    regions = list(regions)
    if not regions:
        return
    for r in regions:
        if box_m is not None and r.w and r.h:
            ax0, ay0 = (int(v) for v in cell_index(box_m[0], box_m[1], r.res))
            ax1, ay1 = (int(v) for v in cell_index(box_m[2], box_m[3], r.res))
            if r.ix0 < ax0 or r.iy0 < ay0 or r.ix0 + r.w - 1 > ax1 or r.iy0 + r.h - 1 > ay1:
                raise MapCoreError(
                    f"a reply of map {r.map!r} covers cells x {r.ix0}..{r.ix0 + r.w - 1}, y {r.iy0}..{r.iy0 + r.h - 1}"
                    f"; the query asked for x {ax0}..{ax1}, y {ay0}..{ay1}: refused (not allocated)"
                )
    w = max(r.ix0 + r.w for r in regions) - min(r.ix0 for r in regions)
    h = max(r.iy0 + r.h for r in regions) - min(r.iy0 for r in regions)
    if w * h > max_cells:
        raise MapCoreError(
            f"replies span {w} × {h} = {w * h} cells; a client allocates at most {max_cells} (MAX_CLIENT_CELLS): "
            "refused (ask for a smaller box)"
        )


def stitch(
    regions: Iterable[MapRegion],
    x0: float = 0.0,
    y0: float = 0.0,
    box_m: tuple[float, float, float, float] | None = None,
    max_cells: int = MAX_CLIENT_CELLS,
) -> LayerGrid:
    """One LayerGrid over the union box of several `map_region` replies (e.g. one per server shard), after
    `check_replies(regions, box_m, max_cells)`.

    Shards own disjoint tiles, so per cell and layer the reply with data (largest `n`) wins; cells no
    reply covers hold the merge identity of each stat (0 for sums, +inf for min, -inf for max) and
    `value` NaN, exactly like an empty cell on the wire. All replies must share map id and `res`."""
    regions = [r for r in regions]
    if not regions:
        raise MapCoreError("no map_region to stitch")
    check_replies(regions, box_m, max_cells)
    first = regions[0]
    for r in regions[1:]:
        if r.map != first.map or r.res != first.res:
            raise MapCoreError(
                f"cannot stitch map {r.map!r} res {r.res} with map {first.map!r} res {first.res}"
            )
    if len(regions) == 1:
        return LayerGrid.from_region(first, x0, y0)
    ix0 = min(r.ix0 for r in regions)
    iy0 = min(r.iy0 for r in regions)
    ix1 = max(r.ix0 + r.w for r in regions)
    iy1 = max(r.iy0 + r.h for r in regions)
    h, w = iy1 - iy0, ix1 - ix0
    layers: Layers = {}
    best: dict[str, np.ndarray] = {}  # per layer: n of the reply chosen so far, -1 = none
    for r in regions:
        rows = slice(r.iy0 - iy0, r.iy0 - iy0 + r.h)
        cols = slice(r.ix0 - ix0, r.ix0 - ix0 + r.w)
        for name, stats in r.layers.items():
            out = layers.setdefault(name, {})
            raw = LAYERS[name].stats if name in LAYERS else ("n",)
            for s in stats:
                if s not in out:
                    out[s] = np.full((h, w), empty_value(s) if s in raw else np.nan)
            n_best = best.setdefault(name, np.full((h, w), -1.0))
            n_here = stats["n"] if "n" in stats else np.isfinite(stats.get("value", np.zeros((r.h, r.w))))
            take = np.asarray(n_here, dtype=np.float64) > n_best[rows, cols]
            for s, a in stats.items():
                out[s][rows, cols][take] = a[take]
            n_best[rows, cols][take] = np.asarray(n_here, dtype=np.float64)[take]
    version = max(r.version for r in regions)
    return LayerGrid(first.map, first.res, ix0, iy0, h, w, layers, version, x0, y0)
