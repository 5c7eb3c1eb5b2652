"""How a map is split over K map-server shards (wire contract v1, sharded maps).

A map's cells are grouped in square tiles of `tile` cells (the map servers' storage tile, a power of two);
each tile belongs to exactly one shard:

    tx, ty = ix >> log2(tile), iy >> log2(tile)          (floor: negative indices too)
    shard  = ((tx · 73856093) xor (ty · 19349663)) mod K  (int64 arithmetic, the classic spatial hash)

A hash, not stripes: the cells a fleet visits at any moment are spread over every shard whatever the routes,
so ingest grows with K; one scout's 5 Hz delta touches one or two tiles, so it is split into at most a few
parts. `K = 1` is the unsharded map of contract v1 (keys `psr/<map>/delta/<scout>` etc.); with `K > 1` shard
`i` subscribes `psr/<map>/shard/<i>/delta/*`, acks on `psr/<map>/shard/<i>/ack/<scout>` and holds the
liveliness token `psr/<map>/alive/server-<i>` (protocol.keys). Every shard answers the `partition` queryable
`psr/<map>/partition` with this object as msgpack, so scouts and planners discover K and the scheme from the
map itself. Each shard deduplicates on its own (scout, epoch, seq) stream: a scout numbers the parts it sends
to shard i 0, 1, 2, … within its epoch, so exactly-once holds per (scout, epoch, shard, seq).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from protocol.errors import ProtocolError

__all__ = ["SCHEME", "Partition"]

SCHEME = "tile-hash-v1"
_PX, _PY = np.int64(73856093), np.int64(19349663)
MAX_SHARDS = 1024


@dataclass(frozen=True)
class Partition:
    shards: int = 1  # K
    tile: int = 64  # cells per tile side (a power of two: the servers' storage tile)
    scheme: str = SCHEME

    def __post_init__(self) -> None:
        if self.scheme != SCHEME:
            raise ProtocolError("bad_value", f"partition scheme {self.scheme!r} unknown; schemes: {SCHEME}")
        if (
            isinstance(self.shards, bool)
            or not isinstance(self.shards, int)
            or not 1 <= self.shards <= MAX_SHARDS
        ):
            raise ProtocolError("bad_value", f"shards={self.shards!r}: valid is an integer 1..{MAX_SHARDS}")
        t = self.tile
        if isinstance(t, bool) or not isinstance(t, int) or t < 1 or t & (t - 1):
            raise ProtocolError("bad_value", f"tile={t!r}: valid is a power of two ≥ 1 (cells per tile side)")

    @property
    def shift(self) -> int:
        return self.tile.bit_length() - 1

    def check_shard(self, shard: int) -> int:
        if isinstance(shard, bool) or not isinstance(shard, int) or not 0 <= shard < self.shards:
            raise ProtocolError(
                "bad_value", f"shard {shard!r}: valid is 0..{self.shards - 1} of {self.shards}"
            )
        return shard

    def shard_of_tiles(self, tx: np.ndarray, ty: np.ndarray) -> np.ndarray:
        """Shard (int64 array) of each tile (tx, ty)."""
        if self.shards == 1:
            return np.zeros(np.shape(tx), np.int64)
        h = (np.asarray(tx, np.int64) * _PX) ^ (np.asarray(ty, np.int64) * _PY)
        return np.mod(h, self.shards)

    def shard_of(self, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
        """Shard (int64 array) of each cell (ix, iy)."""
        s = self.shift
        return self.shard_of_tiles(np.asarray(ix, np.int64) >> s, np.asarray(iy, np.int64) >> s)

    def split(
        self, layers: Mapping[str, Mapping[str, np.ndarray]]
    ) -> dict[int, dict[str, dict[str, np.ndarray]]]:
        """A delta's layers ({name: {"ix", "iy", stat: array}}) cut by shard: {shard: layers}; shards with no
        cell are absent, every cell lands in exactly one part."""
        out: dict[int, dict[str, dict[str, np.ndarray]]] = {}
        for name, cells in layers.items():
            ix = np.asarray(cells["ix"])
            if ix.size == 0:
                continue
            sh = self.shard_of(ix, np.asarray(cells["iy"]))
            for k in np.unique(sh).tolist():
                m = sh == k
                out.setdefault(int(k), {})[name] = {c: np.asarray(v)[m] for c, v in cells.items()}
        return out

    def to_dict(self) -> dict:
        return {"type": "partition", "scheme": self.scheme, "shards": self.shards, "tile": self.tile}

    @classmethod
    def from_dict(cls, d: object) -> Partition:
        if not isinstance(d, dict) or d.get("type") != "partition":
            raise ProtocolError(
                "wrong_type", "expected a partition object {type: 'partition', scheme, shards, tile}"
            )
        for k in ("scheme", "shards", "tile"):
            if k not in d:
                raise ProtocolError("missing_field", f"partition lacks {k!r}; fields: scheme, shards, tile")
        return cls(shards=d["shards"], tile=d["tile"], scheme=d["scheme"])
