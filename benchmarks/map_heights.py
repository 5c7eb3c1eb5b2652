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

Per pair of scouts with shared cells, their disagreement (what `map_cross_scout_rms_m` pools) is split the same
way along the first scout's walk: the part in `--segment` means (their datums apart) and the rest (placement,
the cell's own footholds); and how much of their error against the terrain they share (the correlation of
the two errors' segment means, and the RMS of their mean: what no tie between them can take off).

`--fleet` asks what a fleet datum in hindsight would take off (the idea of a map server re-levelling each
scout's cells): per scout an offset every `--segment` m of its walk (linear between knots, prior σ the cells'
stated vertical σ, a `--fleet-walk` m/√m random walk between knots), solved jointly by least squares over every
pair's shared cells (each difference σ `--fleet-pair` m, every `--fleet-corr` cells one independent read: the
placement's share of a cell's difference holds over metres); each own map re-levelled by its offsets, then the
cross-scout RMS and the σ-weighted merge of the own maps (an approximation of the server's plane fits) before
and after. Inputs are what the scouts published; the truth only scores.

    python benchmarks/map_heights.py /tmp/run                  # a `psrmap mission --run-dir /tmp/run` folder
    python benchmarks/map_heights.py /tmp/run --segment 20 --quiet
    python benchmarks/map_heights.py /tmp/run --quiet --fleet
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from protocol.layers import layer_derived
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


def _cells(run: Path, scout: str) -> dict[tuple[int, int], tuple[float, float, float]]:
    """The scout's own map per cell (ix, iy) -> (height, centre x, centre y) [m]."""
    g = read_npz(run / f"{scout}_local.npz")
    h = grid_height(g)
    if h is None:
        return {}
    ok = (np.nan_to_num(g.layers["elevation"]["n"]) > 0) & np.isfinite(h)
    iy, ix = np.nonzero(ok)
    return {
        (g.ix0 + int(i), g.iy0 + int(j)): (
            float(h[j, i]),
            g.x0 + (g.ix0 + i + 0.5) * g.res,
            g.y0 + (g.iy0 + j + 0.5) * g.res,
        )
        for i, j in zip(ix, iy, strict=True)
    }


def cross_decompose(
    run: Path, a: str, b: str, summary: dict, terrain: Terrain, segment_m: float
) -> dict | None:
    """Scouts a and b over their shared cells: RMS difference = datum (segment means along a's walk) ⊕ rest;
    their errors' shared part (correlation of the segment means, RMS of the two maps' mean error)."""
    ca, cb = _cells(run, a), _cells(run, b)
    shared = sorted(ca.keys() & cb.keys())
    if len(shared) < 3:
        return None
    cx = np.array([ca[k][1] for k in shared])
    cy = np.array([ca[k][2] for k in shared])
    t = terrain.height(cx, cy)
    ea = np.array([ca[k][0] for k in shared]) - t
    eb = np.array([cb[k][0] for k in shared]) - t
    path = np.asarray(summary["scouts"][a]["path_estimate"], dtype=float)
    s = np.r_[0.0, np.cumsum(np.hypot(np.diff(path[:, 1]), np.diff(path[:, 2])))]
    near = np.argmin((cx[:, None] - path[None, :, 1]) ** 2 + (cy[:, None] - path[None, :, 2]) ** 2, axis=1)
    seg = np.floor(s[near] / segment_m).astype(int)
    d = ea - eb
    smooth = np.zeros_like(d)
    ma, mb = [], []
    for q in np.unique(seg):
        m = seg == q
        smooth[m] = d[m].mean()
        ma.append(ea[m].mean())
        mb.append(eb[m].mean())
    corr = float(np.corrcoef(ma, mb)[0, 1]) if len(ma) > 2 else float("nan")
    r = lambda v: round(float(np.sqrt(np.mean(np.square(v)))), 3)  # noqa: E731
    return {"cells": len(shared), "rms_diff_m": r(d), "datum_m": r(smooth), "rest_m": r(d - smooth),
            "err_corr": round(corr, 2), "err_a_m": r(ea), "err_b_m": r(eb), "err_mean_m": r((ea + eb) / 2)}  # fmt: skip


def _own(run: Path, scout: str, path_estimate: list, terrain: Terrain) -> dict:
    """The scout's own cells: keys (ix, iy), height, stated vertical σ, distance walked at the nearest point of
    its estimated path, and the terrain there (scoring only)."""
    g = read_npz(run / f"{scout}_local.npz")
    h = grid_height(g)
    assert h is not None
    sig = (
        layer_derived("height", "sigma", g.layers["height"])
        if "height" in g.layers
        else np.full(h.shape, 0.1)
    )
    ok = (np.nan_to_num(g.layers["elevation"]["n"]) > 0) & np.isfinite(h)
    iy, ix = np.nonzero(ok)
    cx = g.x0 + (g.ix0 + ix + 0.5) * g.res
    cy = g.y0 + (g.iy0 + iy + 0.5) * g.res
    path = np.asarray(path_estimate, dtype=float)
    s = np.r_[0.0, np.cumsum(np.hypot(np.diff(path[:, 1]), np.diff(path[:, 2])))]
    near = np.argmin((cx[:, None] - path[None, :, 1]) ** 2 + (cy[:, None] - path[None, :, 2]) ** 2, axis=1)
    keys = list(zip((g.ix0 + ix).tolist(), (g.iy0 + iy).tolist(), strict=True))
    return {"keys": {k: j for j, k in enumerate(keys)}, "h": h[iy, ix], "sig": np.nan_to_num(sig[iy, ix], nan=0.3),
            "s": s[near], "t": terrain.height(cx, cy), "walked": float(s[-1])}  # fmt: skip


def fleet_hindsight(run: Path, summary: dict, terrain: Terrain, knot_m: float, walk: float, pair: float,
                    corr: float) -> dict:  # fmt: skip
    """`--fleet` (module docstring): per scout (own RMSE before, after), cross-scout RMS and the merged own maps'
    RMSE before and after the joint re-levelling."""
    own = {k: _own(run, k, v["path_estimate"], terrain) for k, v in summary["scouts"].items()
           if "path_estimate" in v and (run / f"{k}_local.npz").is_file()}  # fmt: skip
    ids = list(own)
    at, n = {}, 0
    for k in ids:
        m = int(np.ceil(own[k]["walked"] / knot_m)) + 1
        at[k], n = (n, m), n + m

    def hat(k: str, s: np.ndarray) -> np.ndarray:
        o, m = at[k]
        u = np.clip(s / knot_m, 0.0, m - 1 - 1e-9)
        i = np.minimum(u.astype(int), m - 2)
        rows = np.zeros((len(s), n))
        rows[np.arange(len(s)), o + i] = 1.0 - (u - i)
        rows[np.arange(len(s)), o + i + 1] = u - i
        return rows

    rows, rhs, wts = [], [], []
    for k in ids:
        o, m = at[k]
        for j in range(m):  # each knot's prior: the stated σ of its cells
            near = np.abs(own[k]["s"] - j * knot_m) < knot_m
            sig = float(np.median(own[k]["sig"][near])) if near.any() else 0.3
            rows.append(np.eye(n)[o + j])
            rhs.append(0.0)
            wts.append(1.0 / max(sig, 0.02) ** 2)
        for j in range(m - 1):
            rows.append(np.eye(n)[o + j + 1] - np.eye(n)[o + j])
            rhs.append(0.0)
            wts.append(1.0 / (walk**2 * knot_m))
    A, y, w = np.array(rows), np.array(rhs), np.array(wts)
    pairs = []
    for i, a in enumerate(ids):
        for b in ids[i + 1 :]:
            shared = sorted(own[a]["keys"].keys() & own[b]["keys"].keys())
            if len(shared) < 3:
                continue
            ja = np.array([own[a]["keys"][c] for c in shared])
            jb = np.array([own[b]["keys"][c] for c in shared])
            pairs.append((a, b, ja, jb))
            A = np.vstack([A, hat(a, own[a]["s"][ja]) - hat(b, own[b]["s"][jb])])
            y = np.r_[y, own[a]["h"][ja] - own[b]["h"][jb]]
            w = np.r_[w, np.full(len(shared), 1.0 / (pair**2 * corr))]
    x = np.linalg.solve(A.T @ (w[:, None] * A), A.T @ (w * y))
    after = {k: own[k]["h"] - hat(k, own[k]["s"]) @ x for k in ids}
    before = {k: own[k]["h"] for k in ids}
    r = lambda v: round(float(np.sqrt(np.mean(np.square(v)))), 4)  # noqa: E731

    def cross(H: dict) -> float | None:
        d = [H[a][ja] - H[b][jb] for a, b, ja, jb in pairs]
        return r(np.concatenate(d)) if d else None

    def merged(H: dict) -> float:
        acc: dict = {}
        for k in ids:
            for c, j in own[k]["keys"].items():
                q = acc.setdefault(c, [0.0, 0.0, own[k]["t"][j]])
                wt = 1.0 / max(own[k]["sig"][j], 0.02) ** 2
                q[0] += wt * H[k][j]
                q[1] += wt
        return r([q[0] / q[1] - q[2] for q in acc.values()])

    return {"own": {k: (r(before[k] - own[k]["t"]), r(after[k] - own[k]["t"])) for k in ids},
            "cross": (cross(before), cross(after)), "merged": (merged(before), merged(after))}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path, help="a mission's run folder (summary.json, <scout>_local.npz)")
    p.add_argument("--segment", type=float, default=10.0, help="segment of walk [m] (default 10)")
    p.add_argument(
        "--shift", type=float, default=3.0, help="largest horizontal shift searched [m] (default 3)"
    )
    p.add_argument("--quiet", action="store_true", help="per scout only, no segments")
    p.add_argument("--fleet", action="store_true", help="what a joint fleet datum in hindsight takes off")
    p.add_argument("--fleet-walk", type=float, default=0.03, help="offsets' random walk [m/√m] (0.03)")
    p.add_argument(
        "--fleet-pair", type=float, default=0.07, help="σ of a shared cell's difference [m] (0.07)"
    )
    p.add_argument("--fleet-corr", type=float, default=5.0, help="shared cells per independent read (5)")
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
    scouts = [k for k, v in summary["scouts"].items() if (args.run / f"{k}_local.npz").is_file()]
    for i, a in enumerate(scouts):
        for b in scouts[i + 1 :]:
            x = cross_decompose(args.run, a, b, summary, terrain, args.segment)
            if x is None:
                continue
            print(f"{a}-{b}: {x['cells']} shared cells, RMS diff {x['rms_diff_m']:.3f} m = datum "
                  f"{x['datum_m']:.3f} ⊕ rest {x['rest_m']:.3f} m; against the terrain {x['err_a_m']:.3f} / "
                  f"{x['err_b_m']:.3f} m, their mean {x['err_mean_m']:.3f} m, segment means correlated "
                  f"{x['err_corr']:+.2f}")  # fmt: skip
    if args.fleet:
        f = fleet_hindsight(args.run, summary, terrain, args.segment, args.fleet_walk, args.fleet_pair,
                            args.fleet_corr)  # fmt: skip
        print("fleet datum in hindsight: own maps " + ", ".join(f"{k} {a:.3f} -> {b:.3f}" for k, (a, b) in
              f["own"].items()) + f"; cross-scout {f['cross'][0]} -> {f['cross'][1]}; merged own maps "
              f"{f['merged'][0]:.4f} -> {f['merged'][1]:.4f} m")  # fmt: skip
    print(f"mission: map_elevation_rmse_m {summary.get('map_elevation_rmse_m')} "
          f"({summary.get('map_elevation_cells')} cells), map_cross_scout_rms_m "
          f"{summary.get('map_cross_scout_rms_m')}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
