"""Decode a batch of cell_delta payloads at once, with the numeric checks vectorised over the batch.

Same acceptance and the same `ProtocolError` (reason and message) per delta as `codec.decode`, but
the per-cell work (finite, counts >= 0, index range, duplicate cells) runs as one numpy pass per layer
over all deltas, and the cells of each layer come back concatenated, ready to merge. A delta the fast
pass flags is re-checked alone to produce its exact error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from protocol.codec import (
    DEFAULT_MAX_BYTES,
    INDEX_LIMIT,
    _decode_layer,
    _layer_buffers,
    delta_header,
    unpack_envelope,
)
from protocol.errors import ProtocolError
from protocol.layers import Layer
from protocol.messages import CellDelta

__all__ = ["DeltaBatch", "LayerColumns", "decode_delta_batch"]

_I32 = np.dtype("<i4")
_F64 = np.dtype("<f8")


@dataclass
class LayerColumns:
    """One layer's cells from every valid delta of a batch: `seg[k]` = index of the delta of cell k."""

    layer: Layer
    seg: np.ndarray  # int64 (N,)
    ix: np.ndarray  # int32 (N,)
    iy: np.ndarray  # int32 (N,)
    vals: np.ndarray  # float64 (S, N), rows in `layer.stats` order


@dataclass
class DeltaBatch:
    """`results[i]` is the decoded delta of sample i or the ProtocolError that rejected it."""

    results: list[CellDelta | ProtocolError]
    columns: dict[str, LayerColumns] = field(default_factory=dict)


@dataclass
class _Parts:
    layer: Layer
    seg: list[int] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)
    ix: list[bytes] = field(default_factory=list)
    iy: list[bytes] = field(default_factory=list)
    stats: list[list[bytes]] = field(default_factory=list)  # per stat, the buffers of every delta


def _flag_cells(
    layer: Layer, ix: np.ndarray, iy: np.ndarray, vals: np.ndarray, seg: np.ndarray
) -> np.ndarray:
    """Segments (delta indices) with any bad cell in this layer."""
    bad = ~np.isfinite(vals).all(axis=0)
    for r, s in enumerate(layer.stats):
        if s in layer.counts:
            bad |= vals[r] < 0
    bad |= (ix < -INDEX_LIMIT) | (ix > INDEX_LIMIT) | (iy < -INDEX_LIMIT) | (iy > INDEX_LIMIT)
    flagged = set(np.unique(seg[bad]).tolist()) if bad.any() else set()
    if ix.size > 1:
        order = np.lexsort((iy, ix, seg))
        s_, x_, y_ = seg[order], ix[order], iy[order]
        dup = (s_[1:] == s_[:-1]) & (x_[1:] == x_[:-1]) & (y_[1:] == y_[:-1])
        if dup.any():
            flagged |= set(np.unique(s_[1:][dup]).tolist())
    return np.array(sorted(flagged), dtype=np.int64)


def decode_delta_batch(
    samples: Sequence[tuple[str | None, bytes]],
    *,
    res: float | None = None,
    max_bytes: int = DEFAULT_MAX_BYTES,
    views: bool = True,
) -> DeltaBatch:
    """Decode `(key, payload)` samples as cell_deltas; every failure is a ProtocolError in `results`.

    views=False skips building per-delta layer arrays: the CellDeltas then carry headers only
    (`layers` empty) and the cells are in `columns` (what the server merges).
    """
    results: list[CellDelta | ProtocolError] = []
    headers: dict[int, tuple] = {}
    raws: dict[int, dict] = {}
    parts: dict[str, _Parts] = {}
    for i, (key, payload) in enumerate(samples):
        try:
            d = unpack_envelope(payload, "cell_delta", max_bytes)
            head = delta_header(d, key, res)
            checked = [(name, _layer_buffers(name, raw)) for name, raw in head[6].items()]
        except ProtocolError as exc:
            results.append(exc)
            continue
        results.append(ProtocolError("decode", "pending"))  # replaced below
        headers[i] = head
        raws[i] = head[6]
        for name, (layer, ixb, iyb, statb, n) in checked:
            p = parts.get(name)
            if p is None:
                p = parts[name] = _Parts(layer, stats=[[] for _ in layer.stats])
            p.seg.append(i)
            p.counts.append(n)
            p.ix.append(ixb)
            p.iy.append(iyb)
            for lst, b in zip(p.stats, statb, strict=True):
                lst.append(b)
    columns: dict[str, LayerColumns] = {}
    bad: set[int] = set()
    for name, p in parts.items():
        seg = np.repeat(np.array(p.seg, dtype=np.int64), p.counts)
        ix = np.frombuffer(b"".join(p.ix), dtype=_I32)
        iy = np.frombuffer(b"".join(p.iy), dtype=_I32)
        vals = np.frombuffer(b"".join(b"".join(lst) for lst in p.stats), dtype=_F64).reshape(len(p.stats), -1)
        flagged = _flag_cells(p.layer, ix, iy, vals, seg)
        bad.update(flagged.tolist())
        columns[name] = LayerColumns(p.layer, seg, ix, iy, vals)
    for i in bad:  # exact error message from the single-delta path
        try:
            for name, raw in raws[i].items():
                _decode_layer(name, raw)
            results[i] = ProtocolError("decode", "batch check disagrees with single decode")
        except ProtocolError as exc:
            results[i] = exc
    if bad:
        drop = np.array(sorted(bad), dtype=np.int64)
        for name, c in list(columns.items()):
            keep = ~np.isin(c.seg, drop)
            columns[name] = LayerColumns(c.layer, c.seg[keep], c.ix[keep], c.iy[keep], c.vals[:, keep])
    # CellDelta views for callers that want per-delta objects
    per: dict[int, dict[str, dict[str, np.ndarray]]] = {i: {} for i in headers if i not in bad}
    for name, c in columns.items() if views else ():
        if not c.seg.size:
            for i in per:
                if name in raws[i]:
                    per[i][name] = _empty_cells(c.layer)
            continue
        starts = np.flatnonzero(np.r_[True, c.seg[1:] != c.seg[:-1]])
        ends = np.r_[starts[1:], c.seg.size]
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
            cells: dict[str, np.ndarray] = {"ix": c.ix[s:e], "iy": c.iy[s:e]}
            for r, stat in enumerate(c.layer.stats):
                cells[stat] = c.vals[r, s:e]
            per[int(c.seg[s])][name] = cells
        for i in per:  # layers present with zero cells
            if name in raws[i] and name not in per[i]:
                per[i][name] = _empty_cells(c.layer)
    for i, layers in per.items():
        map_id, scout, epoch, seq, t, r, _ = headers[i]
        results[i] = CellDelta(map_id, scout, epoch, seq, t, r, layers)
    return DeltaBatch(results, columns)


def _empty_cells(layer: Layer) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {"ix": np.empty(0, dtype=np.int32), "iy": np.empty(0, dtype=np.int32)}
    for s in layer.stats:
        out[s] = np.empty(0)
    return out
