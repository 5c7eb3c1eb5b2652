"""Memory a hostile but well-formed stream can cost the map server, under its limits. Prints one JSON object.

The issue-12 attack: small deltas whose cells are spread over ±10⁶ cells, so each cell lands in a new 64×64 tile
(before the limits: 200 such deltas cost +609 MiB). Here the same stream goes through `Merger` with the default
`Limits` (tile budget `--max-tiles`) and with the limits off (huge values), in fresh processes, and the resident-memory growth is measured;
the bound the limits imply (max_new_tiles_per_delta / max_tiles × bytes per tile) is printed beside it.

    python benchmarks/limits.py [--deltas 200] [--cells 20]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp


def _run(limits_on: bool, deltas: int, cells: int, max_tiles: int, q: mp.Queue) -> None:
    import logging

    import numpy as np
    import psutil

    from map_server.limits import Limits
    from map_server.merge import Merger
    from protocol import encode
    from protocol.keys import delta_key
    from protocol.messages import CellDelta
    from protocol.testing import layer_cells
    from psrmap_mapcore import TiledMap

    logging.disable(logging.WARNING)  # one warning per rejected delta otherwise
    big = 1 << 40
    limits = (
        Limits(max_tiles=max_tiles)
        if limits_on
        else Limits(max_cells_per_delta=big, max_new_tiles_per_delta=big, max_tiles=big)
    )
    m = Merger(TiledMap(0.4), "m", limits=limits)
    rng = np.random.default_rng(0)
    payloads = []
    for seq in range(deltas):
        ix = rng.integers(-(10**6), 10**6, cells)
        iy = rng.integers(-(10**6), 10**6, cells)
        layers = {
            name: layer_cells(name, ix, iy, rng) for name in ("elevation", "slip", "cot", "giim", "giam")
        }
        payloads.append((delta_key("m", "s1"), encode(CellDelta("m", "s1", 1, seq, 0.0, 0.4, layers))))
    proc = psutil.Process()
    rss0 = proc.memory_info().rss
    worst = 0
    for p in payloads:
        before = proc.memory_info().rss
        m.ingest([p])
        worst = max(worst, proc.memory_info().rss - before)
    tile_bytes = sum(g.store.shape[1] * g.store.shape[2] * 8 for g in m.map.grids.values())
    q.put(
        {
            "rss_growth_mib": round((proc.memory_info().rss - rss0) / 2**20, 1),
            "worst_single_delta_mib": round(worst / 2**20, 1),
            "tiles": len(m.map.gslots),
            "rejected": dict(m.book.rejected),
            "merged": m.book.merged,
            "wire_mib": round(sum(len(p[1]) for p in payloads) / 2**20, 3),
            "bytes_per_tile_all_layers_mib": round(tile_bytes / 2**20, 3),
            "bound_per_delta_mib": round(limits.max_new_tiles_per_delta * tile_bytes / 2**20, 1)
            if limits_on
            else None,
            "bound_map_mib": round(limits.max_tiles * tile_bytes / 2**20, 1) if limits_on else None,
        }
    )


def main() -> None:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--deltas", type=int, default=200)
    ap.add_argument("--cells", type=int, default=12, help="cells per delta, each in its own new tile")
    ap.add_argument("--max-tiles", type=int, default=512, help="the limited server's tile budget")
    args = ap.parse_args()
    ctx = mp.get_context("spawn")
    out = {"benchmark": "limits", "deltas": args.deltas, "cells_per_delta": args.cells}
    for name, on in (("no_limits", False), ("limits", True)):
        q: mp.Queue = ctx.Queue()
        p = ctx.Process(target=_run, args=(on, args.deltas, args.cells, args.max_tiles, q))
        p.start()
        out[name] = q.get()
        p.join()
    out["rss_ratio_limits_vs_none"] = round(
        out["limits"]["rss_growth_mib"] / max(out["no_limits"]["rss_growth_mib"], 1e-9), 4
    )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
