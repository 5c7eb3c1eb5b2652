"""Decode a batch of cell_delta payloads at once, with the numeric checks vectorised over the batch.

Same acceptance and the same `ProtocolError` (reason and message) per delta as `codec.decode`, but
the per-cell work (finite, counts >= 0, index range, duplicate cells) runs as one numpy pass per layer
over all deltas, and the cells of each layer come back concatenated, ready to merge. A delta the fast
pass flags is re-checked alone to produce its exact error.
"""

from __future__ import annotations

import math
import operator
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import chain
from types import MappingProxyType

import msgpack
import numpy as np

from protocol.codec import (
    DEFAULT_MAX_BYTES,
    INDEX_LIMIT,
    _decode_layer,
    delta_header,
    unpack_envelope,
)
from protocol.errors import ProtocolError
from protocol.keys import parse_delta_key, validate_id
from protocol.layers import LAYERS, Layer
from protocol.messages import VERSION, CellDelta

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


class _Spec:
    """What a structurally valid layer looks like: its keys in order, fetched with one C call."""

    def __init__(self, layer: Layer) -> None:
        self.layer = layer
        self.keys = ("ix", "iy", *layer.stats)
        self.get = operator.itemgetter(*self.keys)
        self.width = len(self.keys)


_SPECS = {name: _Spec(layer) for name, layer in LAYERS.items()}
_KEYS: dict[str, tuple[str, str] | None] = {}  # key expression -> (map, scout), None if invalid
_INT64_MAX = 2**63 - 1
_isfinite = math.isfinite


def _key_ids(key: str) -> tuple[str, str] | None:
    got = _KEYS.get(key, False)
    if got is False:
        try:
            kmap, kscout = parse_delta_key(key)
            got = (validate_id(kmap, "map"), validate_id(kscout, "scout"))
        except ProtocolError:
            got = None
        if len(_KEYS) > 65536:
            _KEYS.clear()
        _KEYS[key] = got
    return got  # type: ignore[return-value]


def _fast_header(d: object, key: str | None, res: float | None) -> tuple | None:
    """The header of a plainly valid cell_delta, or None (then the single-delta path decides)."""
    if type(d) is not dict:
        return None
    v = d.get("v")
    if type(v) is not int or v != VERSION or d.get("type") != "cell_delta":
        return None
    map_id, scout = d.get("map"), d.get("scout")
    if key is None:  # replayed log: ids checked alone
        if type(map_id) is not str or type(scout) is not str:
            return None
        if _key_ids(f"psr/{map_id}/delta/{scout}") != (map_id, scout):
            return None
    else:
        ids = _key_ids(key)
        if ids is None or ids[0] != map_id or ids[1] != scout:
            return None
    epoch, seq, t, r, layers = d.get("epoch"), d.get("seq"), d.get("t"), d.get("res"), d.get("layers")
    if type(epoch) is not int or type(seq) is not int or type(t) is not float or type(r) is not float:
        return None
    if not (0 <= epoch <= _INT64_MAX and 0 <= seq <= _INT64_MAX and _isfinite(t)):
        return None
    if res is not None and r != res:
        return None
    if not (_isfinite(r) and r > 0) or type(layers) is not dict:
        return None
    return (map_id, scout, epoch, seq, t, r, layers)


@dataclass
class _Acc:
    spec: _Spec
    seg: list[int] = field(default_factory=list)
    tups: list[tuple] = field(default_factory=list)  # per delta, the layer's buffers in `spec.keys` order


_HEADER_KEYS = {"type", "map", "scout", "epoch", "seq", "t", "res"}
_LAYERS_KEY = b"\xa6layers"
_TAIL = b"\xa1v\x01"  # "v": 1, the last pair `encode` writes


def _map_hdr(n: int) -> bytes:
    return bytes([0x80 | n]) if n < 16 else b"\xde" + n.to_bytes(2, "big")


def _bin_hdr(n: int) -> bytes:
    if n < 256:
        return b"\xc4" + n.to_bytes(1, "big")
    if n < 65536:
        return b"\xc5" + n.to_bytes(2, "big")
    return b"\xc6" + n.to_bytes(4, "big")


