"""Builders of valid and deliberately broken wire messages, for the tests of every package."""

from __future__ import annotations

import copy
from typing import Any

import msgpack
import numpy as np

from protocol.errors import REASONS
from protocol.keys import delta_key
from protocol.layers import LAYERS
from protocol.messages import CellDelta

MAP, SCOUT, RES = "m1", "s1", 0.4


def layer_cells(name: str, ix, iy, rng: np.random.Generator | None = None, scale: float = 1.0) -> dict:
    """Valid cells of `layer` with integer-valued (exactly summable) statistics that a real sample set has:
    moment sums (n, sum, sumsq, sx … syz), min and max are those of 1..19 integer samples (x, y, z) per cell
    (protocol.consistency accepts them), the height layer's the same samples weighted by one σ of 0.5 or 1 m
    per cell; other statistics are random integers (counts >= 0)."""
    rng = rng or np.random.default_rng(0)
    ix = np.asarray(ix, dtype=np.int32)
    iy = np.asarray(iy, dtype=np.int32)
    out: dict[str, np.ndarray] = {"ix": ix, "iy": iy}
    k = rng.integers(1, 20, ix.size)
    live = np.arange(19)[None, :] < k[:, None]  # (cells, 19): which samples exist
    x, y = (np.where(live, rng.integers(-3, 4, live.shape), 0).astype(np.float64) for _ in range(2))
    z = np.where(live, rng.integers(-50, 50, live.shape), 0).astype(np.float64)
    moments = {
        "n": k.astype(np.float64), "sum": z.sum(1), "sumsq": (z * z).sum(1), "sx": x.sum(1), "sy": y.sum(1),
        "sxx": (x * x).sum(1), "syy": (y * y).sum(1), "sxy": (x * y).sum(1), "sxz": (x * z).sum(1),
        "syz": (y * z).sum(1), "min": np.where(live, z, np.inf).min(1), "max": np.where(live, z, -np.inf).max(1),
    }  # fmt: skip
    # the height layer: each cell's footholds with one σ of 0.5 or 1 m (weights 4 or 1: exact sums)
    sig = rng.choice([0.5, 1.0], ix.size)
    w = 1.0 / sig**2
    weighted = {"w": w * moments["n"], "wz": w * moments["sum"], "wx": w * moments["sx"], "wy": w * moments["sy"],
                "wxx": w * moments["sxx"], "wyy": w * moments["syy"], "wxy": w * moments["sxy"],
                "wxz": w * moments["sxz"], "wyz": w * moments["syz"], "var": sig**2 * moments["n"]}  # fmt: skip
    for s in LAYERS[name].stats:
        if name == "height":
            out[s] = (
                sig.copy() if s == "min_sigma" else moments["n"] * scale if s == "n" else weighted[s] * scale
            )
        elif s in moments and "n" in LAYERS[name].stats:
            out[s] = moments[s] if s in ("min", "max") else moments[s] * scale  # scale keeps the Gram PSD
        elif s in ("min", "max"):
            out[s] = rng.integers(-50, 50, ix.size).astype(np.float64)
        elif s in LAYERS[name].counts:
            out[s] = rng.integers(1, 20, ix.size).astype(np.float64) * scale
        else:
            out[s] = rng.integers(-100, 100, ix.size).astype(np.float64) * scale
    return out


def make_delta(
    seq: int = 0,
    scout: str = SCOUT,
    epoch: int = 7,
    cells=((0, 0), (1, 2), (-3, 5)),
    layers=("slip", "elevation"),
    seed: int = 0,
) -> CellDelta:
    rng = np.random.default_rng(seed)
    ix = [c[0] for c in cells]
    iy = [c[1] for c in cells]
    return CellDelta(MAP, scout, epoch, seq, 1.5 * seq, RES, {n: layer_cells(n, ix, iy, rng) for n in layers})


def raw_delta() -> dict[str, Any]:
    """A valid cell_delta as the raw msgpack map, ready to be broken."""
    d = make_delta()
    layers = {}
    for name, cells in d.layers.items():
        layers[name] = {
            k: np.asarray(v, dtype="<i4" if k in ("ix", "iy") else "<f8").tobytes() for k, v in cells.items()
        }
    return {
        "v": 1,
        "type": "cell_delta",
        "map": MAP,
        "scout": SCOUT,
        "epoch": 7,
        "seq": 0,
        "t": 0.0,
        "res": RES,
        "layers": layers,
    }


def _f64(*v: float) -> bytes:
    return np.array(v, dtype="<f8").tobytes()


