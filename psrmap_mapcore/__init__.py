"""mapcore: the one map core that scouts, map servers, planners and experiments share (pure numpy).

- `tiled.TiledMap`: tiled multi-layer storage of sufficient statistics, merge (the merge rule of
  `protocol.layers`), region reads, change tracking; each layer's tiles in `layer_tiles.LayerTiles`
  over reserved memory (`memory`).
- `dense.LayerGrid`: a dense box of layers with map-frame transforms; `dense.stitch` joins the
  replies of several shards.
- `npz`: the `.npz` map file, written and read in one place.
- `errors`: `MapCoreError`, the root of its exceptions.

It imports `protocol` (the layer table) and numpy, nothing else of psrmap and no transport.
"""

from __future__ import annotations

from psrmap_mapcore.dense import MAX_CLIENT_CELLS, LayerGrid, check_replies, stitch
from psrmap_mapcore.errors import MapCoreError, MapFileError, MapRequestError
from psrmap_mapcore.npz import read_npz, write_npz
from psrmap_mapcore.tiled import TiledMap

__all__ = [
    "LayerGrid",
    "MapCoreError",
    "MapFileError",
    "MapRequestError",
    "TiledMap",
    "read_npz",
    "stitch",
    "check_replies",
    "MAX_CLIENT_CELLS",
    "write_npz",
]