class _Template:
    """The exact bytes of a `layers` value (layer names, stat keys, bin lengths, in order) with the
    array contents left out. A payload `0x89 + header + "layers" + L + "v": 1` whose L has these bytes
    outside the arrays, and whose header is the canonical encoding of the seven header fields, is
    exactly what msgpack would decode to a structurally valid delta with these layers: its arrays are
    cut out of L by numpy for the whole batch, with no per-delta msgpack decode."""

    def __init__(self, raw_layers: dict, section: bytes) -> None:
        out = bytearray(_map_hdr(len(raw_layers)))
        self.spans: dict[str, dict[str, tuple[int, int]]] = {}
        for name, cells in raw_layers.items():
            out += msgpack.packb(name) + _map_hdr(len(cells))
            spans = self.spans[name] = {}
            for k, v in cells.items():
                out += msgpack.packb(k) + _bin_hdr(len(v))
                spans[k] = (len(out), len(v))
                out += v
        if bytes(out) != section:
            raise ValueError("not the canonical encoding")
        self.size = len(section)
        frame = np.ones(self.size, dtype=bool)
        for spans in self.spans.values():
            for a, n in spans.values():
                frame[a : a + n] = False
        self.frame_idx = np.flatnonzero(frame)
        self.frame_vals = np.frombuffer(section, dtype=np.uint8)[self.frame_idx].copy()
        self.names = dict.fromkeys(raw_layers)
        self.ncells = {name: spans["ix"][1] // 4 for name, spans in self.spans.items()}

    def fill(
        self, arr: np.ndarray, idx: np.ndarray, out: dict[str, LayerColumns], at: dict[str, int]
    ) -> None:
        """Copy the rows' cells into preallocated columns from `at[name]` on (advanced): one strided
        byte copy per array, straight from the payload bytes into its place."""
        m = arr.shape[0]
        for name, spans in self.spans.items():
            k = self.ncells[name]
            o = at[name]
            e = at[name] = o + m * k
            if not k:
                continue
            c = out[name]
            c.seg[o:e].reshape(m, k)[:] = idx[:, None]
            # (unaligned) views of the payload bytes as their dtype: copied element- not byte-wise
            a, n = spans["ix"]
            c.ix[o:e].reshape(m, k)[:] = arr[:, a : a + n].view(_I32)
            a, n = spans["iy"]
            c.iy[o:e].reshape(m, k)[:] = arr[:, a : a + n].view(_I32)
            for r, stat in enumerate(c.layer.stats):
                a, n = spans[stat]
                c.vals[r, o:e].reshape(m, k)[:] = arr[:, a : a + n].view(_F64)

    def columns(self, arr: np.ndarray, idx: np.ndarray) -> dict[str, LayerColumns]:
        out = {}
        for name, spans in self.spans.items():
            layer = LAYERS[name]
            a, n = spans["ix"]
            cells = n // 4
            ix = np.ascontiguousarray(arr[:, a : a + n]).view(_I32).reshape(-1)
            a, n = spans["iy"]
            iy = np.ascontiguousarray(arr[:, a : a + n]).view(_I32).reshape(-1)
            vals = np.empty((len(layer.stats), ix.size))
            for r, stat in enumerate(layer.stats):
                a, n = spans[stat]
                vals[r] = np.ascontiguousarray(arr[:, a : a + n]).view(_F64).reshape(-1)
            out[name] = LayerColumns(layer, np.repeat(idx, cells), ix, iy, vals)
        return out


_TEMPLATES: dict[int, _Template] = {}  # by length of the layers section
_MAX_TEMPLATES = 256


def _split(payload: bytes) -> int:
    """Offset of the `layers` key if the payload has the shape `encode` writes, else -1."""
    if payload[:1] != b"\x89" or payload[-3:] != _TAIL:
        return -1
    return payload.find(_LAYERS_KEY)


def _template_header(payload: bytes, j: int, key: str | None, res: float | None) -> tuple | None:
    head_bytes = b"\x87" + payload[1:j]
    try:
        h = msgpack.unpackb(head_bytes, raw=False, strict_map_key=False)
    except Exception:
        return None
    if type(h) is not dict or h.keys() != _HEADER_KEYS:
        return None
    if msgpack.packb(h, use_bin_type=True) != head_bytes:  # canonical: the bytes are these 7 pairs
        return None
    h["v"] = VERSION
    h["layers"] = {}
    return _fast_header(h, key, res)


class _Known:
    """A scout's header bytes as `encode` writes them, up to its seq (map, scout, epoch fixed), and
    from `t` to the layers key (res fixed): a payload that starts with these bytes has the header
    they encode, whatever seq and t it carries (both read here, with msgpack's rules)."""

    __slots__ = ("epoch", "map", "prefix", "res", "res_bytes", "scout")

    def __init__(self, head: tuple) -> None:
        self.map, self.scout, self.epoch = head[0], head[1], head[2]
        self.res = head[5]
        pairs = (("type", "cell_delta"), ("map", self.map), ("scout", self.scout), ("epoch", self.epoch))
        self.prefix = b"\x89" + b"".join(_pack(k) + _pack(v) for k, v in pairs) + _pack("seq")
        self.res_bytes = _pack("res") + _pack(self.res) + _LAYERS_KEY


_pack = msgpack.packb
_HEADS: dict[tuple[str | None, float | None], _Known] = {}  # by (key expression, map res)
_D = struct.Struct(">d")
_INT = {0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8}  # msgpack unsigned ints: type byte -> width


def _known_header(payload: bytes, known: _Known) -> tuple | None:
    """(map, scout, epoch, seq, t, res, offset of the layers key) or None if the bytes differ."""
    if not payload.startswith(known.prefix):
        return None
    o = len(known.prefix)
    if len(payload) < o + 12:  # a truncated message: the exact path names what is wrong
        return None
    b = payload[o]
    if b < 0x80:
        seq, o = b, o + 1
    else:
        w = _INT.get(b)
        if w is None:
            return None
        seq, o = int.from_bytes(payload[o + 1 : o + 1 + w], "big"), o + 1 + w
        if seq > _INT64_MAX:
            return None
    if payload[o : o + 3] != b"\xa1t\xcb" or len(payload) < o + 11:
        return None
    (t,) = _D.unpack_from(payload, o + 3)
    o += 11
    if not _isfinite(t) or not payload.startswith(known.res_bytes, o) or payload[-3:] != _TAIL:
        return None
    return (known.map, known.scout, known.epoch, seq, t, known.res, o + len(known.res_bytes) - 7)


_T_MARK = np.frombuffer(b"\xa1t\xcb", dtype=np.uint8)
_TAIL_ARR = np.frombuffer(_TAIL, dtype=np.uint8)
_SEQ_DT: dict[int, np.dtype] = {
    1: np.dtype(">u1"),
    2: np.dtype(">u2"),
    4: np.dtype(">u4"),
    8: np.dtype(">u8"),
}


def _known_rows(
    arr: np.ndarray, known: _Known
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, _Template, np.ndarray]]:
    """`_known_header` + the template check for rows of equal length at once (numpy over the batch).

    arr: (n, L) uint8, one payload per row, all on one key expression. Returns, per layout found,
    (row numbers, seq int64, t float64, template, the rows' layers sections (m, template size)).
    Rows in none of them are left to the per-delta path (which decides them exactly as before).
    """
    out: list[tuple[np.ndarray, np.ndarray, np.ndarray, _Template, np.ndarray]] = []
    n, L = arr.shape
    pre = np.frombuffer(known.prefix, dtype=np.uint8)
    p = pre.size
    if L < p + 1 + 11 + len(known.res_bytes) + 3:
        return out
    ok = (arr[:, :p] == pre).all(axis=1) & (arr[:, L - 3 :] == _TAIL_ARR).all(axis=1)
    seq_type = arr[:, p]
    kind = np.where(seq_type < 0x80, 0, seq_type)  # positive fixint: the seq is the type byte
    for b in np.unique(kind[ok]).tolist():
        rows = np.flatnonzero(ok & (kind == b)) if n > 1 else np.zeros(1, dtype=np.intp)
        if b < 0x80:
            w = 0
        elif b in _INT:
            w = _INT[b]
        else:
            continue
        o = p + 1 + w  # the "t" key
        sec0 = o + 11 + len(known.res_bytes)  # the layers section
        tpl = _TEMPLATES.get(L - sec0 - 3)
        if tpl is None:
            continue
        sub = arr if rows.size == n else arr[rows]
        if w:
            seq = np.ascontiguousarray(sub[:, p + 1 : o]).view(_SEQ_DT[w]).reshape(-1)
            good = seq <= _INT64_MAX if w == 8 else np.ones(rows.size, dtype=bool)
            seq = seq.astype(np.int64)
        else:
            seq = sub[:, p].astype(np.int64)
            good = np.ones(rows.size, dtype=bool)
        t = np.ascontiguousarray(sub[:, o + 3 : o + 11]).view(">f8").reshape(-1).astype(np.float64)
        rb = np.frombuffer(known.res_bytes, dtype=np.uint8)
        sec = sub[:, sec0 : L - 3]
        good &= (sub[:, o : o + 3] == _T_MARK).all(axis=1) & np.isfinite(t)
        good &= (sub[:, o + 11 : sec0] == rb).all(axis=1)
        good &= (sec[:, tpl.frame_idx] == tpl.frame_vals).all(axis=1)
        if not good.all():
            rows, seq, t, sec = rows[good], seq[good], t[good], sec[good]
        if rows.size:
            out.append((rows, seq, t, tpl, sec))
    return out


