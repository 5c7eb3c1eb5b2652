"""One scout tries to exhaust a map server with default settings (issue 25); prints one JSON object.

A router and a `psrmap server` with default settings only (`--map`, `--connect`, and `--db` unless `--no-db`)
in their own processes; then one scout's credentials-free client publishes `--deltas` tiny deltas, each with
`--cells` cells of every layer spread over ±10⁶ cells (so each cell lands in a tile new to the map). Afterwards another scout
sends one delta into new area and must be merged. Printed: the server's RSS before and after [MiB] and its
growth (goal ≤ 256 MiB), its WAL size, the rejections by reason, whether the other scout's delta was merged.
(Before issue 25: +3,485 MiB RSS and a 3.2 GB WAL, and every other scout's new area refused.)

    python benchmarks/scout_flood.py [--deltas 256] [--cells 16] [--no-db]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil
import zenoh
from ingest import shutdown, spawn

from protocol import decode, encode
from protocol.keys import delta_key, status_key
from protocol.layers import LAYERS
from protocol.messages import CellDelta, Status
from protocol.testing import layer_cells
from psrmap_common.query import wait_for_server
from psrmap_common.session import free_endpoint, zenoh_config

MAP, RES = "flood", 0.4


def status(session: zenoh.Session) -> Status:
    for r in session.get(status_key(MAP), timeout=10):
        if r.ok is not None:
            st = decode(r.ok.payload.to_bytes())
            assert isinstance(st, Status)
            return st
    raise RuntimeError("no status reply")


def flood_deltas(scout: str, deltas: int, cells: int, seed: int = 0) -> list[bytes]:
    rng = np.random.default_rng(seed)
    out = []
    for seq in range(deltas):
        ix, iy = rng.integers(-(10**6), 10**6, cells), rng.integers(-(10**6), 10**6, cells)
        layers = {name: layer_cells(name, ix, iy, rng) for name in LAYERS}  # every layer: the costliest tiles
        out.append(encode(CellDelta(MAP, scout, 1, seq, float(seq), RES, layers)))
    return out


def run(deltas: int, cells: int, db: str | None, timeout_s: float = 120.0) -> dict:
    router = free_endpoint()
    services = [spawn("router", "--listen", router)]
    try:
        services.append(spawn("server", "--map", MAP, "--connect", router, *(["--db", db] if db else [])))
        server = psutil.Process(services[-1].pid)
        with zenoh.open(zenoh_config(connect=[router], mode="client")) as s:
            assert wait_for_server(s, MAP)
            time.sleep(1.0)  # let the server settle (imports, first allocations)
            rss0 = server.memory_info().rss
            hog_pub = s.declare_publisher(
                delta_key(MAP, "hog"), congestion_control=zenoh.CongestionControl.BLOCK
            )
            for p in flood_deltas("hog", deltas, cells):  # as a scout publishes: blocking, never dropped
                hog_pub.put(p)
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                st = status(s)
                if st.merged + sum(st.rejected.values()) >= deltas:
                    break
                time.sleep(0.2)
            time.sleep(0.5)
            rss1 = server.memory_info().rss
            hog = status(s)
            other = encode(
                CellDelta(MAP, "other", 1, 0, 0.0, RES, {"slip": layer_cells("slip", [5000], [-7000])})
            )
            s.put(delta_key(MAP, "other"), other, congestion_control=zenoh.CongestionControl.BLOCK)
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline and status(s).merged <= hog.merged:
                time.sleep(0.1)
            after = status(s)
        wal = Path(db + "-wal").stat().st_size if db and Path(db + "-wal").exists() else 0
        return {
            "db": bool(db),
            "deltas": deltas,
            "cells_per_delta": cells,
            "rss_before_mib": round(rss0 / 2**20, 1),
            "rss_after_mib": round(rss1 / 2**20, 1),
            "rss_growth_mib": round((rss1 - rss0) / 2**20, 1),
            "goal_growth_mib": 256,
            "wal_mib": round(wal / 2**20, 1),
            "hog_merged": hog.merged,
            "hog_decided": hog.merged + sum(hog.rejected.values()) == deltas,  # every delta merged or refused
            "hog_rejected": dict(hog.rejected),
            "other_scout_new_area_merged": after.merged == hog.merged + 1,
        }
    finally:
        shutdown([], services)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--deltas", type=int, default=256)
    ap.add_argument("--cells", type=int, default=16, help="cells per delta, each in a new tile")
    ap.add_argument(
        "--no-db", action="store_true", help="a memory-only server (the default of psrmap server)"
    )
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        print(json.dumps(run(a.deltas, a.cells, None if a.no_db else str(Path(tmp) / "flood.db")), indent=2))


if __name__ == "__main__":
    main()
