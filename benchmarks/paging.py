"""A map bigger than memory: a server process with a tile budget builds a map `--factor` times that budget.

In the same run: a router, a map server with `--tile-budget-mib B` and one without a budget (the baseline), both
fed the same deltas (20 cells × 5 layers, the boustrophedon sweep of benchmarks/ingest.py) until their maps hold
`--factor` × B of tiles; then each one's RSS, against its RSS right after start (the fixed overhead: Python,
numpy, Zenoh, SQLite), and exact totals (cells and the sum of every count over a query of the whole map) against
a reference merge in this process. Prints one JSON object.

    python benchmarks/paging.py [--budget-mib 32] [--factor 4]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil
from ingest import FLEET_LIMITS, LANE_LEN, LAYERS5, RES, STEP, layers_for, shutdown, spawn

MAPS = ("paged", "whole")


def main() -> None:
    import zenoh

    from protocol import decode
    from protocol.keys import map_key
    from protocol.messages import MapRegion, RegionQuery
    from psrmap_common.query import get_replies, get_status, wait_for_server
    from psrmap_common.session import free_endpoint, zenoh_config
    from psrmap_mapcore import TiledMap
    from scout_agent.delivery import DeltaPublisher
    from scout_agent.publisher import ScoutLink, ZenohTransport

    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--budget-mib", type=float, default=32.0)
    ap.add_argument("--factor", type=float, default=4.0, help="map size as a multiple of the budget")
    args = ap.parse_args()

    ref = TiledMap(RES)
    rng = np.random.default_rng(0)
    deltas = []
    while ref.nbytes() < args.factor * args.budget_mib * 2**20:
        layers = layers_for(0, len(deltas), rng)
        ref.merge(layers)
        deltas.append(layers)
    ep = free_endpoint()
    tmp = tempfile.TemporaryDirectory()
    router = spawn("router", "--listen", ep)
    servers = {}
    for name in MAPS:
        budget = ["--tile-budget-mib", str(args.budget_mib) if name == "paged" else "0"]  # 0: no budget
        servers[name] = spawn("server", "--map", name, "--res", str(RES), "--db", str(Path(tmp.name) / f"{name}.db"),
                              "--connect", ep, *budget, *FLEET_LIMITS)  # fmt: skip
    out: dict = {
        "benchmark": "paging",
        "budget_mib": args.budget_mib,
        "map_tiles_mib": round(ref.nbytes() / 2**20, 1),
        "deltas": len(deltas),
        "cells": ref.cells,
    }
    try:
        with zenoh.open(zenoh_config(connect=[ep], mode="client")) as s:
            rss0 = {}
            for name in MAPS:
                assert wait_for_server(s, name)
                rss0[name] = psutil.Process(servers[name].pid).memory_info().rss
            for name in MAPS:
                pub = DeltaPublisher(ZenohTransport(s), name, "p0", RES, max_unacked=512, resend_after_s=5.0)
                t0 = time.perf_counter()
                with ScoutLink(s, pub, token=True) as link:
                    assert link.server_up.wait(10)
                    for k, layers in enumerate(deltas):
                        while pub.full:
                            pub.poll()
                            time.sleep(0.001)
                        pub.send(layers, float(k))
                    assert pub.wait_acked(120)
                dt = time.perf_counter() - t0
                time.sleep(1.0)
                rss_built = psutil.Process(servers[name].pid).memory_info().rss
                st = get_status(s, name, 10.0)
                assert st is not None
                lanes = len(deltas) // (LANE_LEN // STEP) + 1
                rq = RegionQuery(0.0, 0.0, (LANE_LEN + 0.5) * RES, (lanes * 4 + 0.5) * RES, LAYERS5, ("n",))
                region = decode(
                    get_replies(s, f"{map_key(name)}?{rq.to_parameters()}", 30.0).ok[0], max_bytes=1 << 30
                )
                assert isinstance(region, MapRegion)
                want = ref.region(region.ix0, region.iy0, region.ix0 + region.w - 1, region.iy0 + region.h - 1,
                                  LAYERS5, ("n",))  # fmt: skip
                exact = all(np.array_equal(region.layers[n]["n"], want[n]["n"]) for n in LAYERS5)
                rss = psutil.Process(servers[name].pid).memory_info().rss
                out[name] = {
                    "deltas_per_s": round(len(deltas) / dt, 1),
                    "rss_start_mib": round(rss0[name] / 2**20, 1),
                    "rss_built_mib": round(rss_built / 2**20, 1),
                    "rss_growth_built_mib": round((rss_built - rss0[name]) / 2**20, 1),
                    "rss_after_whole_map_query_mib": round(rss / 2**20, 1),
                    "cells_exact": st.cells == ref.cells,
                    "counts_exact": bool(exact),
                }
    finally:
        shutdown([], [*servers.values(), router])
        tmp.cleanup()
    p = out["paged"]
    out["paged_growth_over_budget"] = round(p["rss_growth_built_mib"] / args.budget_mib, 2)
    out["goal"] = "paged server's RSS growth within the budget (+ fixed overhead), totals exact"
    print(json.dumps(out))


if __name__ == "__main__":
    main()
