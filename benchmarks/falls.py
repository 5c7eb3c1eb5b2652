"""The falls matrix of issue 24: ramps α × patch μ around tan α × seeds, and lunar seeds × routes with
unholdable patches allowed, walked with the hazard control (after) and without it (before: the fixed trot and
friction cone, `--no-hazard-control`). One JSON line per walk, appended to OUT as each finishes (so a run cut
short keeps what it measured); `--summary` reads OUT and prints the table.

    python3 benchmarks/falls.py ramps --out runs/falls.jsonl [--workers 2] [--before] [--seeds 0,1]
    python3 benchmarks/falls.py lunar --out runs/falls.jsonl [--seeds 0-9] [--before]
    python3 benchmarks/falls.py lunar --out runs/fwd.jsonl --only after --pilot back_forward=true
    python3 benchmarks/falls.py --summary runs/falls.jsonl

Ramps: α ∈ {5, 10, 15, 20, 25}°, patch μ = tan α + {−0.1, −0.05, 0, +0.05, +0.1} (at least 0.02) over the middle
half of the down-ramp, two seeds (sensor noise + a few cm of start offset, `experiments.common.jitter_start`).
Per walk: fell, hazard stops (and whether the first lies within 1 m of the patch's edge), reached goal, gave up,
unholdable cells crossed (ground truth), slip precision / recall, CoT (estimate and truth).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import sys
import time
from dataclasses import fields, replace
from pathlib import Path

ANGLES = (5.0, 10.0, 15.0, 20.0, 25.0)
OFFSETS = (-0.1, -0.05, 0.0, 0.05, 0.1)
KEYS = ("fell", "fall_xy", "reached_goal", "gave_up", "hazard_stops", "detour_m", "unholdable_cells",
        "unholdable_cells_crossed", "slip_precision", "slip_recall", "gt_slips", "slip_events", "cot_whole_run",
        "cot_whole_run_truth", "distance_m", "sim_seconds", "wall_seconds")  # fmt: skip


def _jobs(kind: str, seeds: list[int], before: bool, angles=ANGLES, offsets=OFFSETS) -> list[dict]:
    modes = (True, False) if before else (True,)
    out = []
    for seed in seeds:
        if kind == "ramps":
            for d in offsets:
                for a in angles:
                    mu = round(max(0.02, math.tan(math.radians(a)) + d), 4)
                    out += [
                        {"kind": kind, "seed": seed, "slope": a, "offset": d, "mu": mu, "on": m}
                        for m in modes
                    ]
        else:
            for route in ("direct", "west", "east"):
                out += [{"kind": kind, "seed": seed, "route": route, "on": m} for m in modes]
    return out


def walk(job: dict) -> dict:
    from psrmap.experiments.common import jitter_start
    from scout_agent.evaluate import Evaluator
    from scout_agent.run import ScoutRunConfig, build_world, run_scout

    if job["kind"] == "ramps":
        cfg = ScoutRunConfig(scene="ramps", slope_deg=job["slope"], slippery_mu=job["mu"], seed=job["seed"],
                             start=jitter_start((0.6, 0.0), job["seed"]), hazard_control=job["on"])  # fmt: skip
    else:
        cfg = ScoutRunConfig(scene="lunar", seed=job["seed"], route=job["route"], slippery_patches=4,
                             hazard_control=job["on"])  # fmt: skip
    if job.get("pilot"):
        top = {k: v for k, v in job["pilot"].items() if "." not in k}
        sub = {
            part: replace(getattr(cfg.pilot, part), **{k.split(".", 1)[1]: v for k, v in job["pilot"].items()
                                                       if k.startswith(part + ".")})
            for part in ("senses", "gait", "friction")
        }  # fmt: skip
        cfg = replace(cfg, pilot=replace(cfg.pilot, **top, **sub))
    if job.get("controller"):
        cfg = replace(cfg, sim=replace(cfg.sim, controller=replace(cfg.sim.controller, **job["controller"])))
    world = build_world(cfg)
    ev = Evaluator(res=0.4)
    t0 = time.time()
    s = run_scout(cfg, on_tick=ev.on_tick, progress=False, world=world, on_hazard=ev.on_hazard)
    r = ev.result(world, cfg.friction_default)
    out = {**job, **{k: s.get(k, r.get(k)) for k in KEYS}, "wall_total_s": round(time.time() - t0, 1)}
    out["patches"] = [list(p) for p in world.friction.to_dict()["patches"]]
    stops = s["hazard_stops"]
    if stops and out["patches"]:
        x, y = stops[0]["x"], stops[0]["y"]
        out["first_stop_to_patch_edge_m"] = round(min(_edge_distance(x, y, p) for p in out["patches"]), 3)
    out["pilot_modes"] = s.get("pilot_modes")
    if s["fell"] and s["fall_xy"]:
        out["fall"] = _fall_context(world, s)
    return out


def _fall_context(world, s: dict) -> dict:
    """Where and when the scout fell, against ground truth: the pilot's mode then and since when, the last
    hazard stop before it, the terrain's slope and μ at the fall point, the nearest patch (inside: negative
    distance to its edge) and the distance from the planned route."""
    import numpy as np

    x, y = s["fall_xy"]
    t = s["sim_seconds"]
    modes = s.get("pilot_modes") or [[0.0, "walk"]]
    mode_t, mode = modes[-1]
    stops = [h for h in s["hazard_stops"] if h["t"] <= t]
    mu = float(world.friction.at(x, y))
    slope = float(world.terrain.slope_deg(x, y))
    patches = [list(p) for p in world.friction.to_dict()["patches"]]
    edge = [(_edge_distance(x, y, p), p) for p in patches]
    inside = [(d, p) for d, p in edge if p[0] <= x <= p[2] and p[1] <= y <= p[3]]
    wp = np.asarray(world.waypoints)[:, :2]
    route_d = min(_segment_distance(x, y, wp[i], wp[i + 1]) for i in range(len(wp) - 1))
    near = min(edge, key=lambda e: e[0]) if edge else None
    return {
        "t": t,
        "xy": [round(x, 3), round(y, 3)],
        "mode": mode,
        "mode_for_s": round(t - mode_t, 3),
        "last_stop": stops[-1] if stops else None,
        "since_last_stop_s": round(t - stops[-1]["t"], 3) if stops else None,
        "mu": round(mu, 3),
        "slope_deg": round(slope, 2),
        "holdable": bool(mu >= math.tan(math.radians(slope))),
        "in_patch": bool(inside),
        "patch_edge_m": round(near[0], 3) if near else None,
        "patch_mu": near[1][4] if near else None,
        "route_m": round(route_d, 3),
    }


def _segment_distance(x: float, y: float, a, b) -> float:
    ax, ay, bx, by = float(a[0]), float(a[1]), float(b[0]), float(b[1])
    dx, dy = bx - ax, by - ay
    u = max(0.0, min(1.0, ((x - ax) * dx + (y - ay) * dy) / max(dx * dx + dy * dy, 1e-12)))
    return math.hypot(x - ax - u * dx, y - ay - u * dy)


def _edge_distance(x: float, y: float, p: list[float]) -> float:
    """Distance [m] from (x, y) to the boundary of the rectangle p = (x0, y0, x1, y1, mu)."""
    x0, y0, x1, y1 = p[:4]
    dx = max(x0 - x, 0.0, x - x1)
    dy = max(y0 - y, 0.0, y - y1)
    if dx or dy:
        return math.hypot(dx, dy)
    return min(x - x0, x1 - x, y - y0, y1 - y)


def _key(r: dict) -> str:
    return json.dumps(
        {k: r[k] for k in r if k in ("kind", "seed", "slope", "mu", "route", "on")}, sort_keys=True
    )


def _done(out: Path) -> set[str]:
    if not out.exists():
        return set()
    return {_key(r) for r in map(json.loads, out.read_text().splitlines()) if r}


def summary(paths: list[Path]) -> dict:
    unique: dict[str, dict] = {}  # the same walk measured twice (two runs of this script): the first counts
    for path in paths:
        for line in path.read_text().splitlines():
            if line.strip():
                r = json.loads(line)
                unique.setdefault(_key(r), r)
    rows = list(unique.values())
    res: dict = {}
    for kind in ("ramps", "lunar"):
        for on in (True, False):
            rs = [r for r in rows if r["kind"] == kind and r["on"] == on]
            if not rs:
                continue
            tag = f"{kind}_{'after' if on else 'before'}"
            unhold = [r for r in rs if r.get("unholdable_cells_crossed") or _patch_unholdable(r)]
            stops = [r for r in unhold if r["hazard_stops"]]
            near = [r for r in stops if r.get("first_stop_to_patch_edge_m") is not None
                    and r["first_stop_to_patch_edge_m"] <= 1.0]  # fmt: skip
            prec = [r["slip_precision"] for r in rs if r["slip_precision"] is not None]
            rec = [
                r["slip_recall"]
                for r in rs
                if r["slip_recall"] is not None and r["slip_recall"] == r["slip_recall"]
            ]
            res[tag] = {
                "walks": len(rs),
                "falls": sum(r["fell"] for r in rs),
                "fell_at": [
                    (r.get("slope"), r.get("mu"), r.get("route"), r["seed"]) for r in rs if r["fell"]
                ],
                "reached_goal": sum(r["reached_goal"] for r in rs),
                "walks_with_hazard_stops": sum(bool(r["hazard_stops"]) for r in rs),
                "unholdable_walks": len(unhold),
                "unholdable_walks_stopped": len(stops),
                "first_stop_within_1m_of_edge": len(near),
                "unholdable_cells_crossed": sum(r.get("unholdable_cells_crossed") or 0 for r in rs),
                "slip_precision_mean": round(sum(prec) / len(prec), 3) if prec else None,
                "slip_recall_mean": round(sum(rec) / len(rec), 3) if rec else None,
            }
    # CoT on holdable ground: the same ramps walks (μ ≥ tan α + 0.05), after vs before, where both reached the goal
    pairs = {}
    for r in rows:
        if r["kind"] == "ramps" and r["offset"] >= 0.05 and r["reached_goal"] and r["cot_whole_run_truth"]:
            pairs.setdefault((r["slope"], r["offset"], r["seed"]), {})[r["on"]] = r["cot_whole_run_truth"]
    both = [(v[True], v[False]) for v in pairs.values() if True in v and False in v]
    if both:
        res["cot_truth_holdable_after_over_before"] = round(
            sum(a for a, _ in both) / sum(b for _, b in both), 4
        )
        res["cot_holdable_pairs"] = len(both)
    return res


def _patch_unholdable(r: dict) -> bool:
    return r["kind"] == "ramps" and r["mu"] < math.tan(math.radians(r["slope"]))


def _pilot_options(p: argparse.ArgumentParser, items: list[str], flag: str = "--pilot") -> dict:
    """{field: value} from FIELD=VALUE items naming scalar PilotConfig fields, the reflex's as senses.FIELD,
    the adaptive gait's as gait.FIELD or the friction estimate's as friction.FIELD (`--controller`: scalar
    ControllerConfig fields)."""
    from scout_agent.control.adaptation import GaitAdaptationConfig
    from scout_agent.control.controller import ControllerConfig
    from scout_agent.control.friction_estimate import FrictionEstimateConfig
    from scout_agent.control.pilot import PilotConfig
    from scout_agent.control.reflex import ReflexConfig

    cls = ControllerConfig if flag == "--controller" else PilotConfig
    scalar = {
        f.name for f in fields(cls) if isinstance(getattr(cls(), f.name), (bool, int, float, type(None)))
    }
    if cls is PilotConfig:
        scalar |= {f"senses.{f.name}" for f in fields(ReflexConfig)}
        scalar |= {f"gait.{f.name}" for f in fields(GaitAdaptationConfig)}
        scalar |= {f"friction.{f.name}" for f in fields(FrictionEstimateConfig)}
    out: dict = {}
    for item in items:
        name, eq, text = item.partition("=")
        if not eq or name not in scalar:
            p.error(f"{flag} {item!r}: give FIELD=VALUE with FIELD one of {', '.join(sorted(scalar))}")
        low = text.strip().lower()
        if low in ("true", "false", "none"):
            out[name] = {"true": True, "false": False, "none": None}[low]
            continue
        try:
            out[name] = int(text) if low.lstrip("-").isdigit() else float(text)
        except ValueError:
            p.error(f"{flag} {item!r}: VALUE must be true, false, none or a number")
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("kind", nargs="?", choices=("ramps", "lunar"))
    p.add_argument("--out", type=Path)
    p.add_argument("--seeds", default="0,1")
    p.add_argument("--before", action="store_true", help="also walk each case without the hazard control")
    p.add_argument(
        "--only", choices=("after", "before"), help="walk only with (after) or without (before) it"
    )
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--angles", default=",".join(f"{a:g}" for a in ANGLES), help="ramps: angles [deg]")
    p.add_argument(
        "--offsets", default=",".join(f"{d:g}" for d in OFFSETS), help="ramps: μ − tan α, in order"
    )
    p.add_argument(
        "--pilot",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="a PilotConfig field for the walks with the hazard control (bool, int, float or none; senses.F, gait.F "
        "and friction.F: the reflex's, adaptive gait's and friction estimate's), repeatable",
    )
    p.add_argument(
        "--controller",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="a scalar ControllerConfig field (the trot's contact handling) for every walk, repeatable",
    )
    p.add_argument("--summary", type=Path, nargs="+")
    a = p.parse_args()
    if a.summary:
        print(json.dumps(summary(a.summary), indent=1))
        return 0
    if a.kind is None or a.out is None:
        p.error("give KIND and --out, or --summary FILE")
    if "-" in a.seeds:
        lo, hi = (int(v) for v in a.seeds.split("-"))
        seeds = list(range(lo, hi + 1))
    else:
        seeds = [int(v) for v in a.seeds.split(",")]
    pilot = _pilot_options(p, a.pilot)
    done = _done(a.out)
    angles = tuple(float(v) for v in a.angles.split(","))
    offsets = tuple(float(v) for v in a.offsets.split(","))
    jobs = [j for j in _jobs(a.kind, seeds, a.before or a.only == "before", angles, offsets)
            if a.only is None or j["on"] == (a.only == "after")
            if _key(j) not in done]  # fmt: skip
    controller = _pilot_options(p, a.controller, "--controller")
    for j in jobs:
        if pilot and j["on"]:
            j["pilot"] = pilot
        if controller:
            j["controller"] = controller
    a.out.parent.mkdir(parents=True, exist_ok=True)
    with mp.get_context("spawn").Pool(a.workers, maxtasksperchild=4) as pool, a.out.open("a") as f:
        for r in pool.imap_unordered(walk, jobs):
            f.write(json.dumps(r) + "\n")
            f.flush()
            print(f"{r['kind']} seed {r['seed']} {r.get('slope', r.get('route'))} mu {r.get('mu')} "
                  f"on={r['on']}: fell={r['fell']} stops={len(r['hazard_stops'])} goal={r['reached_goal']}",
                  file=sys.stderr, flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
