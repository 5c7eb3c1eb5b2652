"""Soak: N virtual scouts replaying recorded scout deltas at 5 Hz (with jitter) against K map-server shards.

The deltas are recorded once from a real scout walk (MuJoCo simulation, the scout's own estimators and
`Mapper`, `--record-seconds` of lunar terrain; cached under $XDG_CACHE_HOME/psrmap). Each virtual scout
replays them shifted to its own patch of the map (scouts 40 m apart), looping, so the visited area grows for
one loop and then stops growing. Virtual scouts are light: `--procs` processes, each one Zenoh session and
one `DeltaPublisher` per (scout, shard) over it; deltas are split by the map's partition, acks are
dispatched by key. A router and K `psrmap server --shards K --shard i` processes (SQLite each) serve.

Every `--report-s` (default 60 s) one JSON line: parts/s merged, p50/p99 publish→ack latency of the parts
acknowledged in that period (an ack follows the commit that makes a delta visible to queries), each shard's
RSS and the size of its SQLite file and WAL, and the CPU cores each process used (router, shards, scout hosts). At the end: parts sent, merged (aggregated status), duplicates, per-scout gaps — 0 lost
and 0 doubled means merged == parts sent and every (scout, shard) stream merged without a gap.

    python benchmarks/soak.py [--scouts 500] [--shards 2] [--minutes 10] [--procs 4]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import pickle
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil
from ingest import shutdown, spawn

MAP, RES, TILE = "soak", 0.4, 64
SPACING_CELLS = 100  # virtual scouts' patches are this many cells (40 m) apart


def _cpu_seconds(pids: dict[str, int | None]) -> dict[str, float]:
    """User + system CPU seconds so far of each named process (0 once it is gone)."""
    out = {}
    for name, pid in pids.items():
        try:
            t = psutil.Process(pid).cpu_times()
            out[name] = t.user + t.system
        except (psutil.Error, ValueError, TypeError):
            out[name] = 0.0
    return out


def cache_file(seconds: float) -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "psrmap"
    base.mkdir(parents=True, exist_ok=True)
    return base / f"soak_deltas_lunar0_{seconds:g}s.pkl"


def record(seconds: float) -> list[dict]:
    """The layers of every delta a real scout publishes on `seconds` of simulated lunar walk."""
    path = cache_file(seconds)
    if path.is_file():
        with path.open("rb") as f:
            return pickle.load(f)
    from scout_agent.mapping import Mapper, MapperConfig
    from scout_agent.run import ScoutRunConfig, run_scout

    deltas: list[dict] = []

    class Recorder:
        full = False

        def send(self, layers, t):
            deltas.append({k: {s: np.asarray(a).copy() for s, a in v.items()} for k, v in layers.items()})
            return len(deltas) - 1

        def poll(self):
            return 0

    mapper = Mapper(MapperConfig(res=RES), publisher=Recorder())
    print(
        f"[soak] recording {seconds:g} s of a scout walk (once; cached in {path})",
        file=sys.stderr,
        flush=True,
    )
    run_scout(
        ScoutRunConfig(scene="lunar", seed=0, route="direct", sim_seconds=seconds),
        on_tick=lambda sample, truth, sim: mapper.update(sample),
        progress=False,
    )
    mapper.flush()  # the last partial delta
    with path.open("wb") as f:
        pickle.dump(deltas, f)
    return deltas


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def shifted(layers: dict, dx: int, dy: int) -> dict:
    out = {}
    for name, cells in layers.items():
        c = dict(cells)
        c["ix"] = (np.asarray(cells["ix"], np.int64) + dx).astype(np.int32)
        c["iy"] = (np.asarray(cells["iy"], np.int64) + dy).astype(np.int32)
        out[name] = c
    return out


def host(
    pid: int,
    scouts: range,
    endpoint: str,
    shards: int,
    rate_hz: float,
    jitter: float,
    rec_path: str,
    stop,
    out_q,
) -> None:
    """One process of virtual scouts: replays the recording for each scout at `rate_hz` with jitter."""
    import zenoh

    from protocol import decode
    from protocol.keys import ack_pattern
    from protocol.partition import Partition
    from psrmap_common.session import zenoh_config
    from scout_agent.delivery import DeltaPublisher
    from scout_agent.publisher import ZenohTransport

    with open(rec_path, "rb") as f:  # the parent recorded it
        rec = pickle.load(f)
    part = Partition(shards, TILE)
    keys: list[int | None] = [None] if shards == 1 else list(range(shards))
    rng = np.random.default_rng(pid)
    lat: list[float] = []
    lat_lock = threading.Lock()
    sent_at: dict[tuple[str, int, int], float] = {}
    with zenoh.open(zenoh_config(connect=[endpoint], mode="client")) as s:
        tr = ZenohTransport(s)
        pubs = {
            (f"v{n}", k): DeltaPublisher(tr, MAP, f"v{n}", RES, max_unacked=4096, resend_after_s=2.0, shard=k)
            for n in scouts
            for k in keys
        }

        def on_ack(sample) -> None:
            a = decode(sample.payload.to_bytes())
            parts = str(sample.key_expr).split("/")
            shard = int(parts[3]) if shards > 1 else None
            pub = pubs.get((a.scout, shard))
            if pub is None:
                return
            prev = pub.acked_seq
            pub.on_ack(a)
            now = time.perf_counter()
            with lat_lock:
                for q in range(prev + 1, a.seq + 1):
                    t0 = sent_at.pop((a.scout, shard or 0, q), None)
                    if t0 is not None:
                        lat.append(now - t0)

        subs = [s.declare_subscriber(ack_pattern(MAP, k), on_ack) for k in keys]
        next_t = {n: time.perf_counter() + rng.uniform(0, 1 / rate_hz) for n in scouts}
        step = dict.fromkeys(scouts, 0)
        sent_parts = 0
        last_report = time.perf_counter()
        while not stop.is_set():
            now = time.perf_counter()
            due = [n for n in scouts if next_t[n] <= now]
            for n in due:
                k = step[n]
                layers = shifted(rec[k % len(rec)], (n % 50) * SPACING_CELLS, (n // 50) * SPACING_CELLS)
                for shard, lay in (part.split(layers) if shards > 1 else {0: layers}).items():
                    pub = pubs[(f"v{n}", shard if shards > 1 else None)]
                    seq = pub.send(lay, float(k))
                    with lat_lock:
                        sent_at[(f"v{n}", shard, seq)] = time.perf_counter()
                    sent_parts += 1
                step[n] = k + 1
                next_t[n] += (1 / rate_hz) * (1 + rng.uniform(-jitter, jitter))
            if now - last_report > 1.0:
                for pub in pubs.values():
                    pub.poll()
                with lat_lock:
                    out_q.put(("lat", pid, lat))
                    lat = []
                last_report = now
            wake = min(next_t.values()) - time.perf_counter()
            if wake > 0:
                stop.wait(min(wake, 0.05))
        # drain: everything acknowledged
        deadline = time.perf_counter() + 120
        while any(p.unacked for p in pubs.values()) and time.perf_counter() < deadline:
            for p in pubs.values():
                p.poll()
            time.sleep(0.05)
        for sub in subs:
            sub.undeclare()
        with lat_lock:
            out_q.put(("lat", pid, lat))
        out_q.put(
            (
                "done",
                pid,
                sent_parts,
                sum(p.unacked for p in pubs.values()),
                {f"{sc}/{k}": p.next_seq for (sc, k), p in pubs.items()},
            )
        )


def main() -> None:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--scouts", type=int, default=500)
    ap.add_argument("--shards", type=int, default=2)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--procs", type=int, default=4, help="processes hosting the virtual scouts")
    ap.add_argument("--rate-hz", type=float, default=5.0, help="deltas per virtual scout per second")
    ap.add_argument("--jitter", type=float, default=0.2, help="± share of the period")
    ap.add_argument("--report-s", type=float, default=60.0, help="seconds between status lines")
    ap.add_argument("--record-seconds", type=float, default=60.0, help="simulated walk recorded for replay")
    args = ap.parse_args()
    if args.scouts < 1 or args.shards < 1 or args.procs < 1 or args.minutes <= 0:
        ap.error("--scouts, --shards, --procs must be >= 1 and --minutes > 0")
    rec = record(args.record_seconds)
    import zenoh

    from psrmap_common.query import aggregate_status, get_statuses, wait_for_server
    from psrmap_common.session import free_endpoint, zenoh_config

    ep = free_endpoint()
    tmp = tempfile.TemporaryDirectory()
    router = spawn("router", "--listen", ep)
    servers = []
    for i in range(args.shards):
        shard = ["--shards", str(args.shards), "--shard", str(i)] if args.shards > 1 else []
        servers.append(
            spawn("server", "--map", MAP, "--res", str(RES), "--tile", str(TILE), "--db",
                  str(Path(tmp.name) / f"s{i}.db"), "--connect", ep, *shard)
        )  # fmt: skip
    ctx = mp.get_context("spawn")
    stop, q = ctx.Event(), ctx.Queue()
    per = np.array_split(np.arange(args.scouts), args.procs)
    procs = [
        ctx.Process(target=host, args=(j, range(int(c[0]), int(c[-1]) + 1), ep, args.shards, args.rate_hz, args.jitter, str(cache_file(args.record_seconds)), stop, q))
        for j, c in enumerate(per)
        if len(c)
    ]  # fmt: skip
    summary: dict = {
        "benchmark": "soak",
        "scouts": args.scouts,
        "shards": args.shards,
        "rate_hz": args.rate_hz,
        "offered_deltas_per_s": args.scouts * args.rate_hz,
        "recorded_deltas": len(rec),
        "minutes": args.minutes,
    }
    lines = []
    try:
        with zenoh.open(zenoh_config(connect=[ep], mode="client")) as s:
            for i in range(args.shards):
                assert wait_for_server(s, MAP, shard=i if args.shards > 1 else None)
            for p in procs:
                p.start()
            t0 = time.perf_counter()
            end = t0 + 60 * args.minutes
            lat: list[float] = []
            last, merged0 = t0, 0
            watched = {"router": router.pid, **{f"shard{i}": sv.pid for i, sv in enumerate(servers)},
                       **{f"scouts{j}": pr.pid for j, pr in enumerate(procs)}}  # fmt: skip
            cpu0 = _cpu_seconds(watched)
            while (now := time.perf_counter()) < end:
                try:
                    kind, _, chunk = q.get(timeout=0.5)[:3]
                    if kind == "lat":
                        lat.extend(chunk)
                except Exception:
                    pass
                if now - last >= args.report_s:
                    parts = get_statuses(s, MAP, 10.0)
                    st = aggregate_status(parts)
                    ms = np.array(lat) * 1e3 if lat else np.array([np.nan])
                    cpu1 = _cpu_seconds(watched)
                    line = {
                        "t_min": round((now - t0) / 60, 2),
                        "merged_parts_per_s": round((st.merged - merged0) / (now - last), 1),
                        "acked_parts": len(lat),
                        "p50_ms": round(float(np.percentile(ms, 50)), 2),
                        "p99_ms": round(float(np.percentile(ms, 99)), 2),
                        "rss_mib": [
                            round(psutil.Process(sv.pid).memory_info().rss / 2**20, 1) for sv in servers
                        ],
                        "db_wal_mib": [
                            [round(_size(Path(tmp.name) / f"s{i}.db{x}") / 2**20, 1) for x in ("", "-wal")]
                            for i in range(args.shards)
                        ],
                        "cells": st.cells,
                        # CPU seconds per second of the period, per process: how the machine's cores were shared
                        "cpu_cores": {
                            k: round((v - cpu0.get(k, 0.0)) / (now - last), 2) for k, v in cpu1.items()
                        },
                    }
                    cpu0 = cpu1
                    print(json.dumps(line), flush=True)
                    lines.append(line)
                    lat, last, merged0 = [], now, st.merged
            stop.set()
            done = []
            while len(done) < len(procs):
                msg = q.get(timeout=300)
                if msg[0] == "done":
                    done.append(msg)
            sent = sum(d[2] for d in done)
            left = sum(d[3] for d in done)
            streams = {k: v for d in done for k, v in d[4].items()}
            time.sleep(1.0)
            parts = get_statuses(s, MAP, 10.0)
            st = aggregate_status(parts)
            per_stream_hw = {
                f"{name}/{p.shard if p.shard is not None else None}": sc.last_seq
                for p in parts
                for name, sc in p.scouts.items()
            }
            gaps = sum(1 for k, n in streams.items() if n and per_stream_hw.get(k, -1) != n - 1)
            rss = [ln["rss_mib"] for ln in lines]
            summary.update(
                {
                    "minutes_run": round((time.perf_counter() - t0) / 60, 2),
                    "parts_sent": sent,
                    "unacked_at_end": left,
                    "merged": st.merged,
                    "duplicates": st.duplicates,
                    "rejected": st.rejected,
                    "streams_with_gaps": gaps,
                    "lost": max(0, sent - st.merged),
                    "doubled": max(0, st.merged - sent),
                    "cells": st.cells,
                    "lines": lines,
                    "p99_ms_max_over_minutes": max((ln["p99_ms"] for ln in lines), default=None),
                    "rss_mib_first_last": [rss[0], rss[-1]] if rss else None,
                }
            )
    finally:
        stop.set()
        shutdown(procs, [*servers, router])
        tmp.cleanup()
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
