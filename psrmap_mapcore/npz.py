"""Maps on disk: one `.npz` in the `map_region` layout, written and read in one place.

Arrays `<layer>/<stat>` float64 (h, w) (row = iy - iy0, column = ix - ix0) and the scalars `res`,
`ix0`, `iy0`, `w`, `h`. A scout's `--save-map`, the experiments and `psrmap export` write it;
`psrmap plan --map-file`, the experiments and the agreement check read it back as a `LayerGrid`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from psrmap_mapcore.dense import LayerGrid, Layers
from psrmap_mapcore.errors import MapFileError

__all__ = ["read_npz", "write_npz"]


def write_npz(path: str | Path, grid: LayerGrid) -> Path:
    """Write `grid` (every layer and stat it holds) to `path` (compressed)."""
    arrays: dict[str, Any] = {
        "res": np.float64(grid.res),
        "ix0": np.int64(grid.ix0),
        "iy0": np.int64(grid.iy0),
        "w": np.int64(grid.w),
        "h": np.int64(grid.h),
    }
    for name, stats in grid.layers.items():
        for stat, a in stats.items():
            arrays[f"{name}/{stat}"] = a
    path = Path(path)
    np.savez_compressed(path, **arrays)
    return path


def read_npz(path: str | Path, map_id: str = "local", x0: float = 0.0, y0: float = 0.0) -> LayerGrid:
    """A LayerGrid from a `.npz` in `map_region` layout: arrays `<layer>/<stat>` (h, w) and scalars
    res, ix0, iy0 (w, h optional). Raises MapFileError naming what a valid file holds."""
    path = Path(path)
    if not path.is_file():
        raise MapFileError(f"no map file {str(path)!r}")
    try:
        z = np.load(path)
    except (OSError, ValueError) as exc:
        raise MapFileError(f"{path} is not a readable .npz map: {exc}") from None
    with z:
        missing = [k for k in ("res", "ix0", "iy0") if k not in z.files]
        if missing:
            raise MapFileError(
                f"{path} lacks {', '.join(missing)}; need res, ix0, iy0 and <layer>/<stat> arrays"
            )
        layers: Layers = {}
        for key in z.files:
            if "/" in key:
                layer, stat = key.split("/", 1)
                layers.setdefault(layer, {})[stat] = np.asarray(z[key], dtype=np.float64)
        if not layers:
            raise MapFileError(f"{path} holds no <layer>/<stat> arrays; files: {', '.join(z.files)}")
        shapes = {a.shape for st in layers.values() for a in st.values()}
        if len(shapes) != 1 or len(next(iter(shapes))) != 2:
            raise MapFileError(f"{path}: layer arrays must share one (h, w) shape, got {sorted(shapes)}")
        h, w = next(iter(shapes))
        return LayerGrid(map_id, float(z["res"]), int(z["ix0"]), int(z["iy0"]), h, w, layers, 0, x0, y0)
