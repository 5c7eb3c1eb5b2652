"""Plan time on 1000^2 and 2000^2 cell maps vs scikit-image's route_through_array on the same cost grid.

The cost grid is terrain-like: smooth costs in [1, 5] per metre plus impassable crater discs (1-3 % of
cells), seeded; the route runs corner to corner (the search's worst case: nearly every cell is
expanded). Both searches see the same grid and must find the same optimal cost. `plan_s` is the
search alone (`search.plan_path`, what route_through_array does); `build_costs_infer_s` is turning an
n x n map of all layers (10 % unexplored, unknown=infer) into a cost grid (`build_costs`), and
`total_plan_s` = build + search, what a user's `psrmap plan --unknown infer` spends after fetching the
map. Times are medians of `--repeat` runs (`build_costs_first_s`: the first build in the process, which
also pays for the kernel handing the process fresh memory; `build_costs_penalty_s`, `_forbid_s`: the
other unknown policies). `c_kernel_s`: the planner's previous C kernel (compiled at run time with `cc`,
`_c_search_kernel.py`) on the same grid, the baseline the packaged numba kernel is held to
(`vs_c_kernel` = plan_s / c_kernel_s, goal <= 1.5; null without a C compiler). Goals: `ratio` <= 0.5 (search vs route_through_array) and `total_plan_s` < 1 s
on 2000 x 2000 (`goal_total_2000_lt_1s`). Prints one JSON object.

    python benchmarks/plan.py [--sizes 1000,2000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import ctypes
import json
import time

import numpy as np
from _c_search_kernel import load as load_c_kernel
from scipy import ndimage
from skimage.graph import route_through_array

from consumer_planner.costs import CostConfig, build_costs
from psrmap_common.pathsearch.search import plan_path
from psrmap_mapcore import LayerGrid


def terrain_costs(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    c = ndimage.gaussian_filter(rng.random((n, n)), n / 100)
    c = 1.0 + 4.0 * (c - c.min()) / (c.max() - c.min())
    k = n * n // 20000
    cy, cx = rng.integers(0, n, (2, k))
    rad = rng.integers(2, max(3, n // 80), k)
    yy, xx = np.ogrid[:n, :n]
    blocked = np.zeros((n, n), bool)
    for y, x, r in zip(cy, cx, rad, strict=True):
        y0, y1, x0, x1 = max(0, y - r), min(n, y + r + 1), max(0, x - r), min(n, x + r + 1)
        blocked[y0:y1, x0:x1] |= (yy[y0:y1] - y) ** 2 + (xx[:, x0:x1] - x) ** 2 <= r * r
    blocked[:3, :3] = blocked[-3:, -3:] = False
    c[blocked] = np.inf
    return c


def layer_grid(n: int, seed: int = 0) -> LayerGrid:
    """A map with every layer (value + n) of n x n cells, 10 % of them unexplored."""
    rng = np.random.default_rng(seed)
    count = np.where(rng.random((n, n)) < 0.1, 0.0, 10.0)
    layers = {
        name: {"value": np.where(count > 0, lo + (hi - lo) * rng.random((n, n)), np.nan), "n": count}
        for name, lo, hi in (("cot", 0.9, 1.5), ("slip", 0.0, 0.1), ("giim", 0.3, 0.8), ("giam", 0.5, 1.1))
    }
    return LayerGrid("bench", 0.4, 0, 0, n, n, layers)


def timed(fn, repeat: int) -> tuple[list[float], object]:
    """Run times of `repeat` calls (the previous result is dropped before each call) and the last result."""
    times, out = [], None
    for _ in range(repeat):
        out = None
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return times, out


def median_of(fn, repeat: int) -> tuple[float, object]:
    times, out = timed(fn, repeat)
    return float(np.median(times)), out


def c_kernel_plan(lib, cost: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> float:
    """The previous C kernel's dial8 (or astar8) on `cost` at res 1 m: the optimal cost, as it ran it."""
    h, w = cost.shape
    pw = w + 2
    padded = np.full((h + 2, pw), np.inf)
    padded[1:-1, 1:-1] = cost
    n = padded.size
    bufs = [np.empty(n, np.float64), np.empty(n, np.int64), np.empty(n, np.uint8), np.empty(n, np.int64)]
    ptrs = [ctypes.c_void_p(b.ctypes.data) for b in bufs]
    total = ctypes.c_double(0.0)
    ps = (start[0] + 1) * pw + start[1] + 1
    pg = (goal[0] + 1) * pw + goal[1] + 1
    finite = cost[np.isfinite(cost)]
    delta = finite.min() * (1.0 - 1e-9)
    nb = int(np.ceil(np.sqrt(2.0) * finite.max() / delta)) + 2
    pad = ctypes.c_void_p(padded.ctypes.data)
    m = lib.dial8(pad, h + 2, pw, 1.0, ps, pg, delta, nb, *ptrs, ctypes.byref(total))
    assert m > 0
    return float(total.value)


