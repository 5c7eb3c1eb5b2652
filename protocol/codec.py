"""msgpack encoding of v1 messages, and decoding with full validation (every failure a ProtocolError)."""

from __future__ import annotations

import math
from typing import Any

import msgpack
import numpy as np

from protocol.consistency import check_consistent
from protocol.errors import DEFAULT_MAX_BYTES, ProtocolError
from protocol.keys import parse_ack_key, parse_delta_key, validate_id
from protocol.layers import Layer, get_layer, pack_pair
from protocol.messages import VERSION, Ack, CellDelta, MapRegion, ScoutStatus, Status, TileChanges

__all__ = ["DEFAULT_MAX_BYTES", "INDEX_LIMIT", "Message", "decode", "encode"]

INDEX_LIMIT = 2**30  # |ix|, |iy| must not exceed this
INT64_MAX = 2**63 - 1
Message = CellDelta | Ack | MapRegion | Status | TileChanges
TYPES = ("cell_delta", "ack", "map_region", "status", "tile_changes")

_I32 = np.dtype("<i4")
_F64 = np.dtype("<f8")


def _arr(a: np.ndarray, dtype: np.dtype) -> bytes:
    return np.ascontiguousarray(a, dtype=dtype).tobytes()


def encode(msg: Message) -> bytes:
    """Serialise a message to msgpack bytes (arrays as raw little-endian bytes)."""
    body: dict[str, Any]
    if isinstance(msg, CellDelta):
        layers = {}
        for name, cells in msg.layers.items():
            out = {"ix": _arr(cells["ix"], _I32), "iy": _arr(cells["iy"], _I32)}
            for stat, values in cells.items():
                if stat not in ("ix", "iy"):
                    out[stat] = _arr(values, _F64)
            layers[name] = out
        body = {
            "type": "cell_delta",
            "map": msg.map,
            "scout": msg.scout,
            "epoch": int(msg.epoch),
            "seq": int(msg.seq),
            "t": float(msg.t),
            "res": float(msg.res),
            "layers": layers,
        }
    elif isinstance(msg, Ack):
        body = {
            "type": "ack",
            "map": msg.map,
            "scout": msg.scout,
            "epoch": int(msg.epoch),
            "seq": int(msg.seq),
        }
        if msg.conflicts:
            body["conflicts"] = [int(s) for s in msg.conflicts]
    elif isinstance(msg, MapRegion):
        layers = {
            name: {s: _arr(np.asarray(a).reshape(-1), _F64) for s, a in stats.items()}
            for name, stats in msg.layers.items()
        }
        body = {
            "type": "map_region",
            "map": msg.map,
            "res": float(msg.res),
            "ix0": int(msg.ix0),
            "iy0": int(msg.iy0),
            "w": int(msg.w),
            "h": int(msg.h),
            "version": int(msg.version),
            "layers": layers,
        }
    elif isinstance(msg, Status):
        body = {
            "type": "status",
            "map": msg.map,
            "res": float(msg.res),
            "version": int(msg.version),
            "cells": int(msg.cells),
            "merged": int(msg.merged),
            "duplicates": int(msg.duplicates),
            "rejected": {k: int(v) for k, v in msg.rejected.items()},
            "scouts": {
                k: {"epoch": int(s.epoch), "last_seq": int(s.last_seq), "alive": bool(s.alive)}
                for k, s in msg.scouts.items()
            },
            "health": dict(msg.health),
            "t": float(msg.t),
        }
        if msg.shards > 1:
            body["shard"], body["shards"] = int(msg.shard or 0), int(msg.shards)
        if msg.bounds is not None:
            body["bounds"] = [int(v) for v in msg.bounds]
    elif isinstance(msg, TileChanges):
        body = {
            "type": "tile_changes",
            "map": msg.map,
            "shard": -1 if msg.shard is None else int(msg.shard),
            "version": int(msg.version),
            "res": float(msg.res),
            "tile": int(msg.tile),
            "tiles": _arr(np.asarray(msg.tiles).reshape(-1), _I32),
        }
    else:
        raise TypeError(
            f"cannot encode {type(msg).__name__}; messages: CellDelta, Ack, MapRegion, Status, TileChanges"
        )
    body["v"] = VERSION
    return msgpack.packb(body, use_bin_type=True)


