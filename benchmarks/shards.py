"""Ingest scaling with map-server shards: one shard against K shards, in the same run, on a real router.

For each K (default 1 then 2): a router, K `psrmap server --shards K --shard i` processes (SQLite each), and
`--publishers` scout processes that pre-encode their deltas (20 cells × 5 layers, the boustrophedon sweep of
benchmarks/ingest.py, split by the map's partition with one seq stream per shard) and then send them as fast
as the shards' acks allow (at most `--window` unacknowledged per shard). The merged rate is the aggregated
`status` over a measurement window after a warm-up; the CPU seconds each process used in that window show
how the machine's cores were shared. Prints one JSON object.

    python benchmarks/shards.py [--shards 1,2] [--publishers 2] [--seconds 8] [--warmup 2]

With `--cpu-quota Q` (root; cgroup v1 or v2, benchmarks/cpu_quota.py) each shard server — and only the shards —
runs in its own cgroup with Q of a core, as K separate hosts would; the router and the publishers (pre-encoded)
stay outside the quotas (in an uncapped group). Every group gets the CFS weight `--cpu-weight` (default 8192, 8×
a lone process's), so on a machine loaded by other work a shard still reaches its quota and the harness keeps up. K = 1, 2, 3 then (default `--shards 1,2,3,1,2,3`); each run also reports every shard's
CPU use and how often its quota throttled it. Goal with Q = 0.3: K=2 ≥ 1.8× and K=3 ≥ 2.5× K=1's deltas/s.

    sudo python benchmarks/shards.py --cpu-quota 0.3 --publishers 6 --max-rate 9000

(Enough publishers that every shard has work at once — a publisher sweeps one tile, so one shard, at a time — and
enough pre-encoded deltas to last the window at K=3.)
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import signal
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil
from cpu_quota import CpuQuota
from ingest import FLEET_LIMITS, LAYERS5, MAP, RES, layers_for, shutdown, spawn

TILE = 64


def publisher(pid: int, endpoint: str, shards: int, n: int, window: int, ready, go, stop, results) -> None:
    """Pre-encode n deltas (split by shard), then send them as fast as acks allow until `stop`."""
    import zenoh

    from protocol import decode, encode
    from protocol.keys import ack_key, delta_key
    from protocol.messages import CellDelta
    from protocol.partition import Partition
    from psrmap_common.session import zenoh_config

    part = Partition(shards, TILE)
    rng = np.random.default_rng(pid)
    scout = f"p{pid}"
    queues: dict[int, list[bytes]] = {k: [] for k in range(shards)}
    for k in range(n):
        for shard, layers in part.split(layers_for(pid, k, rng)).items():
            seq = len(queues[shard])
            queues[shard].append(encode(CellDelta(MAP, scout, 1, seq, float(k), RES, layers)))
    acked = dict.fromkeys(range(shards), -1)
    cond = threading.Condition()

    def on_ack(sample) -> None:
        a = decode(sample.payload.to_bytes())
        key = str(sample.key_expr)
        shard = int(key.split("/")[3]) if shards > 1 else 0
        with cond:
            acked[shard] = max(acked[shard], a.seq)
            cond.notify_all()

    with zenoh.open(zenoh_config(connect=[endpoint], mode="client")) as s:
        keys = {k: delta_key(MAP, scout, k if shards > 1 else None) for k in range(shards)}
        pubs = {  # as the scouts publish (scout_agent.publisher.ZenohTransport): reliable, blocking
            k: s.declare_publisher(
                keys[k],
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
            )
            for k in range(shards)
        }
        subs = [
            s.declare_subscriber(ack_key(MAP, scout, k if shards > 1 else None), on_ack)
            for k in range(shards)
        ]
        sent = dict.fromkeys(range(shards), 0)
        ready.set()
        go.wait()
        while not stop.is_set():
            progressed = False
            for k in range(shards):
                q = queues[k]
                while sent[k] < len(q) and sent[k] - acked[k] <= window:
                    pubs[k].put(q[sent[k]])
                    sent[k] += 1
                    progressed = True
            if all(sent[k] >= len(queues[k]) for k in range(shards)):
                break
            if not progressed:
                with cond:
                    cond.wait(0.01)
        for sub in subs:
            sub.undeclare()
        results.put((pid, sum(sent.values()), sum(len(q) for q in queues.values())))


def run(k: int, args: argparse.Namespace) -> dict:
    import zenoh

    from psrmap_common.query import aggregate_status, get_statuses, wait_for_server
    from psrmap_common.session import free_endpoint, zenoh_config

    ep = free_endpoint()
    tmp = tempfile.TemporaryDirectory()
    router = spawn("router", "--listen", ep)
    servers = []
    quotas: list[CpuQuota] = []
    try:
        for i in range(k):
            shard = ["--shards", str(k), "--shard", str(i)] if k > 1 else []
            servers.append(
                spawn("server", "--map", MAP, "--res", str(RES), "--tile", str(TILE), "--db", str(Path(tmp.name) / f"s{i}.db"),
                      "--connect", ep, *shard, *FLEET_LIMITS, core=i % (psutil.cpu_count() or 1) if args.pin else None)
            )  # fmt: skip
            if args.cpu_quota:  # this shard, and only it, in a cgroup of its own with Q of a core
                quotas.append(
                    CpuQuota(args.cpu_quota, f"psrmap-bench-{os.getpid()}-k{k}-shard{i}", args.cpu_weight)
                )
                quotas[-1].add(servers[-1].pid)
    except BaseException:  # (interrupted or failed while starting: stop what started, remove the cgroups)
        shutdown([], [*servers, router])
        for q in quotas:
            q.close()
        tmp.cleanup()
        raise
    ctx = mp.get_context("spawn")
    ready = [ctx.Event() for _ in range(args.publishers)]
    go, stop, results = ctx.Event(), ctx.Event(), ctx.Queue()
    n = int(args.max_rate * (args.seconds + args.warmup + 5) / args.publishers)
    procs = [
        ctx.Process(target=publisher, args=(p, ep, k, n, args.window, ready[p], go, stop, results))
        for p in range(args.publishers)
    ]
    harness: CpuQuota | None = None
    out: dict = {"shards": k, "pinned": args.pin, "cpu_quota": args.cpu_quota}  # pinned: shard i on core i
    try:
        for p in procs:
            p.start()
        if args.cpu_quota and args.cpu_weight:  # router + publishers: no cap, the same weight as a shard
            harness = CpuQuota(None, f"psrmap-bench-{os.getpid()}-k{k}-harness", args.cpu_weight)
            for pid in (router.pid, *(p.pid for p in procs)):
                harness.add(pid)  # type: ignore[arg-type]
        for e in ready:
            e.wait(600)
        with zenoh.open(zenoh_config(connect=[ep], mode="client")) as s:
            for i in range(k):
                assert wait_for_server(s, MAP, shard=i if k > 1 else None)

            def merged() -> int:
                for _ in range(50):
                    parts = get_statuses(s, MAP, 10.0)
                    if len(parts) == k:
                        return aggregate_status(parts).merged
                raise RuntimeError("not every shard answered status")

            go.set()
            time.sleep(args.warmup)
            ps = {"router": psutil.Process(router.pid)}
            ps.update({f"shard{i}": psutil.Process(sv.pid) for i, sv in enumerate(servers)})
            ps.update({f"publisher{j}": psutil.Process(p.pid) for j, p in enumerate(procs)})
            cpu0 = {name: sum(pr.cpu_times()[:2]) for name, pr in ps.items()}
            q0 = [q.stats() for q in quotas]
            m0, t0 = merged(), time.perf_counter()
            time.sleep(args.seconds)
            m1, t1 = merged(), time.perf_counter()
            cpu1 = {name: sum(pr.cpu_times()[:2]) for name, pr in ps.items()}
            q1 = [q.stats() for q in quotas]
            stop.set()
            got = [results.get(timeout=120) for _ in procs]
            dt = t1 - t0
            out.update(
                {
                    "deltas_per_s": round((m1 - m0) / dt, 1),
                    "window_s": round(dt, 2),
                    "parts_prepared": sum(g[2] for g in got),
                    # a delta split over K shards is K parts (each merged and counted by its shard): the merged
                    # rate above counts parts; in scouts' deltas it is this much lower
                    "parts_per_delta": round(sum(g[2] for g in got) / (n * args.publishers), 4),
                    "cpu_cores_used": {name: round((cpu1[name] - cpu0[name]) / dt, 2) for name in ps},
                }
            )
            out["cpu_cores_used_total"] = round(sum(out["cpu_cores_used"].values()), 2)
            if quotas:  # per shard: periods its quota throttled it in the window (it used its whole share)
                out["quota_throttled_periods"] = {
                    f"shard{i}": int(b["nr_throttled"] - a["nr_throttled"])
                    for i, (a, b) in enumerate(zip(q0, q1, strict=True))
                }
    finally:
        stop.set()
        go.set()
        shutdown(procs, [*servers, router])
        for q in [*quotas, *([harness] if harness is not None else [])]:
            q.close()
        tmp.cleanup()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument(
        "--shards",
        default=None,
        help="comma-separated K, run in this order (the first K is the baseline); default 1,2,1,2,1,2, with "
        "--cpu-quota 1,2,3,1,2,3",
    )
    ap.add_argument(
        "--cpu-quota",
        type=float,
        default=None,
        metavar="Q",
        help="run each shard server (only the shards) in its own cgroup with Q of a core (root; cgroup v1 or v2)",
    )
    ap.add_argument(
        "--cpu-weight",
        type=int,
        default=8192,
        metavar="W",
        help="with --cpu-quota: the CFS weight of each shard's group and of the router + publishers' (uncapped) "
        "group, against the machine's other processes (1024 each): so a shard gets its Q on a loaded machine "
        "(default 8192; 0: leave the weights alone)",
    )
    ap.add_argument("--publishers", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=8.0, help="measurement window per K [s]")
    ap.add_argument("--warmup", type=float, default=2.0, help="sending before the window starts [s]")
    ap.add_argument("--window", type=int, default=1024, help="unacknowledged deltas per shard per publisher")
    ap.add_argument(
        "--max-rate", type=float, default=30000.0, help="deltas/s to pre-encode for (all publishers)"
    )
    ap.add_argument(
        "--pin", action="store_true", help="pin shard i to core i (same CPU per shard whatever K; Linux only)"
    )
    args = ap.parse_args()
    if args.cpu_quota is not None and not args.cpu_quota > 0:
        ap.error(f"--cpu-quota {args.cpu_quota}: need a share of a core > 0 (e.g. 0.3)")
    shards = args.shards or ("1,2,3,1,2,3" if args.cpu_quota else "1,2,1,2,1,2")
    ks = [int(x) for x in shards.split(",")]

    def interrupted(signum: int, frame: object) -> None:  # SIGTERM: unwind, so `run` stops its children
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupted)
    runs = [run(k, args) for k in ks]
    per_k: dict[int, list[float]] = {}
    cpu_k: dict[int, list[float]] = {}
    for r in runs:
        per_k.setdefault(r["shards"], []).append(r["deltas_per_s"])
        if r["deltas_per_s"]:
            cpu_k.setdefault(r["shards"], []).append(1e6 * r["cpu_cores_used_total"] / r["deltas_per_s"])
    med = {k: float(np.median(v)) for k, v in per_k.items()}
    base = med[ks[0]]
    out = {
        "benchmark": "shards",
        "cells_per_layer": 20,
        "layers": len(LAYERS5),
        "publishers": args.publishers,
        "machine_cores": psutil.cpu_count(),
        "runs": runs,
        "median_deltas_per_s": {str(k): round(v, 1) for k, v in med.items()},
        "ratio_of_medians_vs_first": {str(k): round(v / base, 3) if base else None for k, v in med.items()},
        "median_cpu_us_per_delta_all_processes": {
            str(k): round(float(np.median(v)), 1) for k, v in cpu_k.items()
        },
        "cpu_quota": args.cpu_quota,
        "goal": "K=2 >= 1.8x and K=3 >= 2.5x K=1's deltas/s (each shard Q of a core)"
        if args.cpu_quota
        else "2 shards >= 1.5x one shard's saturated deltas/s",
        "note": "runs alternate in the order of --shards; medians per K; cpu_cores_used = CPU seconds per second of "
        "the window, per process (router, shards, publishers): how the machine's cores were shared",
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
