"""Fuzz the map server's input path with structure-aware mutations of valid deltas. Prints one JSON object.

Each message is a valid `cell_delta` mutated one of several ways: a byte flipped, truncated, a field dropped or
given the wrong type, a statistic set to NaN/inf/negative, an array cut short, an index beyond ±2³⁰, a cell
repeated, a huge cell count or spread, a wrong map or resolution — or left valid (and sometimes sent twice).
They go through `Merger.ingest` in batches (the server's own path), and with `--live N` the first N also over Zenoh
to a real server. Checks: no exception but ProtocolError-counted rejections (0 crashes); every message counted once
as merged, duplicate or rejected by reason; the map's totals equal the sums of exactly the accepted deltas
(0 partial merges).

    python benchmarks/fuzz.py [--messages 1000000] [--batch 128] [--live 20000] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections import Counter

import msgpack
import numpy as np

from map_server.limits import Limits
from map_server.merge import Merger
from protocol import decode, encode
from protocol.keys import delta_key
from protocol.messages import CellDelta
from protocol.testing import MAP, RES, layer_cells
from psrmap_mapcore import TiledMap

MUTATIONS = (
    "valid",
    "resend",
    "flip_byte",
    "truncate",
    "drop_field",
    "wrong_type",
    "nan",
    "inf",
    "negative",
    "short_array",
    "index_range",
    "repeat_cell",
    "many_tiles",
    "wrong_map",
    "wrong_res",
    "garbage",
)


def _valid(rng: np.random.Generator, scout: str, seq: int) -> CellDelta:
    n = int(rng.integers(1, 30))
    flat = rng.choice(400, size=n, replace=False)
    ix, iy = flat % 20 - 10, flat // 20 - 10
    names = rng.choice(
        ["elevation", "slip", "cot", "giim", "giam"], size=int(rng.integers(1, 4)), replace=False
    )
    return CellDelta(
        MAP, scout, 1, seq, float(seq), RES, {str(k): layer_cells(str(k), ix, iy, rng) for k in names}
    )


def _mutate(rng: np.random.Generator, payload: bytes, how: str) -> bytes:
    if how in ("valid", "resend"):
        return payload
    if how == "flip_byte":
        b = bytearray(payload)
        b[int(rng.integers(len(b)))] ^= 1 << int(rng.integers(8))
        return bytes(b)
    if how == "truncate":
        return payload[: int(rng.integers(len(payload)))]
    if how == "garbage":
        return rng.bytes(int(rng.integers(1, 200)))
    d = msgpack.unpackb(payload, raw=False)
    layer = next(iter(d["layers"].values()))
    stat = [k for k in layer if k not in ("ix", "iy")][0]
    if how == "drop_field":
        del d[str(rng.choice(["v", "type", "map", "scout", "epoch", "seq", "t", "res", "layers"]))]
    elif how == "wrong_type":
        d[str(rng.choice(["epoch", "seq", "res", "t"]))] = "x"
    elif how in ("nan", "inf", "negative"):
        a = np.frombuffer(layer[stat], "<f8").copy()
        a[int(rng.integers(a.size))] = {"nan": np.nan, "inf": np.inf, "negative": -1.0}[how]
        if how == "negative":
            layer["n"] = a.tobytes() if "n" in layer else layer.get("n")
        else:
            layer[stat] = a.tobytes()
    elif how == "short_array":
        layer[stat] = layer[stat][:-8]
    elif how == "index_range":
        a = np.frombuffer(layer["ix"], "<i4").copy()
        a[0] = 2**30 + 5
        layer["ix"] = a.tobytes()
    elif how == "repeat_cell":
        for k in ("ix", "iy"):
            a = np.frombuffer(layer[k], "<i4").copy()
            a[-1] = a[0]
            layer[k] = a.tobytes()
    elif how == "many_tiles":
        a = np.frombuffer(layer["ix"], "<i4").copy()
        a[:] = np.arange(a.size) * 10_000  # each cell in its own far tile
        layer["ix"] = a.tobytes()
    elif how == "wrong_map":
        d["map"] = "other"
    elif how == "wrong_res":
        d["res"] = 0.5
    return msgpack.packb(d, use_bin_type=True)


def main() -> None:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=1_000_000)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--live", type=int, default=0, help="also send the first N over Zenoh to a live server")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    rng = np.random.default_rng(args.seed)
    limits = Limits(max_new_tiles_per_delta=8)
    m = Merger(TiledMap(RES), MAP, limits=limits)
    key = {s: delta_key(MAP, s) for s in ("s1", "s2", "s3")}
    seqs = Counter()
    expected: dict[str, dict[str, float]] = {}
    kinds = Counter()
    crashes = 0
    sent_live: list[tuple[str, bytes]] = []
    t0 = time.perf_counter()
    done = 0
    last_valid: list[tuple[str, bytes]] = []
    while done < args.messages:
        batch = []
        for _ in range(min(args.batch, args.messages - done)):
            how = str(rng.choice(MUTATIONS))
            if how == "resend" and last_valid:
                batch.append(last_valid[int(rng.integers(len(last_valid)))])
                kinds[how] += 1
                continue
            scout = str(rng.choice(list(key)))
            d = _valid(rng, scout, seqs[scout])
            payload = _mutate(rng, encode(d), "valid" if how == "resend" else how)
            if how in ("valid", "resend"):
                seqs[scout] += 1
            else:
                seqs[scout] += int(rng.integers(0, 2))  # a bad message may or may not burn a seq
            kinds[how] += 1
            batch.append((key[scout], payload))
        try:
            res = m.ingest(batch)
        except Exception as exc:  # a crash: the server's worker would have stopped
            crashes += 1
            print(f"crash: {type(exc).__name__}: {exc}", file=sys.stderr)
            done += len(batch)
            continue
        for a in res.accepted:  # what must be in the map: exactly the accepted deltas
            for name, cells in a.delta.layers.items():
                e = expected.setdefault(name, {})
                for s, v in cells.items():
                    if s not in ("ix", "iy") and s not in ("min", "max"):
                        e[s] = e.get(s, 0.0) + float(np.sum(v))
            last_valid = (last_valid + [(key[a.delta.scout], a.payload)])[-64:]
        if args.live and len(sent_live) < args.live:
            sent_live += batch[: args.live - len(sent_live)]
        done += len(batch)
    wall = time.perf_counter() - t0
    book = m.book
    totals = m.map.totals()
    exact = all(
        abs(totals[n][s] - v) <= 1e-6 * max(1.0, abs(v)) for n, e in expected.items() for s, v in e.items()
    )
    counted = book.merged + book.duplicates + sum(book.rejected.values())
    out = {
        "benchmark": "fuzz",
        "messages": done,
        "seconds": round(wall, 1),
        "messages_per_s": round(done / wall),
        "crashes": crashes,
        "merged": book.merged,
        "duplicates": book.duplicates,
        "rejected_by_reason": dict(sorted(book.rejected.items())),
        "counted": counted,
        "every_message_counted": counted == done and crashes == 0,
        "partial_merges": 0 if exact else "totals differ from the accepted deltas' sums",
        "totals_exact": exact,
        "mutations": dict(sorted(kinds.items())),
    }
    if args.live:
        out["live"] = _live(sent_live)
    print(json.dumps(out))


def _live(samples: list[tuple[str, bytes]]) -> dict:
    """Send the samples to a real server over a real router; it must still answer and agree with an in-process
    merge of the same stream."""
    import zenoh

    from map_server.service import MapService, ServerConfig
    from protocol.keys import status_key
    from psrmap_common.query import wait_for_server
    from psrmap_common.session import free_endpoint, zenoh_config

    ep = free_endpoint()
    ref = Merger(TiledMap(RES), MAP, limits=Limits(max_new_tiles_per_delta=8))
    for i in range(0, len(samples), 128):
        ref.ingest(samples[i : i + 128])
    with zenoh.open(zenoh_config(listen=[ep], mode="router")):
        cfg = ServerConfig(map_id=MAP, res=RES, connect=(ep,), limits=Limits(max_new_tiles_per_delta=8))
        with MapService(cfg) as service, zenoh.open(zenoh_config(connect=[ep], mode="client")) as c:
            assert wait_for_server(c, MAP)
            pubs = {
                k: c.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
                for k, _ in samples
            }
            for k, p in samples:
                pubs[k].put(p)
            target = len(samples)
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                b = service.merger.book
                if b.merged + b.duplicates + sum(b.rejected.values()) >= target:
                    break
                time.sleep(0.1)
            reply = next(iter(c.get(status_key(MAP), timeout=5)))
            st = decode(reply.ok.payload.to_bytes())
            return {
                "messages": target,
                "still_answers_status": st.merged == service.merger.book.merged,
                "merged": st.merged,
                "rejected": sum(st.rejected.values()),
                "duplicates": st.duplicates,
                "same_as_in_process": service.map.equals(ref.map) and st.merged == ref.book.merged,
                "worker": st.health.get("worker"),
            }


if __name__ == "__main__":
    main()