# ---------------------------------------------------------------- decoding helpers


def _get(d: dict, name: str, where: str) -> Any:
    try:
        return d[name]
    except KeyError:
        raise ProtocolError("missing_field", f"{where} lacks field {name!r}") from None


def _int(d: dict, name: str, where: str, lo: int = 0, hi: int = INT64_MAX) -> int:
    v = _get(d, name, where)
    if isinstance(v, bool) or not isinstance(v, int):
        raise ProtocolError("wrong_type", f"{where}.{name} must be an int, got {type(v).__name__}")
    if not lo <= v <= hi:
        raise ProtocolError("bad_value", f"{where}.{name}={v} must be in [{lo}, {hi}]")
    return v


def _float(d: dict, name: str, where: str, positive: bool = False) -> float:
    v = _get(d, name, where)
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ProtocolError("wrong_type", f"{where}.{name} must be a number, got {type(v).__name__}")
    v = float(v)
    if not math.isfinite(v):
        raise ProtocolError("nonfinite", f"{where}.{name}={v} must be finite")
    if positive and v <= 0:
        raise ProtocolError("bad_value", f"{where}.{name}={v} must be > 0")
    return v


def _dict(v: Any, where: str) -> dict:
    if not isinstance(v, dict):
        raise ProtocolError("wrong_type", f"{where} must be a map, got {type(v).__name__}")
    for k in v:
        if not isinstance(k, str):
            raise ProtocolError("wrong_type", f"{where} keys must be strings, got {type(k).__name__}")
    return v


def _buf(v: Any, dtype: np.dtype, where: str) -> np.ndarray:
    if not isinstance(v, bytes | bytearray):
        raise ProtocolError(
            "wrong_type", f"{where} must be bytes ({dtype.name} little-endian), got {type(v).__name__}"
        )
    if len(v) % dtype.itemsize:
        raise ProtocolError(
            "bad_length", f"{where} has {len(v)} bytes, not a multiple of {dtype.itemsize} ({dtype.name})"
        )
    return np.frombuffer(v, dtype=dtype)


def _check_map(got: str, key_map: str | None, where: str) -> None:
    if key_map is not None and got != key_map:
        raise ProtocolError(
            "key_mismatch", f"{where}.map={got!r} but the key expression names map {key_map!r}"
        )


def _layer_buffers(name: str, raw: Any) -> tuple[Layer, Any, Any, list[Any], int]:
    """Structural checks of one layer (names, types, lengths) without touching the numbers.

    Returns (layer, ix bytes, iy bytes, stat bytes in the layer's order, N).
    """
    where = f"layers.{name}"
    layer = get_layer(name)
    raw = _dict(raw, where)
    allowed = ("ix", "iy", *layer.stats)
    for k in raw:
        if k not in allowed:
            raise ProtocolError("unknown_stat", f"{where} has no stat {k!r}; stats: {', '.join(allowed)}")
    bufs = []
    for k in allowed:
        v = _get(raw, k, where)
        dtype = _I32 if k in ("ix", "iy") else _F64
        if not isinstance(v, bytes | bytearray):
            raise ProtocolError(
                "wrong_type",
                f"{where}.{k} must be bytes ({dtype.name} little-endian), got {type(v).__name__}",
            )
        if len(v) % dtype.itemsize:
            raise ProtocolError(
                "bad_length",
                f"{where}.{k} has {len(v)} bytes, not a multiple of {dtype.itemsize} ({dtype.name})",
            )
        bufs.append(v)
    n = len(bufs[0]) // 4
    if len(bufs[1]) != 4 * n:
        raise ProtocolError("length_mismatch", f"{where}.iy has {len(bufs[1]) // 4} cells, ix has {n}")
    for stat, v in zip(layer.stats, bufs[2:], strict=True):
        if len(v) != 8 * n:
            raise ProtocolError(
                "length_mismatch", f"{where}.{stat} has {len(v) // 8} values, ix has {n} cells"
            )
    return layer, bufs[0], bufs[1], bufs[2:], n