def _learn_header(key: str | None, res: float | None, head: tuple, payload: bytes) -> None:
    known = _Known(head)
    if _known_header(payload, known) is None:
        return
    if len(_HEADS) >= 65536:
        _HEADS.clear()
    _HEADS[(key, res)] = known


def _learn_templates(samples: Sequence[tuple[str | None, bytes]], raws: dict[int, dict]) -> None:
    for i, raw in raws.items():
        if len(_TEMPLATES) >= _MAX_TEMPLATES:
            return
        payload = samples[i][1]
        j = _split(payload) if type(payload) is bytes else -1
        if j <= 0:
            continue
        size = len(payload) - j - len(_LAYERS_KEY) - len(_TAIL)
        if size in _TEMPLATES:
            continue
        try:
            _TEMPLATES[size] = _Template(raw, payload[j + len(_LAYERS_KEY) : len(payload) - len(_TAIL)])
        except (ValueError, TypeError, KeyError):
            continue


def _flag_values(layer: Layer, vals: np.ndarray, seg: np.ndarray) -> set[int]:
    """Segments (delta indices) with a NaN/inf statistic or a negative count in this layer."""
    counts = [r for r, s in enumerate(layer.stats) if s in layer.counts]
    # a sum is finite only if every term is (NaN and inf propagate; an overflow only sends the
    # batch to the exact check below)
    if np.isfinite(np.add.reduce(vals, axis=None)) and all(vals[r].min() >= 0 for r in counts):
        return set()
    bad = ~np.isfinite(vals).all(axis=0)
    for r in counts:
        bad |= vals[r] < 0
    return set(np.unique(seg[bad]).tolist()) if bad.any() else set()


