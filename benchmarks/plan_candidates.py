"""The path-search candidates of issue 13 on the plan benchmark's grids: the planner's numba kernel against
dijkstra3d and pyastar2d (optional: `pip install dijkstra3d pyastar2d`; a missing one is reported, not run).

Each search runs on the same terrain-like cost grid, corner to corner, median of `--repeat` runs, in this one
process. The candidates cost a path by the cells they enter (no (a + b) / 2 edge cost, no √2 on diagonals),
so their paths are re-costed in the planner's metric: `excess` = how much more that path costs than the
planner's optimum (0 = the same optimum). Prints one JSON object.

    python benchmarks/plan_candidates.py [--sizes 1000,2000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import importlib
import json
import time

import numpy as np
from plan import terrain_costs

from psrmap_common.pathsearch.search import plan_path


def _median(fn, repeat: int):
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def path_cost(cost: np.ndarray, cells) -> float:
    """The planner's cost of a cell path: Σ len · (cost[a] + cost[b]) / 2, len 1 or √2 (res 1 m)."""
    c = np.asarray(cells)
    d = np.abs(np.diff(c, axis=0))
    length = np.where((d[:, 0] > 0) & (d[:, 1] > 0), np.sqrt(2.0), 1.0)
    v = cost[c[:, 0], c[:, 1]]
    return float((length * 0.5 * (v[1:] + v[:-1])).sum())


def main() -> None:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,2000")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    mods = {}
    for name in ("dijkstra3d", "pyastar2d"):
        try:
            mods[name] = importlib.import_module(name)
        except ImportError:
            mods[name] = None
    results = []
    for n in (int(s) for s in args.sizes.split(",")):
        cost = terrain_costs(n)
        start, goal = (0, 0), (n - 1, n - 1)
        plan_path(cost, start, goal, 1.0)  # numba: compile or cache load outside the timing
        t_ours, ours = _median(lambda: plan_path(cost, start, goal, 1.0), args.repeat)  # noqa: B023
        row: dict[str, object] = {"cells": f"{n}x{n}", "numba_s": round(t_ours, 4), "optimum": ours.cost}
        field = cost.astype(np.float32)  # +inf stays impassable
        runs = {
            "dijkstra3d": lambda m: m.dijkstra(field, start, goal, connectivity=8),  # noqa: B023
            "pyastar2d": lambda m: m.astar_path(field, start, goal, allow_diagonal=True),  # noqa: B023
        }
        for name, run in runs.items():
            m = mods[name]
            if m is None:
                row[name] = "not installed"
                continue
            t, path = _median(lambda: run(m), args.repeat)  # noqa: B023
            row[name] = {
                "s": round(t, 4),
                "vs_numba": round(t / t_ours, 2),
                "excess": round(path_cost(cost, path) / ours.cost - 1.0, 4),
            }
        results.append(row)
    print(json.dumps({"benchmark": "plan_candidates", "repeat": args.repeat, "results": results}))


if __name__ == "__main__":
    main()