def check_cells(where: str, layer: Any, ix: np.ndarray, iy: np.ndarray, block: np.ndarray) -> None:
    """Numeric checks of one layer's cells: finite stats, counts >= 0, index range, no duplicate cell."""
    n = ix.size
    if not n:
        return
    if not np.isfinite(block).all():
        bad = [s for s, a in zip(layer.stats, block, strict=True) if not np.isfinite(a).all()]
        raise ProtocolError("nonfinite", f"{where} stats {bad} hold NaN/inf; every statistic must be finite")
    for stat, a in zip(layer.stats, block, strict=True):
        if stat in layer.counts and a.min() < 0:
            raise ProtocolError("negative_count", f"{where}.{stat} has {a.min()} < 0; counts must be >= 0")
    check_consistent(where, layer, block)
    lo, hi = min(ix.min(), iy.min()), max(ix.max(), iy.max())
    if lo < -INDEX_LIMIT or hi > INDEX_LIMIT:
        raise ProtocolError(
            "index_range",
            f"{where} has index {lo if lo < -INDEX_LIMIT else hi}; indices must be within +-2**30",
        )
    keys = pack_pair(ix, iy)
    if n > 1 and len(np.unique(keys)) != n:
        raise ProtocolError("duplicate_cell", f"{where} lists a cell more than once; each cell at most once")


def _decode_layer(name: str, raw: Any) -> dict[str, np.ndarray]:
    layer, ixb, iyb, statb, n = _layer_buffers(name, raw)
    ix = np.frombuffer(ixb, dtype=_I32)
    iy = np.frombuffer(iyb, dtype=_I32)
    block = np.frombuffer(b"".join(statb), dtype=_F64).reshape(len(statb), n)  # (S, N)
    check_cells(f"layers.{name}", layer, ix, iy, block)
    out: dict[str, np.ndarray] = {"ix": ix, "iy": iy}
    for stat, a in zip(layer.stats, block, strict=True):
        out[stat] = a
    return out


def delta_header(
    d: dict, key: str | None, res: float | None
) -> tuple[str, str, int, int, float, float, dict]:
    """Checks of a cell_delta's scalar fields -> (map, scout, epoch, seq, t, res, raw layers)."""
    w = "cell_delta"
    map_id = validate_id(_get(d, "map", w), "map")
    scout = validate_id(_get(d, "scout", w), "scout")
    if key is not None:
        kmap, kscout = parse_delta_key(key)
        _check_map(map_id, kmap, w)
        if scout != kscout:
            raise ProtocolError(
                "key_mismatch", f"{w}.scout={scout!r} but the key expression names scout {kscout!r}"
            )
    epoch = _int(d, "epoch", w)
    seq = _int(d, "seq", w)
    t = _float(d, "t", w)
    r = _float(d, "res", w, positive=True)
    if res is not None and r != res:
        raise ProtocolError("wrong_res", f"{w}.res={r} but map {map_id!r} has res {res}")
    raw_layers = _dict(_get(d, "layers", w), f"{w}.layers")
    return map_id, scout, epoch, seq, t, r, raw_layers


def _decode_delta(d: dict, key: str | None, res: float | None) -> CellDelta:
    map_id, scout, epoch, seq, t, r, raw_layers = delta_header(d, key, res)
    layers = {name: _decode_layer(name, raw) for name, raw in raw_layers.items()}
    return CellDelta(map_id, scout, epoch, seq, t, r, layers)


