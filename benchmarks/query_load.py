"""Queries never block deltas (issue 25): scout ack latency with and without a flood of concurrent queries.

A router and a `psrmap server --db` in their own processes. A scout process publishes pre-encoded deltas
(`--scouts` scouts, `--rate` deltas/s in all, 20 cells × 5 layers each) and times each delta from its put to the
ack that covers it. Phase 1 (`--seconds`): ingest only. Phase 2 (`--seconds`): the same ingest while a query
process keeps `--queries` region queries in flight at once (40 m × 40 m, every stat of every layer: the heavy
kind), issuing a new burst as soon as the last one is answered. Prints one JSON object: ack p50/p99 of each
phase, their ratio (goal: p99 with queries ≤ 2× without), and the queries answered, refused `busy`, or lost.
(Before issue 25: ack p99 9 ms → 4.4 s during a burst of 1,000 queries.)

    python benchmarks/query_load.py [--queries 1000] [--seconds 10] [--rate 200] [--scouts 10]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from ingest import MAP, RES, layers_for, shutdown, spawn


def scouts(endpoint: str, n: int, rate: float, seconds: float, phase2, results) -> None:
    """Publish for 2 × `seconds`; each ack latency is labelled with the phase its delta was sent in."""
    import zenoh

    from protocol import decode, encode
    from protocol.keys import ack_key, delta_key
    from protocol.messages import Ack, CellDelta
    from psrmap_common.session import zenoh_config

    rng = np.random.default_rng(0)
    per = int(rate * 2 * seconds / n) + 2
    payloads = [
        [encode(CellDelta(MAP, f"q{i}", 1, k, float(k), RES, layers_for(i, k, rng))) for k in range(per)]
        for i in range(n)
    ]
    sent: list[dict[int, tuple[float, int]]] = [{} for _ in range(n)]  # scout -> seq -> (put time, phase)
    acked = [-1] * n
    lat: dict[int, list[float]] = {1: [], 2: []}
    lock = threading.Lock()

    def on_ack(sample: zenoh.Sample) -> None:
        now = time.perf_counter()
        ack = decode(sample.payload.to_bytes())
        assert isinstance(ack, Ack)
        i = int(ack.scout[1:])
        with lock:
            for seq in range(acked[i] + 1, ack.seq + 1):
                got = sent[i].pop(seq, None)
                if got is not None:
                    lat[got[1]].append(now - got[0])
            acked[i] = max(acked[i], ack.seq)

    with zenoh.open(zenoh_config(connect=[endpoint], mode="client")) as s:
        subs = [s.declare_subscriber(ack_key(MAP, f"q{i}"), on_ack) for i in range(n)]
        pubs = [  # as scouts publish: reliable, blocking (never dropped under load)
            s.declare_publisher(delta_key(MAP, f"q{i}"), congestion_control=zenoh.CongestionControl.BLOCK)
            for i in range(n)
        ]
        time.sleep(0.5)
        t0 = time.perf_counter()
        k = 0
        while (now := time.perf_counter()) - t0 < 2 * seconds:
            if k >= (now - t0) * rate:
                time.sleep(max(0.0, k / rate - (now - t0)))
                continue
            phase = 1 if now - t0 < seconds else 2
            if phase == 2 and not phase2.is_set():
                phase2.set()
            i, seq = k % n, k // n
            with lock:
                sent[i][seq] = (time.perf_counter(), phase)
            pubs[i].put(payloads[i][seq])
            k += 1
        deadline = time.perf_counter() + 30
        while time.perf_counter() < deadline and any(sent):
            time.sleep(0.05)
        for x in subs + pubs:
            x.undeclare()
    with lock:
        results.put({"sent": k, "unacked": sum(len(x) for x in sent), 1: lat[1], 2: lat[2]})


def queries(endpoint: str, burst: int, phase2, stop, results) -> None:
    """Once phase 2 starts: keep `burst` region queries in flight at once until `stop`."""
    import zenoh

    from protocol.keys import map_key
    from protocol.messages import RegionQuery
    from psrmap_common.session import zenoh_config

    sel = f"{map_key(MAP)}?{RegionQuery(0.0, 0.0, 40.0, 40.0, None, ('all',)).to_parameters()}"
    ok = busy = other = lost = bursts = 0
    with zenoh.open(zenoh_config(connect=[endpoint], mode="client")) as s:
        phase2.wait(120)
        while not stop.is_set():
            handlers = [s.get(sel, timeout=20) for _ in range(burst)]
            bursts += 1
            for h in handlers:
                got = False
                for r in h:
                    got = True
                    if r.ok is not None:
                        ok += 1
                    elif r.err.payload.to_bytes().startswith(b"busy"):
                        busy += 1
                    else:
                        other += 1
                lost += not got
    results.put({"bursts": bursts, "ok": ok, "busy": busy, "error": other, "no_reply": lost})


def pct(a: list[float], q: float) -> float:
    return round(float(np.percentile(a, q)) * 1e3, 1) if a else float("nan")


def run(n_queries: int, seconds: float, rate: float, n_scouts: int) -> dict:
    from psrmap_common.session import free_endpoint

    ctx = mp.get_context("spawn")
    router = free_endpoint()
    services = [spawn("router", "--listen", router)]
    workers: list = []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            services.append(
                spawn("server", "--map", MAP, "--connect", router, "--db", str(Path(tmp) / "q.db"))
            )
            phase2, stop = ctx.Event(), ctx.Event()
            res_s, res_q = ctx.Queue(), ctx.Queue()
            workers = [
                ctx.Process(target=scouts, args=(router, n_scouts, rate, seconds, phase2, res_s)),
                ctx.Process(target=queries, args=(router, n_queries, phase2, stop, res_q)),
            ]
            for w in workers:
                w.start()
            sc = res_s.get(timeout=4 * seconds + 300)
            stop.set()
            q = res_q.get(timeout=120)
    finally:
        shutdown(workers, services)
    p99_1, p99_2 = pct(sc[1], 99), pct(sc[2], 99)
    return {
        "rate_deltas_per_s": rate,
        "scouts": n_scouts,
        "seconds_per_phase": seconds,
        "deltas_sent": sc["sent"],
        "deltas_unacked": sc["unacked"],
        "ack_ms_without_queries": {"p50": pct(sc[1], 50), "p99": p99_1, "n": len(sc[1])},
        "ack_ms_with_queries": {"p50": pct(sc[2], 50), "p99": p99_2, "n": len(sc[2])},
        "p99_ratio": round(p99_2 / p99_1, 2) if p99_1 else None,
        "goal_ratio": 2.0,
        "concurrent_queries": n_queries,
        "queries": q,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--queries", type=int, default=1000, help="region queries in flight at once")
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each phase [s]")
    ap.add_argument("--rate", type=float, default=200.0, help="deltas/s over all scouts")
    ap.add_argument("--scouts", type=int, default=10)
    a = ap.parse_args()
    print(json.dumps(run(a.queries, a.seconds, a.rate, a.scouts), indent=2))


if __name__ == "__main__":
    main()
