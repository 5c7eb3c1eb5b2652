"""The experiments' maps: several runs' cells merged into one `LocalMap` (the server's merge rule), saved as a
`.npz` the planner reads back as a `LayerGrid`, and a layer laid out as a dense grid over the lunar field
(for the figures and for cell-by-cell comparisons of two maps).

`lunar`, `utility`, `utility_scores` and `plots` all read maps this way; it lives here, below all of them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from protocol.layers import layer_value
from psrmap.experiments.common import MAP_RES
from psrmap_mapcore import LayerGrid, read_npz
from scout_agent.cells import LocalMap

__all__ = ["FIELD_M", "dense", "merged_grid", "merged_local_map", "save_region_npz"]

FIELD_M = 20.0  # side of the lunar field [m] (`scout_agent.sim.terrain.LunarConfig`)


def merged_local_map(runs: list[dict], res: float = MAP_RES) -> LocalMap:
    """One `LocalMap` holding the merge of several runs' maps (the server's merge rule)."""
    local = LocalMap(res)
    for r in runs:
        layers = {k: v for k, v in r["cells"].items() if len(v["ix"])}
        if layers:
            local.merge(layers)
    return local


def save_region_npz(local: LocalMap, path: Path, size_m: float = FIELD_M) -> Path:
    """`LocalMap.save_npz` (map_region layout) covering the whole field [0, size]² at least, so that routes
    through unmapped cells can still be looked up."""
    n = int(round(size_m / local.res))
    return local.save_npz(path, cover=(0, 0, n - 1, n - 1))


def merged_grid(runs: list[dict], npz_path: Path, map_id: str) -> LayerGrid:
    """The merged map saved as `.npz` (map_region layout) and read back as the planner's `LayerGrid`."""
    save_region_npz(merged_local_map(runs), npz_path)
    return read_npz(npz_path, map_id=map_id)


def dense(
    cells: dict[str, np.ndarray],
    layer: str,
    size_m: float = FIELD_M,
    res: float = MAP_RES,
    what: str = "value",
) -> np.ndarray:
    """(n, n) grid over [0, size]² of a layer's value (or slip `events`); NaN where unmapped."""
    n = int(round(size_m / res))
    out = np.full((n, n), np.nan)
    if not len(cells["ix"]):
        return out
    v = cells["events"] if what == "events" else layer_value(layer, cells)
    ix, iy = cells["ix"], cells["iy"]
    ok = (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n)
    out[iy[ok], ix[ok]] = v[ok]
    return out