def _flag_index(ix: np.ndarray, iy: np.ndarray, seg: np.ndarray) -> set[int]:
    """Segments with an index beyond +-2**30 or a cell listed twice (within one delta and layer)."""
    bad = (ix < -INDEX_LIMIT) | (ix > INDEX_LIMIT) | (iy < -INDEX_LIMIT) | (iy > INDEX_LIMIT)
    flagged = set(np.unique(seg[bad]).tolist()) if bad.any() else set()
    if ix.size > 1:
        # duplicate cell within one delta: sort one int64 key (delta, ix, iy) when it fits
        x0, y0 = int(ix.min()), int(iy.min())
        w, h = int(ix.max()) - x0 + 1, int(iy.max()) - y0 + 1
        if not flagged and (int(seg.max()) + 1) * w * h < 2**62:
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


class _IndexFlags:
    """`_flag_index` with the last answer kept: the layers of a batch usually list the same cells of
    the same deltas, and equal (seg, ix, iy) have equal flags."""

    def __init__(self) -> None:
        self.last: tuple[np.ndarray, np.ndarray, np.ndarray, set[int]] | None = None

    def __call__(self, ix: np.ndarray, iy: np.ndarray, seg: np.ndarray) -> set[int]:
        last = self.last
        if (
            last is not None
            and last[0].shape == seg.shape
            and last[1].shape == ix.shape
            and last[2].shape == iy.shape
            and (last[0] == seg).all()
            and (last[1] == ix).all()
            and (last[2] == iy).all()
        ):
            return last[3]
        flagged = _flag_index(ix, iy, seg)
        self.last = (seg, ix, iy, flagged)
        return flagged


def _flag_cells(
    layer: Layer, ix: np.ndarray, iy: np.ndarray, vals: np.ndarray, seg: np.ndarray
) -> np.ndarray:
    """Segments (delta indices) with any bad cell in this layer."""
    flagged = _flag_values(layer, vals, seg) | _flag_index(ix, iy, seg)
    return np.array(sorted(flagged), dtype=np.int64)


