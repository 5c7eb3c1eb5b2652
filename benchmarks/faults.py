"""Fault injection against real processes: the map server killed with SIGKILL at random points of a stream and
restarted, and the router restarted mid-stream. Prints one JSON object.

A scout-like publisher (DeltaPublisher with acks and resend, over a real `psrmap router`) streams `--deltas`
deltas of 20 cells × 5 layers; meanwhile the server (`psrmap server --db`) is killed with SIGKILL `--kills` times at
random moments and restarted each time from its SQLite file; then the router itself is killed and restarted on the
same port. At the end every delta must be acknowledged and the server's totals must equal the sums of what was
sent: 0 lost, 0 doubled.

    python benchmarks/faults.py [--kills 100] [--deltas 3000] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import selectors
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from protocol import decode
from protocol.keys import status_key
from protocol.testing import layer_cells
from psrmap_common.session import free_endpoint, zenoh_config
from psrmap_mapcore import TiledMap
from scout_agent.delivery import DeltaPublisher
from scout_agent.publisher import ScoutLink, ZenohTransport

MAP, RES = "faults", 0.4


def _spawn(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "psrmap", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )


def _ready(proc: subprocess.Popen, word: str, timeout_s: float = 60.0) -> None:
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)  # type: ignore[arg-type]
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0 and sel.select(left):
        line = proc.stdout.readline().decode()  # type: ignore[union-attr]
        if word in line:
            return
        if not line:
            break
    raise RuntimeError(f"{proc.args} did not become ready (rc={proc.poll()})")


def main() -> None:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=100)
    ap.add_argument("--deltas", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    tmp = Path(tempfile.mkdtemp(prefix="psrmap-faults-"))
    ep = free_endpoint()
    server_args = ("server", "--map", MAP, "--res", str(RES), "--db", str(tmp / "map.db"), "--connect", ep)
    router = _spawn("router", "--listen", ep)
    _ready(router, "router")
    server = _spawn(*server_args)
    _ready(server, "server")
    reference = TiledMap(RES)
    kills = restarts_ok = 0
    router_restarted = False
    t0 = time.monotonic()
    with zenoh.open(zenoh_config(connect=[ep], mode="client")) as s:
        pub = DeltaPublisher(ZenohTransport(s), MAP, "scout", RES, resend_after_s=1.0, max_unacked=100_000)
        link = ScoutLink(s, pub)
        assert link.server_up.wait(20)
        kill_at = sorted(rng.choice(np.arange(50, args.deltas - 50), size=args.kills, replace=False).tolist())
        router_at = args.deltas * 3 // 4
        for i in range(args.deltas):
            r = np.random.default_rng(i)
            ix = np.arange(20) + (i % 50)
            iy = np.full(20, (i // 50) % 40)
            layers = {n: layer_cells(n, ix, iy, r) for n in ("elevation", "slip", "cot", "giim", "giam")}
            reference.merge(layers)
            pub.send(layers, float(i))
            pub.poll()
            while kill_at and kill_at[0] == i:
                kill_at.pop(0)
                server.kill()
                server.wait()
                kills += 1
                server.stdout.close()  # type: ignore[union-attr]
                server = _spawn(*server_args)
                _ready(server, "server")
                restarts_ok += 1
            if i == router_at:
                router.kill()
                router.wait()
                router.stdout.close()  # type: ignore[union-attr]
                router = _spawn("router", "--listen", ep)
                _ready(router, "router")
                router_restarted = True
            if i % 200 == 0:
                print(
                    f"[faults] {i}/{args.deltas} sent, {kills} kills, {pub.unacked} unacked", file=sys.stderr
                )
        deadline = time.monotonic() + 300
        while pub.unacked and time.monotonic() < deadline:
            pub.poll()
            threading.Event().wait(0.1)
        st = None
        for _ in range(50):
            replies = list(s.get(status_key(MAP), timeout=5))
            if replies and replies[0].ok is not None:
                st = decode(replies[0].ok.payload.to_bytes())
                break
        # the map's totals, read back with a raw-stat query of the whole touched box
        from consumer_planner.client import ClientConfig, query_region

        grid = query_region(s, MAP, (0, 0, 70 * RES, 41 * RES), ClientConfig(connect=(ep,)))
        link.close()
    want = reference.totals()
    got = {n: {k: float(np.nansum(grid.layers[n][k])) for k in want[n]} for n in want}
    exact = all(abs(got[n][k] - v) <= 1e-6 * max(1.0, abs(v)) for n in want for k, v in want[n].items())
    for p in (server, router):
        p.kill()
        p.wait()
    print(
        json.dumps(
            {
                "benchmark": "faults",
                "deltas": args.deltas,
                "server_kills": kills,
                "server_restarts": restarts_ok,
                "router_restarted": router_restarted,
                "unacked_at_end": pub.unacked,
                "merged": st.merged if st else None,
                "duplicates": st.duplicates if st else None,
                "lost": args.deltas - (st.merged if st else 0),
                "totals_exact": exact,
                "doubled": 0 if exact and st and st.merged == args.deltas else "see totals",
                "wall_seconds": round(time.monotonic() - t0, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