# reasons only a query (not a delta) can be rejected for; the server's limits on deltas (the decoder knows
# none of them); the reasons the decoder alone gives; and every reason a server rejects one delta for
# (seq_conflict needs an earlier delta: tested on its own)
QUERY_REASONS = ("duplicate_name", "limit_query_cells", "limit_reply_bytes", "busy")
LIMIT_REASONS = (
    "limit_cells", "limit_new_tiles", "limit_tiles", "limit_scout_tiles", "limit_scout_tile_rate", "outside_bbox"
)  # fmt: skip
SHARD_REASONS = ("wrong_shard",)  # a shard of a sharded map: a cell another shard owns
DECODE_REASONS = tuple(
    r for r in REASONS if r not in (*QUERY_REASONS, *LIMIT_REASONS, *SHARD_REASONS, "seq_conflict")
)
DELTA_REASONS = DECODE_REASONS + LIMIT_REASONS + SHARD_REASONS


def broken(reason: str) -> tuple[str, bytes, dict[str, Any]]:
    """(key, payload, kwargs) of a cell_delta that must be rejected with `reason`; kwargs: decode's, plus
    `limits` (a server's `Limits` fields) for the limit reasons, `bbox` (cells) for outside_bbox, `partition` ({shards, tile}) and `shard`
    for wrong_shard (the merger is shard 0 of 2 with 8-cell tiles; cell (9, 0) is in tile (1, 0), shard 1)."""
    key = delta_key(MAP, SCOUT)
    kw: dict[str, Any] = {"key": key, "res": RES}
    d = raw_delta()
    slip = d["layers"]["slip"]
    if reason == "decode":
        return key, b"\xc1\x00not msgpack", kw
    if reason == "oversize":
        kw["max_bytes"] = 64
    elif reason == "bad_version":
        d["v"] = 2
    elif reason == "bad_type":
        d["type"] = "cell_deltas"
    elif reason == "missing_field":
        del d["epoch"]
    elif reason == "wrong_type":
        d["seq"] = "3"
    elif reason == "bad_id":
        d["scout"] = "s 1/x"
    elif reason == "bad_value":
        d["seq"] = -1
    elif reason == "key_mismatch":
        d["scout"] = "s2"
    elif reason == "wrong_res":
        d["res"] = 0.5
    elif reason == "unknown_layer":
        d["layers"]["cots"] = copy.deepcopy(slip)
    elif reason == "unknown_stat":
        slip["evnts"] = slip["events"]
    elif reason == "bad_length":
        slip["ix"] = slip["ix"][:-1]
    elif reason == "length_mismatch":
        slip["events"] = slip["events"][:-8]
    elif reason == "nonfinite":
        slip["events"] = _f64(1.0, np.nan, 2.0)
    elif reason == "negative_count":
        slip["n"] = _f64(1.0, -1.0, 2.0)
    elif reason == "stat_range":
        slip["n"] = _f64(1.0, 1e308, 2.0)
    elif reason == "inconsistent":
        e = d["layers"]["elevation"]
        e["sumsq"] = _f64(0.0, 0.0, 0.0)  # sumsq < sum²/n: a negative variance (sum is not 0 in every cell)
    elif reason == "index_range":
        slip["ix"] = np.array([0, 2**30 + 1, 2], dtype="<i4").tobytes()
    elif reason == "limit_cells":
        kw["limits"] = {"max_cells_per_delta": 2}  # the delta has 3
    elif reason == "limit_new_tiles":
        slip["ix"] = np.array([0, 1000, 2000], dtype="<i4").tobytes()  # three tiles far apart
        kw["limits"] = {"max_new_tiles_per_delta": 2}
    elif reason == "limit_tiles":
        slip["ix"] = np.array([100, 101, 102], dtype="<i4").tobytes()  # one tile the map does not have yet
        kw["limits"] = {"max_tiles": 1}
    elif reason in ("limit_scout_tiles", "limit_scout_tile_rate"):
        slip["ix"] = np.array([0, 1000, 2000], dtype="<i4").tobytes()  # two tiles new to the map
        field = "max_tiles_per_scout" if reason == "limit_scout_tiles" else "max_new_tiles_per_scout_minute"
        kw["limits"] = {field: 1}
    elif reason == "outside_bbox":
        slip["ix"] = np.array([0, 100, 2], dtype="<i4").tobytes()
        kw["bbox"] = (-10, -10, 10, 10)  # cells (ix0, iy0, ix1, iy1) a delta may touch
    elif reason == "wrong_shard":
        slip["ix"] = np.array([0, 9, 2], dtype="<i4").tobytes()
        kw["partition"], kw["shard"] = {"shards": 2, "tile": 8}, 0
    elif reason == "duplicate_cell":
        slip["ix"] = np.array([4, 4, 1], dtype="<i4").tobytes()
        slip["iy"] = np.array([4, 4, 1], dtype="<i4").tobytes()
    else:
        raise AssertionError(f"no broken message for {reason}")
    return key, msgpack.packb(d, use_bin_type=True), kw