def _structural_bad(acc: _Acc) -> set[int]:
    """Deltas whose buffers in this layer are not all bytes of consistent lengths."""
    width = acc.spec.width
    flat = list(chain.from_iterable(acc.tups))
    if set(map(type, flat)) == {bytes}:
        lens = np.fromiter(map(len, flat), dtype=np.int64, count=len(flat)).reshape(-1, width)
        n4 = lens[:, 0]
        ok = (n4 % 4 == 0) & (lens[:, 1] == n4) & (lens[:, 2:] == 2 * n4[:, None]).all(axis=1)
        return {acc.seg[j] for j in np.flatnonzero(~ok).tolist()}
    bad = set()
    for i, tup in zip(acc.seg, acc.tups, strict=True):
        if any(type(b) is not bytes for b in tup):
            bad.add(i)
            continue
        nb = len(tup[0])
        if nb % 4 or len(tup[1]) != nb or any(len(b) != 2 * nb for b in tup[2:]):
            bad.add(i)
    return bad


def _columns(acc: _Acc, drop: set[int]) -> LayerColumns:
    seg, tups = acc.seg, acc.tups
    if drop and not drop.isdisjoint(seg):
        keep = [j for j, i in enumerate(seg) if i not in drop]
        seg, tups = [seg[j] for j in keep], [tups[j] for j in keep]
    layer = acc.spec.layer
    if not tups:
        return LayerColumns(
            layer,
            np.empty(0, np.int64),
            np.empty(0, _I32),
            np.empty(0, _I32),
            np.empty((len(layer.stats), 0)),
        )
    cols = list(zip(*tups, strict=True))
    ix = np.frombuffer(b"".join(cols[0]), dtype=_I32)
    iy = np.frombuffer(b"".join(cols[1]), dtype=_I32)
    vals = np.frombuffer(b"".join(chain.from_iterable(cols[2:])), dtype=_F64).reshape(len(layer.stats), -1)
    counts = np.fromiter(map(len, cols[0]), dtype=np.int64, count=len(tups)) >> 2
    return LayerColumns(layer, np.repeat(np.array(seg, dtype=np.int64), counts), ix, iy, vals)


def _concat(a: LayerColumns, b: LayerColumns) -> LayerColumns:
    return LayerColumns(
        a.layer,
        np.concatenate([a.seg, b.seg]),
        np.concatenate([a.ix, b.ix]),
        np.concatenate([a.iy, b.iy]),
        np.concatenate([a.vals, b.vals], axis=1),
    )


def _concat_all(parts: list[LayerColumns]) -> LayerColumns:
    return LayerColumns(
        parts[0].layer,
        np.concatenate([p.seg for p in parts]),
        np.concatenate([p.ix for p in parts]),
        np.concatenate([p.iy for p in parts]),
        np.concatenate([p.vals for p in parts], axis=1),
    )


def _single(key: str | None, payload: bytes, res: float | None, max_bytes: int) -> CellDelta:
    """The single-delta path (`codec.decode`), the reference for acceptance and errors."""
    d = unpack_envelope(payload, "cell_delta", max_bytes)
    map_id, scout, epoch, seq, t, r, raw_layers = delta_header(d, key, res)
    layers = {name: _decode_layer(name, raw) for name, raw in raw_layers.items()}
    return CellDelta(map_id, scout, epoch, seq, t, r, layers)


def _delta(head: tuple, layers: dict) -> CellDelta:
    """A CellDelta from checked fields, without the frozen dataclass' per-field __setattr__."""
    obj = _new(CellDelta)
    _setattr(
        obj,
        "__dict__",
        {
            "map": head[0],
            "scout": head[1],
            "epoch": head[2],
            "seq": head[3],
            "t": head[4],
            "res": head[5],
            "layers": layers,
        },
    )
    return obj


def _new_delta(
    map_id: str, scout: str, epoch: int, seq: int, t: float, res: float, layers: Mapping
) -> CellDelta:
    obj = _new(CellDelta)
    _setattr(
        obj,
        "__dict__",
        {"map": map_id, "scout": scout, "epoch": epoch, "seq": seq, "t": t, "res": res, "layers": layers},
    )
    return obj


_new = object.__new__
_NO_LAYERS: Mapping[str, dict[str, np.ndarray]] = MappingProxyType(
    {}
)  # the layers of every header-only CellDelta (views=False)
_setattr = object.__setattr__


