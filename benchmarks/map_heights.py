"""Where a mission's map heights are wrong: each scout's own map against the terrain, split into a vertical
offset, a horizontal misplacement and the rest (evaluation only: it reads the simulator's terrain).

Per scout (its saved `<id>_local.npz` and its estimated path in `summary.json`), each cell with data is given
the distance walked at the nearest point of the path; per `--segment` metres of walk:
- offset: the mean of (map height − terrain height) over the segment's cells (a datum error or a height drift);
- horizontal: what the best shift of the terrain under the segment (±`--shift` m, 0.1 m steps, each with its
  own offset) takes off the mean square left after the offset (the map placed beside where it was);
- rest: what is left after both (rocks and the foot's sinkage inside a 0.4 m cell, the plane fit at its centre,
  and the drift within one segment).
The three mean squares add up to the own map's mean square error; the script prints their square roots, per
segment and per scout, and the mission's map figures beside them.

    python benchmarks/map_heights.py /tmp/run                  # a `psrmap mission --run-dir /tmp/run` folder
    python benchmarks/map_heights.py /tmp/run --segment 20 --quiet
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from psrmap.agreement import grid_height
from psrmap_mapcore import read_npz
from scout_agent.run import ScoutRunConfig, build_world
from scout_agent.sim.terrain import Terrain


def decompose(
    run: Path, scout: str, summary: dict, terrain: Terrain, segment_m: float, shift_m: float
) -> dict:
    g = read_npz(run / f"{scout}_local.npz")
    h = grid_height(g)
    if h is None:
        return {"cells": 0}
    ok = (np.nan_to_num(g.layers["elevation"]["n"]) > 0) & np.isfinite(h)
    iy, ix = np.nonzero(ok)
    cx = g.x0 + (g.ix0 + ix + 0.5) * g.res
    cy = g.y0 + (g.iy0 + iy + 0.5) * g.res
    z = h[iy, ix]
    err = z - terrain.height(cx, cy)
    path = np.asarray(summary["path_estimate"], dtype=float)  # t, x, y, z
    s = np.r_[0.0, np.cumsum(np.hypot(np.diff(path[:, 1]), np.diff(path[:, 2])))]
    nearest = np.argmin((cx[:, None] - path[None, :, 1]) ** 2 + (cy[:, None] - path[None, :, 2]) ** 2, axis=1)
    seg = np.floor(s[nearest] / segment_m).astype(int)
    shifts = np.arange(-shift_m, shift_m + 1e-9, 0.1)
    sq = {"offset": 0.0, "horizontal": 0.0, "rest": 0.0}
    rows = []
    for b in np.unique(seg):
        m = seg == b
        dz = float(err[m].mean())
        after_dz = float(np.mean((err[m] - dz) ** 2))
        best, best_shift = after_dz, (0.0, 0.0)
        for dx in shifts:
            for dy in shifts:
                r = z[m] - terrain.height(cx[m] - dx, cy[m] - dy)
                v = float(np.mean((r - r.mean()) ** 2))
                if v < best:
                    best, best_shift = v, (float(dx), float(dy))
        k = int(m.sum())
        sq["offset"] += k * dz**2
        sq["horizontal"] += k * (after_dz - best)
        sq["rest"] += k * best
        rows.append({"from_m": b * segment_m, "cells": k, "offset_m": round(dz, 3),
                     "horizontal_m": round(float(np.sqrt(max(after_dz - best, 0.0))), 3),
                     "rest_m": round(float(np.sqrt(best)), 3), "shift_m": best_shift})  # fmt: skip
    n = len(err)
    return {
        "cells": n,
        "rmse_m": round(float(np.sqrt(np.mean(err**2))), 3),
        "mean_m": round(float(err.mean()), 3),
        **{f"{k}_m": round(float(np.sqrt(max(v, 0.0) / n)), 3) for k, v in sq.items()},
        "_sq": {k: v for k, v in sq.items()},
        "segments": rows,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path, help="a mission's run folder (summary.json, <scout>_local.npz)")
    p.add_argument("--segment", type=float, default=10.0, help="segment of walk [m] (default 10)")
    p.add_argument(
        "--shift", type=float, default=3.0, help="largest horizontal shift searched [m] (default 3)"
    )
    p.add_argument("--quiet", action="store_true", help="per scout only, no segments")
    args = p.parse_args(argv)
    summary = json.loads((args.run / "summary.json").read_text())
    cfg = summary["config"]
    terrain = build_world(ScoutRunConfig(scene="lunar", seed=cfg["seed"], field_m=cfg["field_m"])).terrain
    total = {"offset": 0.0, "horizontal": 0.0, "rest": 0.0}
    cells = 0
    for scout, s in summary["scouts"].items():
        if "path_estimate" not in s:
            continue
        d = decompose(args.run, scout, s, terrain, args.segment, args.shift)
        if not d["cells"]:
            continue
        print(f"{scout}: {d['cells']} cells, RMSE {d['rmse_m']:.3f} m (mean {d['mean_m']:+.3f}) = offset "
              f"{d['offset_m']:.3f} ⊕ horizontal {d['horizontal_m']:.3f} ⊕ rest {d['rest_m']:.3f} m")  # fmt: skip
        if not args.quiet:
            for r in d["segments"]:
                print(f"  {r['from_m']:5.0f} m  {r['cells']:4d} cells  offset {r['offset_m']:+.3f}  horizontal "
                      f"{r['horizontal_m']:.3f} (shift {r['shift_m'][0]:+.1f}, {r['shift_m'][1]:+.1f})  "
                      f"rest {r['rest_m']:.3f}")  # fmt: skip
        for k in total:
            total[k] += d["_sq"][k]
        cells += d["cells"]
    if cells:
        print(
            "all own maps: "
            + ", ".join(f"{k} {np.sqrt(max(v, 0.0) / cells):.3f} m" for k, v in total.items())
        )
    print(f"mission: map_elevation_rmse_m {summary.get('map_elevation_rmse_m')} "
          f"({summary.get('map_elevation_cells')} cells), map_cross_scout_rms_m "
          f"{summary.get('map_cross_scout_rms_m')}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
