"""Wire contract v1 messages as frozen dataclasses (numpy arrays inside; `codec` turns them into bytes)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from protocol.errors import ProtocolError
from protocol.layers import LAYERS, derived_names, get_layer

__all__ = [
    "VERSION",
    "Ack",
    "CellDelta",
    "LayerCells",
    "MapRegion",
    "RegionQuery",
    "ScoutStatus",
    "Status",
    "TileChanges",
]

VERSION = 1

# One layer of a delta: {"ix": int32 (N,), "iy": int32 (N,), <stat>: float64 (N,), ...}
LayerCells = dict[str, np.ndarray]


@dataclass(frozen=True, eq=False)
class CellDelta:
    """Statistics one scout gathered since its previous delta.

    epoch: unique per scout process start; seq: 0, 1, 2, ... per (scout, epoch) without gaps;
    t: scout clock [s] of the newest sample; res: cell size [m]; layers: layer -> LayerCells.
    """

    map: str
    scout: str
    epoch: int
    seq: int
    t: float
    res: float
    layers: dict[str, LayerCells] = field(default_factory=dict)

    def n_updates(self) -> int:
        """Cell-statistic updates carried: sum over layers of cells x stats."""
        return sum(len(c["ix"]) * (len(c) - 2) for c in self.layers.values())


@dataclass(frozen=True)
class Ack:
    """Server -> scout: every seq <= `seq` of (scout, epoch) is merged and persisted — except those listed in
    `conflicts`: seqs whose new content was rejected because other content was merged under them before."""

    map: str
    scout: str
    epoch: int
    seq: int
    conflicts: tuple[int, ...] = ()


@dataclass(frozen=True, eq=False)
class MapRegion:
    """A box of the map: layers -> stat/derived name -> float64 (h, w); row = iy - iy0, col = ix - ix0."""

    map: str
    res: float
    ix0: int
    iy0: int
    w: int
    h: int
    version: int
    layers: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class TileChanges:
    """Server -> subscribers, after each committed batch: the tiles (tile-index pairs (n, 2) int32: tx, ty; a
    tile covers cells [tx·tile, (tx+1)·tile) × [ty·tile, (ty+1)·tile)) whose statistics changed, and the map
    version (of this shard) that holds the change. A planner watching a region re-queries only when a tile
    it covers changed (consumer_planner.watch)."""

    map: str
    shard: int | None
    version: int
    res: float
    tile: int
    tiles: np.ndarray

    def boxes(self) -> np.ndarray:
        """(n, 4) cell boxes ix0, iy0, ix1, iy1 (inclusive) of the changed tiles."""
        t = np.asarray(self.tiles, np.int64).reshape(-1, 2) * self.tile
        return np.column_stack([t[:, 0], t[:, 1], t[:, 0] + self.tile - 1, t[:, 1] + self.tile - 1])


@dataclass(frozen=True)
class ScoutStatus:
    epoch: int
    last_seq: int  # highest seq merged without gaps in `epoch` (-1: none yet)
    alive: bool


@dataclass(frozen=True)
class Status:
    map: str
    res: float
    version: int
    cells: int
    merged: int
    duplicates: int
    rejected: dict[str, int] = field(default_factory=dict)
    scouts: dict[str, ScoutStatus] = field(default_factory=dict)
    # the merge worker's and the store's health: worker ok | waiting_for_store | failed, worker_error,
    # store ok | error | none, store_error (the original error of the last failed commit), last_commit_unix
    health: dict[str, str | float | None] = field(default_factory=dict)
    t: float = 0.0  # newest merged sample's scout clock [s] since the server started (mission time; 0: none)
    shard: int | None = None  # which shard of a sharded map answered (None: an unsharded map)
    shards: int = 1  # K of the map's partition (protocol.partition)
    # the inclusive cell box (ix0, iy0, ix1, iy1) of the cells holding data (paged-out tiles counted whole);
    # None: no data (or a server from before it was added). Clients query the whole map with `extent_m`.
    bounds: tuple[int, int, int, int] | None = None

    def extent_m(self) -> tuple[float, float, float, float] | None:
        """The map-frame box [m] (x0, y0, x1, y1) through the centres of the `bounds` corner cells: a query of
        it returns every cell holding data. None when the map is empty."""
        if self.bounds is None:
            return None
        ix0, iy0, ix1, iy1 = self.bounds
        r = self.res
        return ((ix0 + 0.5) * r, (iy0 + 0.5) * r, (ix1 + 0.5) * r, (iy1 + 0.5) * r)

    def to_json(self) -> dict:
        """Plain JSON-ready dict (what `psrmap status` prints and a mission's summary.json keeps)."""
        return {
            "map": self.map,
            "res": self.res,
            "version": self.version,
            "cells": self.cells,
            "merged": self.merged,
            "duplicates": self.duplicates,
            "rejected": dict(self.rejected),
            "scouts": {
                k: {"epoch": v.epoch, "last_seq": v.last_seq, "alive": v.alive}
                for k, v in self.scouts.items()
            },
            "health": dict(self.health),
            "t": self.t,
            "shard": self.shard,
            "shards": self.shards,
            "bounds": list(self.bounds) if self.bounds is not None else None,
        }


def _no_repeats(names: tuple[str, ...], what: str) -> None:
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise ProtocolError(
                "duplicate_name", f"{what} lists {n!r} more than once; name each at most once"
            )
        seen.add(n)


def _split(value: str) -> tuple[str, ...]:
    return tuple(s for s in (p.strip() for p in value.split(",")) if s)


@dataclass(frozen=True)
class RegionQuery:
    """Parameters of a `map` query: an inclusive map-frame box [m], layers (None = all) and stats.

    stats: raw statistic names, `value`, derived names (`layer_derived`), or `all` (every raw stat).
    """

    x0: float
    y0: float
    x1: float
    y1: float
    layers: tuple[str, ...] | None = None
    stats: tuple[str, ...] = ("value", "n")

    def to_parameters(self) -> str:
        # float() first: a numpy scalar's repr ("np.float64(1.5)") is not a number on the wire
        parts = [
            f"{k}={float(v)!r}"
            for k, v in (("x0", self.x0), ("y0", self.y0), ("x1", self.x1), ("y1", self.y1))
        ]
        if self.layers is not None:
            parts.append("layers=" + ",".join(self.layers))
        parts.append("stats=" + ",".join(self.stats))
        return ";".join(parts)

    @classmethod
    def parse(cls, params: str | Mapping[str, str]) -> RegionQuery:
        """Parse `x0=..;y0=..;x1=..;y1=..[;layers=a,b][;stats=value,n]`; ProtocolError on anything else."""
        if isinstance(params, str):
            items: dict[str, str] = {}
            for part in params.split(";"):
                if not part:
                    continue
                k, sep, v = part.partition("=")
                if not sep:
                    raise ProtocolError("missing_field", f"parameter {part!r} is not of the form name=value")
                items[k.strip()] = v.strip()
        else:
            items = dict(params)
        allowed = {"x0", "y0", "x1", "y1", "layers", "stats"}
        extra = sorted(set(items) - allowed)
        if extra:
            raise ProtocolError(
                "unknown_stat", f"unknown parameter(s) {extra}; parameters: {sorted(allowed)}"
            )
        box: list[float] = []
        for k in ("x0", "y0", "x1", "y1"):
            if k not in items:
                raise ProtocolError(
                    "missing_field", f"query needs {k}; give x0, y0, x1, y1 in map-frame metres"
                )
            try:
                num = float(items[k])
            except ValueError:
                raise ProtocolError("wrong_type", f"{k}={items[k]!r} is not a number") from None
            if not math.isfinite(num):
                raise ProtocolError("nonfinite", f"{k}={items[k]!r} must be finite")
            box.append(num)
        if box[2] < box[0] or box[3] < box[1]:
            raise ProtocolError("bad_value", f"empty box: need x0 <= x1 and y0 <= y1, got {box}")
        layers = None
        if "layers" in items:
            layers = _split(items["layers"])
            for name in layers:
                get_layer(name)
            _no_repeats(layers, "layers")
        stats = _split(items.get("stats", "value,n")) or ("value", "n")
        _no_repeats(stats, "stats")
        names = {"value", "all"} | {s for la in LAYERS.values() for s in la.stats}
        names |= {d for la in LAYERS for d in derived_names(la)}
        for s in stats:
            if s not in names:
                raise ProtocolError("unknown_stat", f"no stat {s!r}; stats: {', '.join(sorted(names))}")
        return cls(box[0], box[1], box[2], box[3], layers, stats)