def _vector_rows(
    samples: Sequence[tuple[str | None, bytes]],
    idx_list: list[int],
    kn: _Known,
    max_bytes: int,
    heads: dict[int, tuple | CellDelta],
    names_of: dict[int, dict],
    tparts: list[tuple[_Template, np.ndarray, np.ndarray]],
    views: bool,
) -> None:
    """`_known_rows` over the deltas `idx_list` (one key expression), grouped by length."""
    by_len: dict[int, list[int]] = {}
    lens = list(map(len, [samples[i][1] for i in idx_list]))
    if lens.count(lens[0]) == len(lens):
        by_len[lens[0]] = idx_list
    else:
        for i, n in zip(idx_list, lens, strict=True):
            lst = by_len.get(n)
            if lst is None:
                by_len[n] = [i]
            else:
                lst.append(i)
    for size, group in by_len.items():
        if size > max_bytes:
            continue
        arr = np.frombuffer(b"".join([samples[i][1] for i in group]), dtype=np.uint8)
        rows_of = np.array(group, dtype=np.int64)
        for rows, seqs, ts, tpl, sec in _known_rows(arr.reshape(len(group), size), kn):
            idx = rows_of[rows]
            names = tpl.names
            m, sc, ep, r_ = kn.map, kn.scout, kn.epoch, kn.res
            # the CellDeltas themselves (layers filled in later if views are wanted; without views
            # one shared empty read-only mapping): few objects per delta (allocations drive the GC)
            new, put = _new, _setattr
            if views:
                for i, sq, tt in zip(idx.tolist(), seqs.tolist(), ts.tolist(), strict=True):
                    heads[i] = _new_delta(m, sc, ep, sq, tt, r_, {})
                    names_of[i] = names
            else:  # (_new_delta inlined: this loop is most of the per-delta work left)
                for i, sq, tt in zip(idx.tolist(), seqs.tolist(), ts.tolist(), strict=True):
                    heads[i] = obj = new(CellDelta)
                    put(
                        obj,
                        "__dict__",
                        {
                            "map": m,
                            "scout": sc,
                            "epoch": ep,
                            "seq": sq,
                            "t": tt,
                            "res": r_,
                            "layers": _NO_LAYERS,
                        },
                    )
            tparts.append((tpl, idx, sec))


def _learn_from(
    key: str | None, res: float | None, payload: bytes, max_bytes: int, old: _Known | None
) -> _Known | None:
    """The header bytes of `payload` as a `_Known`, learnt for `key`, if its header is valid, in
    `encode`'s canonical form and of a known template; None if not (or if nothing new was learnt)."""
    if len(payload) > max_bytes:
        return None
    j = _split(payload)
    if j <= 0 or len(payload) - j - 10 not in _TEMPLATES:
        return None
    head = _template_header(payload, j, key, res)
    if head is None:
        return None
    known = _Known(head)
    if _known_header(payload, known) is None:
        return None
    if old is not None and (old.prefix, old.res_bytes) == (known.prefix, known.res_bytes):
        return None
    if len(_HEADS) >= 65536:
        _HEADS.clear()
    _HEADS[(key, res)] = known
    return known


