"""Decode + validate + exactly-once merge throughput of the map core, against raw `np.add.at`.

Prints one JSON object. Updates = cells x statistics. Two delta sizes: the 20 cells x 5 layers a
walking scout sends at 5 Hz, and bulk deltas of 1000 cells x 5 layers (e.g. a replayed log).
Two raw references on the same arrays: `raw_add_at` = one np.add.at per (layer, stat) over all
deltas concatenated into a dense array (the ceiling), and `raw_add_at_per_array` = one np.add.at
per delta array (what a per-delta merge without any decoding would cost).
decode_merge = steady state (the cells' tiles exist: a second pass of the same deltas under another
epoch); fresh_map = the first pass, which also creates every tile (first touch of ~100 MB here).
Usage: python3 benchmarks/merge.py [--deltas 4000] [--bulk 200] [--batch 512]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from map_server.merge import Merger
from map_server.tiles import TiledMap
from protocol import LAYERS, encode
from protocol.keys import delta_key
from protocol.messages import CellDelta

LAYERS5 = ("elevation", "slip", "cot", "giim", "giam")
RES = 0.4


def make_deltas(n: int, cells: int, rng: np.random.Generator) -> list[CellDelta]:
    out = []
    for seq in range(n):
        cx, cy = rng.integers(-300, 300, 2)
        flat = rng.choice(64 * 64, size=cells, replace=False)
        ix = (cx + flat % 64).astype(np.int32)
        iy = (cy + flat // 64).astype(np.int32)
        layers = {}
        for name in LAYERS5:
            cellsd: dict[str, np.ndarray] = {"ix": ix, "iy": iy}
            for s in LAYERS[name].stats:
                cellsd[s] = rng.uniform(0.0, 2.0, cells)
            layers[name] = cellsd
        out.append(CellDelta("bench", "s1", 1, seq, 0.0, RES, layers))
    return out


def raw_add_at(deltas: list[CellDelta]) -> tuple[float, int]:
    """One `np.add.at` per (layer, stat) over every cell of every delta into a dense array: the ceiling."""
    span = 800
    prepared = []
    for name in LAYERS5:
        ix = np.concatenate([d.layers[name]["ix"] for d in deltas]).astype(np.int64) + 320
        iy = np.concatenate([d.layers[name]["iy"] for d in deltas]).astype(np.int64) + 320
        idx = iy * span + ix
        for s in LAYERS[name].stats:
            prepared.append((idx, np.concatenate([d.layers[name][s] for d in deltas])))
    target = np.zeros(span * span)
    t0 = time.perf_counter()
    for idx, vals in prepared:
        np.add.at(target, idx, vals)
    dt = time.perf_counter() - t0
    return dt, sum(v.size for _, v in prepared)


def raw_add_at_per_array(deltas: list[CellDelta]) -> tuple[float, int]:
    """`np.add.at` on each delta's own arrays (one call per delta, layer and stat), no decode."""
    span = 800
    prepared = []
    for d in deltas:
        for name in LAYERS5:
            c = d.layers[name]
            idx = (c["iy"].astype(np.int64) + 320) * span + c["ix"].astype(np.int64) + 320
            prepared.extend((idx, c[s]) for s in LAYERS[name].stats)
    target = np.zeros(span * span)
    t0 = time.perf_counter()
    for idx, vals in prepared:
        np.add.at(target, idx, vals)
    dt = time.perf_counter() - t0
    return dt, sum(v.size for _, v in prepared)


def ingest(deltas: list[CellDelta], batch: int) -> tuple[float, float, int]:
    """(seconds into a fresh map, seconds into the same map again, updates per pass).

    The first pass creates the tiles (first touch of their memory); the second merges the same cells
    again as new deltas (another epoch) into existing tiles: the steady state of a long mission.
    """
    merger = Merger(TiledMap(RES), "bench")
    times = []
    for epoch in (1, 2):
        samples = [(delta_key(d.map, d.scout), encode(dataclasses.replace(d, epoch=epoch))) for d in deltas]
        t0 = time.perf_counter()
        for i in range(0, len(samples), batch):
            r = merger.ingest(samples[i : i + batch])
            assert not r.rejected
        times.append(time.perf_counter() - t0)
    assert merger.book.merged == 2 * len(deltas)
    return times[0], times[1], sum(d.n_updates() for d in deltas)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--deltas", type=int, default=4000, help="small deltas (20 cells x 5 layers)")
    ap.add_argument("--bulk", type=int, default=200, help="bulk deltas (1000 cells x 5 layers)")
    ap.add_argument("--batch", type=int, default=512, help="deltas per ingest batch (the server's batch_max)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    out: dict[str, object] = {"benchmark": "merge", "batch": args.batch}
    for label, n, cells in (("scout_20x5", args.deltas, 20), ("bulk_1000x5", args.bulk, 1000)):
        deltas = make_deltas(n, cells, rng)
        ingest(deltas[: max(1, n // 10)], args.batch)  # warm-up
        t_raw, u_raw = raw_add_at(deltas)
        t_arr, u_arr = raw_add_at_per_array(deltas)
        t_cold, t_ing, u_ing = ingest(deltas, args.batch)
        raw_rate, rate, arr_rate = u_raw / t_raw, u_ing / t_ing, u_arr / t_arr
        out[label] = {
            "deltas": n,
            "updates": u_ing,
            "decode_merge_updates_per_s": round(rate),
            "deltas_per_s": round(n / t_ing),
            "fresh_map_updates_per_s": round(u_ing / t_cold),
            "fresh_map_fraction_of_raw": round(u_ing / t_cold / raw_rate, 3),
            "raw_add_at_updates_per_s": round(raw_rate),
            "fraction_of_raw": round(rate / raw_rate, 3),
            "raw_add_at_per_array_updates_per_s": round(arr_rate),
            "fraction_of_raw_per_array": round(rate / arr_rate, 3),
        }
    s = out["scout_20x5"]
    assert isinstance(s, dict)
    out["goal_met"] = bool(s["fraction_of_raw"] >= 0.25 and s["decode_merge_updates_per_s"] >= 5e6)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