def _decode_ack(d: dict, key: str | None) -> Ack:
    w = "ack"
    map_id = validate_id(_get(d, "map", w), "map")
    scout = validate_id(_get(d, "scout", w), "scout")
    if key is not None:
        kmap, kscout = parse_ack_key(key)
        _check_map(map_id, kmap, w)
        if scout != kscout:
            raise ProtocolError(
                "key_mismatch", f"{w}.scout={scout!r} but the key expression names scout {kscout!r}"
            )
    conflicts = d.get("conflicts", [])
    if not isinstance(conflicts, list) or not all(type(c) is int and c >= 0 for c in conflicts):
        raise ProtocolError("bad_value", f"{w}.conflicts must be a list of seqs (integers >= 0)")
    return Ack(map_id, scout, _int(d, "epoch", w), _int(d, "seq", w, lo=-1), tuple(conflicts))


def _decode_region(d: dict, res: float | None) -> MapRegion:
    w = "map_region"
    map_id = validate_id(_get(d, "map", w), "map")
    r = _float(d, "res", w, positive=True)
    if res is not None and r != res:
        raise ProtocolError("wrong_res", f"{w}.res={r} but expected res {res}")
    ix0 = _int(d, "ix0", w, -INDEX_LIMIT, INDEX_LIMIT)
    iy0 = _int(d, "iy0", w, -INDEX_LIMIT, INDEX_LIMIT)
    width, height = _int(d, "w", w, 0, 2 * INDEX_LIMIT), _int(d, "h", w, 0, 2 * INDEX_LIMIT)
    version = _int(d, "version", w)
    layers: dict[str, dict[str, np.ndarray]] = {}
    for name, stats in _dict(_get(d, "layers", w), f"{w}.layers").items():
        get_layer(name)
        layers[name] = {}
        for s, raw in _dict(stats, f"{w}.layers.{name}").items():
            a = _buf(raw, _F64, f"{w}.layers.{name}.{s}")
            if len(a) != width * height:
                raise ProtocolError(
                    "length_mismatch", f"{w}.layers.{name}.{s} has {len(a)} values, h*w = {height * width}"
                )
            layers[name][s] = a.reshape(height, width)
    return MapRegion(map_id, r, ix0, iy0, width, height, version, layers)


def _decode_status(d: dict) -> Status:
    w = "status"
    scouts = {}
    for name, s in _dict(_get(d, "scouts", w), f"{w}.scouts").items():
        s = _dict(s, f"{w}.scouts.{name}")
        alive = _get(s, "alive", f"{w}.scouts.{name}")
        if not isinstance(alive, bool):
            raise ProtocolError("wrong_type", f"{w}.scouts.{name}.alive must be a bool")
        scouts[name] = ScoutStatus(_int(s, "epoch", name), _int(s, "last_seq", name, lo=-1), alive)
    rejected = {}
    for reason, count in _dict(_get(d, "rejected", w), f"{w}.rejected").items():
        if isinstance(count, bool) or not isinstance(count, int):
            raise ProtocolError("wrong_type", f"{w}.rejected.{reason} must be an int")
        rejected[reason] = count
    health = _dict(d.get("health", {}), f"{w}.health")
    for k, v in health.items():
        if (
            not isinstance(k, str)
            or not (v is None or isinstance(v, str | float | int))
            or isinstance(v, bool)
        ):
            raise ProtocolError("wrong_type", f"{w}.health.{k} must be a string, a number or nil")
    t = d.get("t", 0.0)  # optional: senders before it was added do not set it
    if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t):
        raise ProtocolError("wrong_type", f"{w}.t must be a finite number of seconds")
    shards = _int(d, "shards", w, 1, 1024) if "shards" in d else 1
    shard = _int(d, "shard", w, 0, shards - 1) if shards > 1 else None
    bounds = _bounds(d["bounds"], f"{w}.bounds") if d.get("bounds") is not None else None  # optional
    return Status(
        validate_id(_get(d, "map", w), "map"),
        _float(d, "res", w, positive=True),
        _int(d, "version", w),
        _int(d, "cells", w),
        _int(d, "merged", w),
        _int(d, "duplicates", w),
        rejected,
        scouts,
        health,
        float(t),
        shard,
        shards,
        bounds,
    )