def main() -> None:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,2000")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    c_lib = load_c_kernel()
    results = []
    for n in (int(s) for s in args.sizes.split(",")):
        cost = terrain_costs(n)
        start, goal = (0, 0), (n - 1, n - 1)
        t_plan, path = median_of(lambda: plan_path(cost, start, goal, 1.0), args.repeat)  # noqa: B023
        sk_cost = np.where(np.isfinite(cost), cost, -1.0)
        t_sk, (_, sk_total) = median_of(
            lambda: route_through_array(sk_cost, start, goal, fully_connected=True, geometric=True),  # noqa: B023
            args.repeat,
        )
        assert path is not None
        plan_path(cost, start, goal, 1.0)  # the first call above paid numba's compile or cache load
        t_plan, path = median_of(lambda: plan_path(cost, start, goal, 1.0), args.repeat)  # noqa: B023
        t_c = c_cost = None
        if c_lib is not None:
            t_c, c_cost = median_of(lambda: c_kernel_plan(c_lib, cost, start, goal), args.repeat)  # noqa: B023
        grid = layer_grid(n)
        t_builds, _ = timed(lambda: build_costs(grid, CostConfig(unknown="infer")), args.repeat)  # noqa: B023
        t_costs = float(np.median(t_builds))
        t_other = {
            policy: median_of(lambda: build_costs(grid, CostConfig(unknown=policy)), args.repeat)[0]  # noqa: B023
            for policy in ("penalty", "forbid")
        }
        results.append({
            "cells": f"{n}x{n}",
            "impassable_fraction": round(float(np.isinf(cost).mean()), 4),
            "plan_s": round(t_plan, 4),
            "skimage_route_through_array_s": round(t_sk, 4),
            "ratio": round(t_plan / t_sk, 3),
            "plan_cost": path.cost,
            "skimage_cost": float(sk_total),
            "same_optimum": bool(abs(path.cost - sk_total) <= 1e-9 * sk_total),
            "method": path.method,
            "c_kernel_s": None if t_c is None else round(t_c, 4),
            "vs_c_kernel": None if t_c is None else round(t_plan / t_c, 3),
            "same_optimum_as_c_kernel": None if c_cost is None else bool(abs(path.cost - c_cost) <= 1e-9 * c_cost),
            "build_costs_infer_s": round(t_costs, 4),
            "build_costs_first_s": round(t_builds[0], 4),
            "build_costs_penalty_s": round(t_other["penalty"], 4),
            "build_costs_forbid_s": round(t_other["forbid"], 4),
            "total_plan_s": round(t_costs + t_plan, 4),
        })  # fmt: skip
    goals: dict[str, bool] = {"goal_ratio_le_0.5": all(r["ratio"] <= 0.5 for r in results)}
    if c_lib is not None:
        goals["goal_vs_c_kernel_le_1.5"] = all(r["vs_c_kernel"] <= 1.5 for r in results)
    big = [r for r in results if r["cells"] == "2000x2000"]
    if big:
        goals["goal_total_2000_lt_1s"] = big[0]["total_plan_s"] < 1.0
    head = {
        "benchmark": "plan",
        "c_kernel_available": c_lib is not None,
        "repeat": args.repeat,
        "timing": "median",
    }
    print(json.dumps({**head, "results": results, **goals}))


if __name__ == "__main__":
    main()
