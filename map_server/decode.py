"""Decode a batch of cell_delta payloads for the merge: msgspec for the msgpack, numpy for the numbers.

`DeltaDecoder.decode(samples)` returns, per sample, the decoded delta or the `ProtocolError` that
rejected it, and the cells of every accepted delta as one set of columns per layer, ready to merge.
Acceptance and errors are exactly `protocol.codec.decode`'s (the contract's reference decoder):

1. Each payload is decoded by msgspec with the header typed (types and ranges checked in C) and each
   layer kept as its raw msgpack bytes (`msgspec.Raw`: no Python object per array); unknown layers are
   refused there. Structs are not tracked by Python's cyclic GC (`gc=False`).
2. Per layer, the rows (that layer's bytes in each delta) of equal byte length form a group. Every row
   must equal msgspec's own encoding of a cells Struct of that many cells everywhere outside the arrays (`_Template`, found by
   encoding the Struct with arrays of 0x00 and of 0xFF; learnt per layer and length from one delta
   decoded with the typed Structs): then the row holds exactly those fields with those lengths, and
   numpy cuts the arrays of the whole group out at once. Rows in any other layout (another key order,
   other int widths) take the typed path: Structs built from the layer table (one per layer, its stats
   as fields, unknown stats refused), array lengths checked in Python, equal-length rows joined and cut
   the same way.
3. Over the whole batch at once: ids against the key expression, `res` against the map, finite `t`;
   then, one numpy pass per layer, finite statistics, counts >= 0, magnitudes and consistency
   (`protocol.consistency`), indices within +-2**30, no cell twice in one delta and layer.
4. Any payload msgspec refuses, or that a batch check flags, goes through `codec.decode` alone, which
   gives the exact reason and message (or accepts it: e.g. an int `t`, extra top-level fields).

Caches (key expression -> ids; (layer, byte length) -> template) belong to the decoder instance and are
bounded.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import chain
from operator import attrgetter
from types import MappingProxyType
from typing import Annotated, Any, Literal

import msgspec
import numpy as np

from protocol.codec import DEFAULT_MAX_BYTES, INDEX_LIMIT, decode
from protocol.consistency import bad_cells
from protocol.errors import ProtocolError
from protocol.keys import parse_delta_key, validate_id
from protocol.layers import LAYERS, Layer
from protocol.messages import CellDelta

__all__ = ["DeltaBatch", "DeltaDecoder", "LayerColumns"]

_I32 = np.dtype("<i4")
_F64 = np.dtype("<f8")
_INT64_MAX = 2**63 - 1
_NO_LAYERS: Mapping[str, dict[str, np.ndarray]] = MappingProxyType({})


@dataclass
class LayerColumns:
    """One layer's cells from every accepted delta of a batch: `seg[k]` = index of the delta of cell k."""

    layer: Layer
    seg: np.ndarray  # int64 (N,)
    ix: np.ndarray  # int32 (N,)
    iy: np.ndarray  # int32 (N,)
    vals: np.ndarray  # float64 (S, N), rows in `layer.stats` order

    def subset(self, keep: np.ndarray) -> LayerColumns:
        return LayerColumns(self.layer, self.seg[keep], self.ix[keep], self.iy[keep], self.vals[:, keep])


@dataclass
class DeltaBatch:
    """`results[i]` is the decoded delta of sample i or the ProtocolError that rejected it."""

    results: list[CellDelta | ProtocolError]
    columns: dict[str, LayerColumns] = field(default_factory=dict)


# --------------------------------------------------------------- the wire shape, as msgspec Structs

_Count = Annotated[int, msgspec.Meta(ge=0, le=_INT64_MAX)]


def _cells_struct(layer: Layer) -> type[msgspec.Struct]:
    fields = [("ix", bytes), ("iy", bytes), *((s, bytes) for s in layer.stats)]
    return msgspec.defstruct(f"{layer.name}_cells", fields, forbid_unknown_fields=True, gc=False)


_CELLS = {name: _cells_struct(layer) for name, layer in LAYERS.items()}
_LAYER_NAMES = tuple(LAYERS)
_Layers = msgspec.defstruct(
    "Layers",
    [(name, _CELLS[name] | msgspec.UnsetType, msgspec.UNSET) for name in _LAYER_NAMES],
    forbid_unknown_fields=True,
    gc=False,
)