def _bounds(v: object, where: str) -> tuple[int, int, int, int]:
    """An inclusive cell box [ix0, iy0, ix1, iy1] within the index range, ix0 <= ix1 and iy0 <= iy1."""
    if (
        not isinstance(v, list | tuple)
        or len(v) != 4
        or any(isinstance(x, bool) or not isinstance(x, int) or abs(x) > INDEX_LIMIT for x in v)
    ):
        raise ProtocolError(
            "wrong_type", f"{where} must be 4 integer cell indices [ix0, iy0, ix1, iy1] within +-2**30"
        )
    ix0, iy0, ix1, iy1 = (int(x) for x in v)
    if ix1 < ix0 or iy1 < iy0:
        raise ProtocolError("bad_value", f"{where} {list(v)}: need ix0 <= ix1 and iy0 <= iy1")
    return ix0, iy0, ix1, iy1


def _decode_changes(d: dict) -> TileChanges:
    w = "tile_changes"
    shard = _int(d, "shard", w, -1, 1023)
    tiles = _buf(_get(d, "tiles", w), _I32, f"{w}.tiles")
    if len(tiles) % 2:
        raise ProtocolError("length_mismatch", f"{w}.tiles holds {len(tiles)} int32s; need (tx, ty) pairs")
    tile = _int(d, "tile", w, 1, 1 << 20)
    return TileChanges(
        validate_id(_get(d, "map", w), "map"),
        None if shard < 0 else shard,
        _int(d, "version", w),
        _float(d, "res", w, positive=True),
        tile,
        tiles.reshape(-1, 2),
    )


def decode(
    data: bytes | bytearray | memoryview,
    *,
    expected_type: str | None = None,
    key: str | None = None,
    res: float | None = None,
    max_bytes: int = DEFAULT_MAX_BYTES,
) -> Message:
    """Decode and fully validate one message; raise ProtocolError (with `.reason`) on any violation.

    expected_type: reject other types (`bad_type`); key: the key expression the message arrived on
    (its map / scout must agree); res: the map's resolution (`wrong_res` otherwise).
    """
    d = unpack_envelope(data, expected_type, max_bytes)
    typ = d["type"]
    if typ == "cell_delta":
        return _decode_delta(d, key, res)
    if typ == "ack":
        return _decode_ack(d, key)
    if typ == "map_region":
        return _decode_region(d, res)
    if typ == "tile_changes":
        return _decode_changes(d)
    return _decode_status(d)


def unpack_envelope(data: bytes | bytearray | memoryview, expected_type: str | None, max_bytes: int) -> dict:
    """msgpack -> dict with a supported `v` and a known (or the expected) `type`."""
    if len(data) > max_bytes:
        raise ProtocolError("oversize", f"payload has {len(data)} bytes; the limit is {max_bytes}")
    try:
        d = msgpack.unpackb(bytes(data), raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several unrelated types
        raise ProtocolError("decode", f"not a msgpack message ({type(exc).__name__}: {exc})") from None
    d = _dict(d, "message")
    v = _get(d, "v", "message")
    if v != VERSION or isinstance(v, bool):
        raise ProtocolError("bad_version", f"v={v!r}; supported schema versions: {VERSION}")
    typ = _get(d, "type", "message")
    if typ not in TYPES:
        raise ProtocolError("bad_type", f"type={typ!r}; types: {', '.join(TYPES)}")
    if expected_type is not None and typ != expected_type:
        raise ProtocolError("bad_type", f"type={typ!r} but {expected_type!r} is expected here")
    return d