def decode_delta_batch(
    samples: Sequence[tuple[str | None, bytes]],
    *,
    res: float | None = None,
    max_bytes: int = DEFAULT_MAX_BYTES,
    views: bool = True,
) -> DeltaBatch:
    """Decode `(key, payload)` samples as cell_deltas; every failure is a ProtocolError in `results`.

    Deltas of a learnt layout (a scout's header bytes and a template of its layers) are checked with
    numpy over all deltas of one key expression and length at once (`_known_rows`), their arrays
    copied once from the payload bytes into the batch's columns. Others take a fast path of a few C
    calls each (msgpack -> bytes, one itemgetter per layer); their buffers are joined per layer. The
    numbers of every layer are checked with one numpy pass per layer. Any delta the fast paths do not
    vouch for goes through the single-delta path (`codec.decode`), which decides acceptance and gives
    the exact error. views=False skips building per-delta layer arrays: the CellDeltas then carry
    headers only (`layers` empty, an immutable mapping on the vectorised path) and the cells are in
    `columns` (what the server merges).
    """
    n = len(samples)
    results: list[CellDelta | ProtocolError | None] = [None] * n
    heads: dict[int, tuple | CellDelta] = {}  # header tuple, or the CellDelta (vectorised path)
    names_of: dict[int, dict] = {}  # vectorised path: the delta's layer names
    accs: dict[str, _Acc] = {}
    slow: set[int] = set()
    unpackb = msgpack.unpackb
    specs = _SPECS
    templates = _TEMPLATES
    heads_known = _HEADS
    learn: list[int] = []  # deltas whose header went through msgpack: learn their scout's prefix
    tgroups: dict[int, tuple[list[int], list[bytes]]] = {}
    raws: dict[int, dict] = {}  # generic-path deltas: raw layers (to learn templates from)
    tparts: list[tuple[_Template, np.ndarray, np.ndarray]] = []  # (template, delta indices, sections)
    if templates:
        # deltas of a known payload layout, by key expression: every check of `_known_header` and of
        # the template frame is one numpy pass over the deltas of one length
        by_key: dict[str | None, list[int]] = {}
        for i, (key, payload) in enumerate(samples):
            if type(payload) is bytes:
                lst = by_key.get(key)
                if lst is None:
                    by_key[key] = [i]
                else:
                    lst.append(i)
        for key, idx_list in by_key.items():
            kn = heads_known.get((key, res))
            first = samples[idx_list[0]][1]
            if kn is None or not first.startswith(kn.prefix):  # a new scout or epoch: learn it first
                kn = _learn_from(key, res, first, max_bytes, kn) or kn
            pending = idx_list
            for attempt in range(2):
                if kn is not None:
                    _vector_rows(samples, pending, kn, max_bytes, heads, names_of, tparts, views)
                    pending = [i for i in pending if i not in heads]
                if not pending or attempt:
                    break
                # a new scout or epoch: learn its header bytes from its first delta, then the rest
                new_kn = _learn_from(key, res, samples[pending[0]][1], max_bytes, kn)
                if new_kn is None:
                    break
                kn = new_kn
    for i, (key, payload) in enumerate(samples):
        if i in heads:  # (only the vectorised path's so far)
            continue
        if len(payload) > max_bytes:
            slow.add(i)
            continue
        if templates and type(payload) is bytes:
            known = heads_known.get((key, res))
            head = _known_header(payload, known) if known is not None else None
            if head is not None:
                j = head[6]
            else:
                j = _split(payload)
            size = len(payload) - j - 10
            if j > 0 and size in templates:
                if head is None:
                    head = _template_header(payload, j, key, res)
                    if head is not None:
                        learn.append(i)
                if head is not None:
                    heads[i] = (*head[:6], templates[size].names)
                    group = tgroups.get(size)
                    if group is None:
                        group = tgroups[size] = ([], [])
                    group[0].append(i)
                    group[1].append(payload[j + 7 : len(payload) - 3])
                    continue
        try:
            d = unpackb(payload, raw=False, strict_map_key=False)
        except Exception:  # msgpack raises several unrelated types; the single path names it
            slow.add(i)
            continue
        head = _fast_header(d, key, res)
        if head is None:
            slow.add(i)
            continue
        got = []
        for name, raw in head[6].items():
            spec = specs.get(name)
            if spec is None or type(raw) is not dict or len(raw) != spec.width:
                break
            try:
                got.append((name, spec, spec.get(raw)))
            except KeyError:
                break
        else:
            heads[i] = head
            raws[i] = head[6]
            for name, spec, tup in got:
                acc = accs.get(name)
                if acc is None:
                    acc = accs[name] = _Acc(spec)
                acc.seg.append(i)
                acc.tups.append(tup)
            continue
        slow.add(i)
    # structure (types, lengths) of every layer, then numbers, one pass per layer over the batch
    bad: set[int] = set()
    for acc in accs.values():
        bad |= _structural_bad(acc)
    for size, (idx_list, sections) in tgroups.items():
        tpl = templates[size]
        idx = np.array(idx_list, dtype=np.int64)
        arr = np.frombuffer(b"".join(sections), dtype=np.uint8).reshape(len(sections), tpl.size)
        ok = (arr[:, tpl.frame_idx] == tpl.frame_vals).all(axis=1)
        if not ok.all():  # framing differs: the generic decision (single path) for those
            for i in idx[~ok].tolist():
                slow.add(i)
                heads.pop(i, None)
            idx, arr = idx[ok], arr[ok]
        if idx.size:
            tparts.append((tpl, idx, arr))
    # template deltas (already checked, framing included): each layer's cells copied once into place
    tcols: dict[str, list[LayerColumns]] = {}
    if tparts:
        total: dict[str, int] = {}
        for tpl, idx, _ in tparts:
            for name, k in tpl.ncells.items():
                total[name] = total.get(name, 0) + k * idx.size
        tout = {
            name: LayerColumns(
                LAYERS[name],
                np.empty(n, np.int64),
                np.empty(n, _I32),
                np.empty(n, _I32),
                np.empty((len(LAYERS[name].stats), n), _F64),
            )
            for name, n in total.items()
        }
        at = dict.fromkeys(total, 0)
        for tpl, idx, arr in tparts:
            tpl.fill(arr, idx, tout, at)
        tcols = {name: [c] for name, c in tout.items()}
    columns: dict[str, LayerColumns] = {}
    index_flags = _IndexFlags()
    for name in dict.fromkeys([*accs, *tcols]):
        parts = [_columns(accs[name], bad)] if name in accs else []
        parts += tcols.get(name, [])
        c = parts[0] if len(parts) == 1 else _concat_all(parts)
        if c.seg.size:
            bad |= _flag_values(c.layer, c.vals, c.seg)
            bad |= index_flags(c.ix, c.iy, c.seg)
        columns[name] = c
    if bad:
        for name, c in list(columns.items()):
            if c.seg.size and not bad.isdisjoint(np.unique(c.seg).tolist()):
                keep = ~np.isin(c.seg, np.array(sorted(bad), dtype=np.int64))
                columns[name] = LayerColumns(c.layer, c.seg[keep], c.ix[keep], c.iy[keep], c.vals[:, keep])
        for i in bad:
            heads.pop(i, None)
    learnt: set[str | None] = set()
    for i in learn:  # the first accepted delta of each key expression in the batch
        key = samples[i][0]
        head_i = heads.get(i)
        if type(head_i) is tuple and key not in learnt:
            learnt.add(key)
            _learn_header(key, res, head_i, samples[i][1])
    if len(_TEMPLATES) < _MAX_TEMPLATES and raws:
        _learn_templates(samples, {i: r for i, r in raws.items() if i not in bad and i in heads})
    # the single-delta path decides every delta the fast path did not vouch for
    extra: dict[int, CellDelta] = {}
    for i in sorted(slow | bad):
        key, payload = samples[i]
        try:
            extra[i] = _single(key, bytes(payload), res, max_bytes)
        except ProtocolError as exc:
            results[i] = exc
    for i, delta in extra.items():
        heads[i] = (delta.map, delta.scout, delta.epoch, delta.seq, delta.t, delta.res, delta.layers)
        for name, lc in delta.layers.items():
            layer = LAYERS[name]
            add = LayerColumns(
                layer,
                np.full(lc["ix"].size, i, dtype=np.int64),
                lc["ix"],
                lc["iy"],
                np.stack([lc[s] for s in layer.stats]) if lc["ix"].size else np.empty((len(layer.stats), 0)),
            )
            columns[name] = _concat(columns[name], add) if name in columns else add
    # CellDelta views for callers that want per-delta objects
    per: dict[int, dict[str, dict[str, np.ndarray]]] = (
        {i: h.layers if type(h) is CellDelta else {} for i, h in heads.items()} if views else {}
    )
    for name, c in columns.items() if views else ():
        if c.seg.size:
            order = np.argsort(c.seg, kind="stable")
            if (order != np.arange(order.size)).any():
                c = LayerColumns(c.layer, c.seg[order], c.ix[order], c.iy[order], c.vals[:, order])
            starts = np.flatnonzero(np.r_[True, c.seg[1:] != c.seg[:-1]])
            ends = np.r_[starts[1:], c.seg.size]
            for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
                cells: dict[str, np.ndarray] = {"ix": c.ix[s:e], "iy": c.iy[s:e]}
                for r, stat in enumerate(c.layer.stats):
                    cells[stat] = c.vals[r, s:e]
                per[int(c.seg[s])][name] = cells
        for i in per:  # layers present with zero cells
            hv = heads[i]
            names = names_of[i] if isinstance(hv, CellDelta) else hv[6]
            if name in names and name not in per[i]:
                per[i][name] = _empty_cells(c.layer)
    for i, hv in heads.items():
        results[i] = hv if type(hv) is CellDelta else _delta(hv, per[i] if views else {})  # type: ignore[arg-type]
    return DeltaBatch(results, columns)  # type: ignore[arg-type]


def _empty_cells(layer: Layer) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {"ix": np.empty(0, dtype=np.int32), "iy": np.empty(0, dtype=np.int32)}
    for s in layer.stats:
        out[s] = np.empty(0)
    return out