class _Delta(msgspec.Struct, gc=False):
    """A cell_delta as `codec.encode` writes it (extra top-level fields are ignored, as the codec does)."""

    v: Literal[1]
    type: Literal["cell_delta"]
    map: str
    scout: str
    epoch: _Count
    seq: _Count
    t: float
    res: float
    layers: _Layers  # type: ignore[valid-type]


_astuple = msgspec.structs.astuple
_get_layers = attrgetter("layers")
_LAYER_GETTERS = tuple(attrgetter(name) for name in _LAYER_NAMES)


def _shape(d: Any) -> tuple[int, ...] | None:
    """Cells per layer (-1 where the delta lacks the layer), or None when a layer's arrays disagree in
    length (ix, iy: 4 bytes a cell; every stat: 8 bytes a cell)."""
    out = []
    for cells in _astuple(d.layers):
        if cells is msgspec.UNSET:
            out.append(-1)
            continue
        bufs = _astuple(cells)
        nb = len(bufs[0])
        if nb % 4 or len(bufs[1]) != nb or any(len(b) != 2 * nb for b in bufs[2:]):
            return None
        out.append(nb // 4)
    return tuple(out)


# every layer as its raw msgpack bytes (an absent layer: empty); unknown layers still refused
_LayersRaw = msgspec.defstruct(
    "LayersRaw",
    [(name, msgspec.Raw, msgspec.Raw()) for name in _LAYER_NAMES],
    forbid_unknown_fields=True,
    gc=False,
)
_DeltaRaw = msgspec.defstruct(
    "DeltaRaw",
    [(f.name, f.type if f.name != "layers" else _LayersRaw) for f in msgspec.structs.fields(_Delta)],
    gc=False,
)


class _Template:
    """A layer's cells of `cells` cells as msgspec encodes them (a map: ix, iy, then the stats in the
    layer's order, each a bin of its exact length): the byte positions outside the arrays and their
    values, and where each array starts. Found by encoding the Struct twice, arrays all 0x00 and all
    0xFF: the bytes that differ are exactly the arrays."""

    def __init__(self, layer: Layer, cells: int) -> None:
        fields = [("ix", bytes), ("iy", bytes), *((st, bytes) for st in layer.stats)]
        struct = msgspec.defstruct(f"{layer.name}_template", fields)
        sizes = [4 * cells, 4 * cells, *([8 * cells] * len(layer.stats))]
        zero = np.frombuffer(msgspec.msgpack.encode(struct(*(b"\x00" * s for s in sizes))), np.uint8)
        ones = np.frombuffer(msgspec.msgpack.encode(struct(*(b"\xff" * s for s in sizes))), np.uint8)
        differ = zero != ones
        self.size = zero.size
        self.cells = cells
        self.frame_idx = np.flatnonzero(~differ)
        self.frame_vals = zero[self.frame_idx].copy()
        # each array: a run of differing bytes, in field order
        edges = np.flatnonzero(np.diff(np.r_[0, differ.astype(np.int8), 0]) == 1)
        starts = [int(e) for e in edges]
        if cells == 0:  # no array bytes: the positions do not matter
            starts = [0] * len(sizes)
        self.ix, self.iy = starts[0], starts[1]
        self.stats = starts[2:]


# --------------------------------------------------------------- batch checks of the numbers


def _flag_values(layer: Layer, vals: np.ndarray, seg: np.ndarray) -> set[int]:
    """Deltas with a NaN/inf statistic, a negative count, a statistic out of range or inconsistent ones in
    this layer (`protocol.consistency`)."""
    counts = [r for r, s in enumerate(layer.stats) if s in layer.counts]
    # a sum is finite only if every term is (an overflow only sends the batch to the exact check)
    bad = np.zeros(seg.size, bool)
    with np.errstate(over="ignore", invalid="ignore"):
        total = np.add.reduce(vals, axis=None)
    if not (np.isfinite(total) and all(vals[r].min() >= 0 for r in counts)):
        bad = ~np.isfinite(vals).all(axis=0)
        for r in counts:
            bad |= vals[r] < 0
        vals = np.where(bad, 0.0, vals)  # the other cells are judged on their own below
    # magnitudes within MAX_STAT and statistics a real sample set could have
    for mask in bad_cells(layer, vals).values():
        bad |= mask
    if not bad.any():
        return set()
    return set(np.unique(seg[bad]).tolist())


def _flag_index(ix: np.ndarray, iy: np.ndarray, seg: np.ndarray) -> set[int]:
    """Deltas with an index beyond +-2**30 or a cell listed twice (within one delta and layer)."""
    bad = (ix < -INDEX_LIMIT) | (ix > INDEX_LIMIT) | (iy < -INDEX_LIMIT) | (iy > INDEX_LIMIT)
    flagged = set(np.unique(seg[bad]).tolist()) if bad.any() else set()
    if ix.size > 1:
        x0, y0 = int(ix.min()), int(iy.min())
        w, h = int(ix.max()) - x0 + 1, int(iy.max()) - y0 + 1
        if not flagged and (int(seg.max()) + 1) * w * h < 2**62:  # one sortable int64 key per cell
            key = np.sort((seg * w + (ix.astype(np.int64) - x0)) * h + (iy.astype(np.int64) - y0))
            dup = key[1:] == key[:-1]
            if dup.any():
                flagged |= set(np.unique(key[1:][dup] // (w * h)).tolist())
        else:
            order = np.lexsort((iy, ix, seg))
            s_, x_, y_ = seg[order], ix[order], iy[order]
            dup = (s_[1:] == s_[:-1]) & (x_[1:] == x_[:-1]) & (y_[1:] == y_[:-1])
            if dup.any():
                flagged |= set(np.unique(s_[1:][dup]).tolist())
    return flagged


def _concat(parts: list[LayerColumns]) -> LayerColumns:
    if len(parts) == 1:
        return parts[0]
    return LayerColumns(
        parts[0].layer,
        np.concatenate([p.seg for p in parts]),
        np.concatenate([p.ix for p in parts]),
        np.concatenate([p.iy for p in parts]),
        np.concatenate([p.vals for p in parts], axis=1),
    )


class DeltaDecoder:
    """Decodes batches of `(key expression | None, payload)` cell_delta samples for one map.

    res: the map's cell size (a delta with another res is rejected), or None to accept any;
    max_bytes: larger payloads are rejected as oversize. Not thread-safe (one per merge worker).
    """

    _MAX_KEYS = 4096
    _MAX_TEMPLATES = 4096  # (layer, length) pairs: every cell count up to the limits, for every layer

    def __init__(self, res: float | None = None, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        self.res = res
        self.max_bytes = max_bytes
        self._msgspec = msgspec.msgpack.Decoder(_Delta)
        self._ids: dict[str | tuple[str, str], tuple[str, str] | None] = {}
        self._raw = msgspec.msgpack.Decoder(_DeltaRaw)
        # (layer index, raw byte length) -> the template of msgspec's own encoding of that many cells
        self._templates: dict[tuple[int, int], _Template] = {}

    def _key_ids(self, key: str) -> tuple[str, str] | None:
        """(map, scout) a delta key expression names, None if it is no valid delta key (cached)."""
        ids = self._ids.get(key, False)
        if ids is False:
            try:
                kmap, kscout = parse_delta_key(key)
                ids = (validate_id(kmap, "map"), validate_id(kscout, "scout"))
            except ProtocolError:
                ids = None
            if len(self._ids) >= self._MAX_KEYS:
                self._ids.clear()
            self._ids[key] = ids
        return ids  # type: ignore[return-value]

    def _valid_ids(self, map_id: str, scout: str) -> bool:
        """Both ids valid (deltas replayed without a key expression); cached like key expressions."""
        got = self._ids.get((map_id, scout), False)
        if got is False:
            try:
                got = (validate_id(map_id, "map"), validate_id(scout, "scout"))
            except ProtocolError:
                got = None
            if len(self._ids) >= self._MAX_KEYS:
                self._ids.clear()
            self._ids[(map_id, scout)] = got
        return got is not None

    def _ids_ok(self, heads: list[tuple[str | None, str, str]]) -> np.ndarray:
        """Per (key expression, map, scout): the ids are valid and are the ones the key names."""
        out = np.empty(len(heads), bool)
        memo: dict[tuple[str | None, str, str], bool] = {}
        for k, h in enumerate(heads):
            got = memo.get(h)
            if got is None:
                key, map_id, scout = h
                got = memo[h] = (
                    self._valid_ids(map_id, scout) if key is None else self._key_ids(key) == (map_id, scout)
                )
            out[k] = got
        return out

    def decode(self, samples: Sequence[tuple[str | None, bytes]], *, views: bool = False) -> DeltaBatch:
        """Decode and check every sample; each failure is a ProtocolError in `results`.

        views=False (what the server merges): the CellDeltas carry headers only (`layers` an empty
        read-only mapping) and the cells are in `columns`. views=True also gives each CellDelta its
        layers as arrays (views into the columns)."""
        n = len(samples)
        results: list[Any] = [None] * n
        slow: list[int] = []  # decided by the reference decoder
        typed: list[tuple[int, Any, tuple[int, ...]]] = []  # (sample, typed Struct, shape)
        fast: list[tuple[int, Any, tuple[Any, ...]]] = []  # (sample, Struct with raw layers, the raw layers)
        max_bytes = self.max_bytes
        raw = self._raw.decode
        astuple = _astuple
        for i, (_, payload) in enumerate(samples):
            if len(payload) > max_bytes:
                slow.append(i)
                continue
            try:
                d: Any = raw(payload)  # header typed and checked in C, layers as raw bytes
            except (msgspec.MsgspecError, ValueError, TypeError):  # the reference decoder names it
                slow.append(i)
                continue
            fast.append((i, d, astuple(d.layers)))
        fast = self._checked_headers(samples, fast, slow)
        parts: dict[str, list[LayerColumns]] = {}
        retry = self._fast_columns(fast, parts, samples)  # rows not in msgspec's own layout: typed path
        for i in retry:
            self._decode_typed(i, samples[i][1], typed, slow)
        typed = self._checked_headers(samples, typed, slow)
        self._typed_columns(typed, parts)
        if typed or retry:
            again = set(retry)
            done = sorted([(i, d) for i, d, _ in typed] + [(i, d) for i, d, _ in fast if i not in again])
            ok_idx = [i for i, _ in done]
            ok_delta = [d for _, d in done]
        else:  # every delta on the fast path, in sample order
            ok_idx = [i for i, _, _ in fast]
            ok_delta = [d for _, d, _ in fast]
        bad: set[int] = set()
        columns: dict[str, LayerColumns] = {}
        last_index: tuple[np.ndarray, np.ndarray, np.ndarray, set[int]] | None = None
        for name in _LAYER_NAMES:
            if name not in parts:
                continue
            c = columns[name] = _concat(parts[name])
            if c.seg.size:
                bad |= _flag_values(c.layer, c.vals, c.seg)
                # the layers of a delta usually list the same cells: equal (seg, ix, iy), equal flags
                li = last_index
                if li is None or not (
                    li[0].size == c.seg.size
                    and (li[0] == c.seg).all()
                    and (li[1] == c.ix).all()
                    and (li[2] == c.iy).all()
                ):
                    li = last_index = (c.seg, c.ix, c.iy, _flag_index(c.ix, c.iy, c.seg))
                bad |= li[3]
        if bad:
            drop = np.array(sorted(bad), np.int64)
            for name, c in list(columns.items()):
                if c.seg.size and np.isin(c.seg, drop).any():
                    columns[name] = c.subset(~np.isin(c.seg, drop))
        names_of: dict[int, tuple[str, ...]] = {}
        new, put = object.__new__, object.__setattr__
        for i, d in zip(ok_idx, ok_delta, strict=True):
            if i in bad:
                continue
            results[i] = obj = new(CellDelta)
            put(obj, "__dict__", {"map": d.map, "scout": d.scout, "epoch": d.epoch, "seq": d.seq,
                                  "t": float(d.t), "res": float(d.res), "layers": _NO_LAYERS})  # fmt: skip
            if views:
                names_of[i] = tuple(
                    nm
                    for nm, c in zip(_LAYER_NAMES, _astuple(d.layers), strict=True)
                    if c is not msgspec.UNSET and not (type(c) is msgspec.Raw and len(c) == 0)
                )
        # the reference decoder decides everything the batch path did not vouch for
        extra: list[LayerColumns] = []
        for i in sorted(set(slow) | bad):
            key, payload = samples[i]
            try:
                delta = decode(
                    bytes(payload), expected_type="cell_delta", key=key, res=self.res, max_bytes=max_bytes
                )
            except ProtocolError as exc:
                results[i] = exc
                continue
            assert isinstance(delta, CellDelta)  # expected_type="cell_delta"
            results[i] = delta
            for name, lc in delta.layers.items():
                layer = LAYERS[name]
                vals = (
                    np.stack([lc[s] for s in layer.stats])
                    if lc["ix"].size
                    else np.empty((len(layer.stats), 0))
                )
                extra.append(
                    LayerColumns(layer, np.full(lc["ix"].size, i, np.int64), lc["ix"], lc["iy"], vals)
                )
        for c in extra:
            columns[c.layer.name] = _concat([columns[c.layer.name], c]) if c.layer.name in columns else c
        if views:
            self._attach_views(results, columns, names_of)
        return DeltaBatch(results, columns)

    def _decode_typed(
        self, i: int, payload: bytes, typed: list[tuple[int, Any, tuple[int, ...]]], slow: list[int]
    ) -> None:
        """Decode one sample with the typed Structs, its array lengths checked in Python."""
        try:
            d = self._msgspec.decode(payload)
        except (msgspec.MsgspecError, ValueError, TypeError):  # the reference decoder names what is wrong
            slow.append(i)
            return
        shape = _shape(d)
        if shape is None:  # arrays of one layer disagree in length
            slow.append(i)
            return
        typed.append((i, d, shape))

    def _checked_headers(
        self,
        samples: Sequence[tuple[str | None, bytes]],
        decoded: list[tuple[int, Any, tuple[int, ...]]],
        slow: list[int],
    ) -> list[tuple[int, Any, tuple[int, ...]]]:
        """The decoded samples whose header passes, over the batch at once: ids against the key
        expression, finite t, res of the map. The others go to `slow`."""
        if not decoded:
            return decoded
        heads = [(samples[i][0], d.map, d.scout) for i, d, _ in decoded]
        t = np.array([d.t for _, d, _ in decoded], np.float64)
        r = np.array([d.res for _, d, _ in decoded], np.float64)
        good = self._ids_ok(heads) & np.isfinite(t) & np.isfinite(r) & (r > 0)
        if self.res is not None:
            good &= r == self.res
        if good.all():
            return decoded
        slow.extend(i for (i, _, _), g in zip(decoded, good.tolist(), strict=True) if not g)
        return [x for x, g in zip(decoded, good.tolist(), strict=True) if g]

    def _fast_columns(
        self,
        fast: list[tuple[int, Any, tuple[Any, ...]]],
        parts: dict[str, list[LayerColumns]],
        samples: Sequence[tuple[str | None, bytes]],
    ) -> list[int]:
        """Columns of the deltas decoded with raw layers. Per layer, the rows of equal byte length form a
        group; every row must equal msgspec's own encoding of a cells Struct of that many cells outside
        the arrays (`_Template`), so it holds exactly those fields and lengths, and numpy cuts the arrays
        of the whole group out at once. Returns the samples with a row in any other layout (another key
        order, other int widths, wrong lengths): they take the typed path, with all their layers."""
        if not fast:
            return []
        idx_all = np.array([i for i, _, _ in fast], np.int64)
        n_layers = len(_LAYER_NAMES)
        lays = [lay for _, _, lay in fast]
        lens_all = np.fromiter(
            map(len, chain.from_iterable(lays)), np.int64, idx_all.size * n_layers
        ).reshape(-1, n_layers)  # (n, layers): each layer's byte length, 0 where absent
        by_layer = list(zip(*lays, strict=True))  # per layer: the raws of every delta
        bad = np.zeros(idx_all.size, bool)
        all_rows = np.arange(idx_all.size)
        checked: list[tuple[str, np.ndarray, np.ndarray, _Template]] = []  # (layer, rows of fast, rows, tpl)
        for j, name in enumerate(_LAYER_NAMES):
            sizes = lens_all[:, j]
            raws = by_layer[j]
            lo, hi = int(sizes.min()), int(sizes.max())
            if lo == hi:  # one size for every delta (or absent from all)
                sizes_here = [hi] if hi > 0 else []
            else:
                sizes_here = np.unique(sizes[sizes > 0]).tolist()
            for size in sizes_here:
                sel = all_rows if lo == hi else np.flatnonzero(sizes == size)
                tpl = self._template(j, size, samples[int(idx_all[sel[0]])][1])
                if tpl is None:
                    bad[sel] = True
                    continue
                rows = np.frombuffer(b"".join([raws[x] for x in sel.tolist()]), np.uint8).reshape(
                    sel.size, size
                )
                bad[sel] |= ~(rows[:, tpl.frame_idx] == tpl.frame_vals).all(axis=1)
                checked.append((name, sel, rows, tpl))
        for name, sel, rows, tpl in checked:
            keep = ~bad[sel]
            if not keep.all():
                sel, rows = sel[keep], rows[keep]
            if not sel.size:
                continue
            m, k = sel.size, tpl.cells
            ix = rows[:, tpl.ix : tpl.ix + 4 * k].view(_I32).reshape(-1)
            iy = rows[:, tpl.iy : tpl.iy + 4 * k].view(_I32).reshape(-1)
            vals = np.empty((len(tpl.stats), m * k))
            for r, a in enumerate(tpl.stats):
                vals[r] = rows[:, a : a + 8 * k].view(_F64).reshape(-1)
            parts.setdefault(name, []).append(
                LayerColumns(LAYERS[name], np.repeat(idx_all[sel], k), ix, iy, vals)
            )
        return idx_all[bad].tolist()

    def _typed_columns(
        self, typed: list[tuple[int, Any, tuple[int, ...]]], parts: dict[str, list[LayerColumns]]
    ) -> None:
        """Columns of the typed-decoded deltas: deltas of one shape have equal-length arrays, so each layer
        of a shape group is one joined buffer of equal rows (ix | iy | stats), cut into columns by numpy."""
        groups: dict[tuple[int, ...], tuple[list[int], list[Any]]] = {}
        for i, d, shape in typed:
            g = groups.get(shape)
            if g is None:
                g = groups[shape] = ([], [])
            g[0].append(i)
            g[1].append(d.layers)
        for shape, (gidx, glayers) in groups.items():
            idx = np.array(gidx, np.int64)
            for name, k, get in zip(_LAYER_NAMES, shape, _LAYER_GETTERS, strict=True):
                if k < 0:
                    continue
                layer = LAYERS[name]
                S = len(layer.stats)
                m = idx.size
                rows = np.frombuffer(
                    b"".join(chain.from_iterable(map(_astuple, map(get, glayers)))), np.uint8
                ).reshape(m, 8 * k * (S + 1))
                # dtype views of the rows' byte ranges (each row's last axis is contiguous), one copy each
                ix = rows[:, : 4 * k].view(_I32).reshape(-1)
                iy = rows[:, 4 * k : 8 * k].view(_I32).reshape(-1)
                vals = rows[:, 8 * k :].view(_F64).reshape(m, S, k).transpose(1, 0, 2).reshape(S, m * k)
                parts.setdefault(name, []).append(LayerColumns(layer, np.repeat(idx, k), ix, iy, vals))

    def _template(self, j: int, size: int, payload: bytes) -> _Template | None:
        """The template of layer `j` whose encoding is `size` bytes long, learnt from `payload` (a delta
        with that layer of that size): None when that payload's layer is not msgspec's own layout."""
        got = self._templates.get((j, size))
        if got is not None:
            return got
        try:
            d = self._msgspec.decode(payload)
        except (msgspec.MsgspecError, ValueError, TypeError):
            return None
        cells = _astuple(d.layers)[j]
        if cells is msgspec.UNSET:
            return None
        nb = len(_astuple(cells)[0])
        if nb % 4:
            return None
        tpl = _Template(LAYERS[_LAYER_NAMES[j]], nb // 4)
        if tpl.size != size:  # not the canonical encoding of that many cells: no template for this size
            return None
        if len(self._templates) >= self._MAX_TEMPLATES:
            self._templates.clear()
        self._templates[(j, size)] = tpl
        return tpl

    @staticmethod
    def _attach_views(
        results: list[Any], columns: dict[str, LayerColumns], names_of: dict[int, tuple]
    ) -> None:
        """Give each batch-path CellDelta its layers (slices of the columns, ordered by delta)."""
        per: dict[int, dict[str, dict[str, np.ndarray]]] = {i: {} for i in names_of}
        for name, c in columns.items():
            if not c.seg.size:
                continue
            order = np.argsort(c.seg, kind="stable")
            c = c.subset(order)
            starts = np.flatnonzero(np.r_[True, c.seg[1:] != c.seg[:-1]])
            ends = np.r_[starts[1:], c.seg.size]
            for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
                i = int(c.seg[s])
                if i in per:
                    cells: dict[str, np.ndarray] = {"ix": c.ix[s:e], "iy": c.iy[s:e]}
                    for r, stat in enumerate(c.layer.stats):
                        cells[stat] = c.vals[r, s:e]
                    per[i][name] = cells
        for i, names in names_of.items():
            layers = per[i]
            for name in names:  # layers present with zero cells
                if name not in layers:
                    layers[name] = _empty_columns_dict(LAYERS[name])
            object.__setattr__(results[i], "__dict__", {**results[i].__dict__, "layers": layers})


def _empty_columns_dict(layer: Layer) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {"ix": np.empty(0, _I32), "iy": np.empty(0, _I32)}
    for s in layer.stats:
        out[s] = np.empty(0)
    return out
