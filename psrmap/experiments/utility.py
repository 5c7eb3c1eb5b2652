"""`psrmap experiment utility` (new): does a map made by some scouts predict what another robot experiences?

Per terrain seed: scouts walk part of the lunar field (`--scouts`, default the west and east routes — the
same runs as `lunar`'s first run, shared through the cache); their maps are merged (the server's rule) and
read as the planner's `LayerGrid`; the planner picks the cheapest route from `--from` to `--to` across it
(`--unknown infer` by default: unmapped cells near mapped ones are filled by the paper's eq. 17, farther
ones are impassable; `--slip-spread M`, default the planner's 0.8 m: each cell's slip term reads the
largest slip rate within M metres, 0 = the raw slip layer). A fresh robot (a new noise seed, its own start offset) then walks the planned route
and the straight one, mapping as it goes.

Reported per route: what the scouts' map predicted (planner breakdown: mean CoT, expected slip events, mean
and minimum GIIM / GIAM, unknown share) against what the fresh robot experienced (whole-walk CoT, energy,
ground-truth and detected slips, GIIM / GIAM over its own map, fall), the per-cell agreement of the two maps
along the route, and whether the planned route beat the straight one in what the robot experienced.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from psrmap.experiments import lunar, maps, utility_scores
from psrmap.experiments.common import MAP_RES, RunPool, RunSpec, jitter_start
from psrmap.experiments.config import ExperimentConfig, ExperimentError
from psrmap_mapcore import LayerGrid

__all__ = [
    "add_arguments",
    "experienced",
    "fresh_specs",
    "plan",
    "run",
    "scout_specs",
    "simplify",
    "slip_spread_m",
    "specs",
]

NAME = "utility"
DEFAULT_SEEDS = "0,1,2,3,4"
DEFAULT_RUNS = 1
FRESH_NOISE_OFFSET = 50  # fresh robot's noise seed = seed·100 + 50 + run (scouts use seed·100 + run)


def _point(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a point; give x,y in metres") from None
    return x, y


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("utility")
    g.add_argument("--scouts", default="west,east", help="lunar routes the scouts map (default west,east)")
    g.add_argument(
        "--from",
        dest="utility_from",
        type=_point,
        default=(1.5, 1.5),
        metavar="X,Y",
        help="start of the planned and straight routes (default 1.5,1.5)",
    )
    g.add_argument(
        "--to",
        dest="utility_to",
        type=_point,
        default=(18.5, 18.5),
        metavar="X,Y",
        help="goal of the planned and straight routes (default 18.5,18.5)",
    )
    g.add_argument("--unknown", default="infer", help="planner's unknown-cell policy (default infer)")
    g.add_argument(
        "--weights", default="", metavar="NAME=W,...", help="planner cost weights (default: planner's)"
    )
    g.add_argument(
        "--slip-spread",
        "--inflate-slip",  # the experiment's option before the planner had it
        dest="slip_spread",
        type=_spread,
        default=None,
        metavar="M",
        help="planner's slip spread: each cell's slip term reads the largest slip rate within M metres, "
        "0 <= M (default: the planner's, 0.8; 0 = the raw slip layer)",
    )


def _spread(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (v >= 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text!r}: give a radius in metres, 0 <= M < inf (0 = off)")
    return v


def slip_spread_m(cfg: ExperimentConfig) -> float:
    """The planner's slip spread radius [m] this run uses (`--slip-spread`, else the planner default)."""
    from consumer_planner.costs import CostConfig

    v = getattr(cfg, "slip_spread", None)
    return CostConfig.slip_spread_m if v is None else float(v)


def _scouts(cfg: ExperimentConfig) -> tuple[str, ...]:
    from scout_agent.sim.terrain import LUNAR_ROUTES

    names = tuple(s.strip() for s in cfg.scouts.split(",") if s.strip())
    bad = [n for n in names if n not in LUNAR_ROUTES]
    if bad or not names:
        raise ExperimentError(f"--scouts {cfg.scouts!r}; routes: {', '.join(LUNAR_ROUTES)}")
    return names


def scout_specs(cfg: ExperimentConfig, seed: int) -> list[RunSpec]:
    return lunar.route_specs(cfg, seed, _scouts(cfg), runs=1)


def specs(cfg: ExperimentConfig) -> list[RunSpec]:
    """The scouting runs (the fresh robot's runs depend on the plan and come later)."""
    return [s for seed in cfg.seeds for s in scout_specs(cfg, seed)]


def simplify(points: np.ndarray, tol: float) -> np.ndarray:
    """Ramer–Douglas–Peucker: the polyline's vertices that keep it within `tol` [m]."""
    pts = np.asarray(points, float)
    if len(pts) < 3:
        return pts
    a, b = pts[0], pts[-1]
    ab = b - a
    n = float(np.hypot(*ab))
    d = (
        np.abs(ab[0] * (pts[:, 1] - a[1]) - ab[1] * (pts[:, 0] - a[0])) / n
        if n > 1e-12
        else np.hypot(*(pts - a).T)
    )
    i = int(np.argmax(d))
    if d[i] <= tol:
        return np.array([a, b])
    return np.vstack([simplify(pts[: i + 1], tol)[:-1], simplify(pts[i:], tol)])


def _cost_config(cfg: ExperimentConfig, unknown: str | None = None):
    from consumer_planner.costs import UNKNOWN_POLICIES, CostConfig, parse_weights

    policy: Any = unknown or cfg.unknown  # one of UNKNOWN_POLICIES, checked here
    if policy not in UNKNOWN_POLICIES:
        raise ExperimentError(f"--unknown {policy!r}; policies: {', '.join(UNKNOWN_POLICIES)}")
    return replace(
        CostConfig(), weights=parse_weights(cfg.weights), unknown=policy, slip_spread_m=slip_spread_m(cfg)
    )


def plan(cfg: ExperimentConfig, seed: int, scouts: list[dict], out_dir: Path) -> dict[str, Any]:
    from consumer_planner.compare import evaluate_route, plan_route
    from consumer_planner.costs import build_costs
    from consumer_planner.errors import PlannerError

    grid = maps.merged_grid(scouts, out_dir / f"scouts_seed{seed}.npz", f"scouts{seed}")
    costs = build_costs(grid, _cost_config(cfg))
    start, goal = tuple(cfg.utility_from), tuple(cfg.utility_to)
    out: dict[str, Any] = {"grid": grid, "costs": costs}
    try:
        route = plan_route(grid, costs, start, goal, name="planned")
    except PlannerError as exc:
        route, out["error"] = None, str(exc)
    straight = [start, goal]
    try:
        out["straight_predicted"] = evaluate_route(grid, costs, straight, name="straight").breakdown.as_dict()
        pen = build_costs(grid, _cost_config(cfg, "penalty"))
        out["straight_predicted_penalty"] = evaluate_route(
            grid, pen, straight, name="straight"
        ).breakdown.as_dict()
    except PlannerError as exc:
        out["straight_error"] = str(exc)
    if route is None:
        out.setdefault(
            "error", f"no passable route from {start} to {goal} on the scouts' map (unknown={cfg.unknown})"
        )
        return out
    wps = simplify(route.path, 0.15)
    wps[0], wps[-1] = start, goal
    out["route"] = route
    out["waypoints"] = [tuple(round(float(v), 3) for v in p) for p in wps]
    out["planned_predicted"] = route.breakdown.as_dict()
    return out


def fresh_specs(cfg: ExperimentConfig, seed: int, routes: dict[str, list]) -> list[RunSpec]:
    out = []
    for name, wps in routes.items():
        for r in range(cfg.runs):
            noise = seed * 100 + FRESH_NOISE_OFFSET + r
            out.append(
                RunSpec(
                    scene="lunar",
                    terrain_seed=seed,
                    noise_seed=noise,
                    waypoints=tuple(tuple(p) for p in wps),
                    start=jitter_start(wps[0], noise, 0.1, 0.1),
                    slippery_patches=cfg.slippery_patches,
                    sim_seconds=cfg.sim_seconds,
                    sensors=cfg.sensors,
                    launch=cfg.launch,
                    label=f"utility{seed}-{name}-n{noise}",
                )
            )
    return out


def experienced(cfg: ExperimentConfig, run: dict, waypoints: list) -> dict[str, Any]:
    """What the fresh robot lived through on one route, plus the planner's cost of that route on its map."""
    from consumer_planner.compare import evaluate_route
    from consumer_planner.costs import build_costs
    from consumer_planner.errors import PlannerError

    s, sc = run["summary"], run["scores"]
    cot = sc.get("cot_whole_run")
    out: dict[str, Any] = {
        "fell": s["fell"],
        "reached_goal": s["reached_goal"],
        "distance_m": s["distance_m"],
        "sim_seconds": s["sim_seconds"],
        "cot_whole_run": cot,
        "cot_whole_run_truth": s.get("cot_whole_run_truth"),  # simulator energy over the true path
        "cot_mean_cells": sc.get("cot_mean"),
        "energy_m": cot * s["distance_m"] if cot is not None else None,  # Σ E / (m g) [m]
        "gt_slips": sc.get("gt_slips"),
        "detected_slips": sc.get("slip_events"),
        "giim_mean": sc.get("giim_mean"),
        "giam_mean": sc.get("giam_mean"),
        "giim_worst": sc.get("giim_worst"),
        "giam_worst": sc.get("giam_worst"),
        "giim_paper_mean": sc.get("giim_paper_mean"),
        "giam_paper_mean": sc.get("giam_paper_mean"),
        "nonfoot_contact_ticks": s.get("nonfoot_contact_ticks"),
    }
    own = maps.merged_local_map([run])
    for layer in ("giim", "giam"):  # the worst cell mean, comparable with the planner's min over cells
        c = own.cells(layer)
        out[f"{layer}_min_cell"] = float(np.min(c["sum"] / c["n"])) if len(c["ix"]) else None
    b = own.bounds()
    if b is not None:
        ix0, iy0, ix1, iy1 = b
        region = own.region(ix0 - 2, iy0 - 2, ix1 + 2, iy1 + 2)
        grid = LayerGrid("own", MAP_RES, ix0 - 2, iy0 - 2, iy1 - iy0 + 5, ix1 - ix0 + 5, region)
        try:
            costs = build_costs(grid, _cost_config(cfg, "penalty"))
            bd = evaluate_route(grid, costs, waypoints, name="walked").breakdown.as_dict()
            out["cost_on_own_map"] = bd["cost"]
            out["own_map_unknown_fraction"] = bd["unknown_fraction"]
        except PlannerError as exc:
            out["cost_on_own_map_error"] = str(exc)
    return out


def run(cfg: ExperimentConfig, pool: RunPool, out_dir: Path) -> dict[str, Any]:
    from psrmap.experiments import plots
    from scout_agent.sim.terrain import LunarConfig, make_lunar

    scouting = pool.run(specs(cfg), desc=f"{NAME} scouts")
    per_seed: dict[str, Any] = {}
    plans: dict[int, dict] = {}
    fresh: list[RunSpec] = []
    tags: list[tuple[int, str]] = []  # (seed, route name) of each fresh spec
    for seed in cfg.seeds:
        mine = [r for r in scouting if r["spec"]["terrain_seed"] == seed]
        p = plan(cfg, seed, mine, out_dir)
        plans[seed] = p
        if "waypoints" in p:
            for name, wps in (
                ("planned", p["waypoints"]),
                ("straight", [cfg.utility_from, cfg.utility_to]),
            ):
                new = fresh_specs(cfg, seed, {name: wps})
                fresh += new
                tags += [(seed, name)] * len(new)
    walked = pool.run(fresh, desc=f"{NAME} fresh robot")  # same order as `fresh`
    figures: list[Path] = []
    for seed in cfg.seeds:
        p = plans[seed]
        entry: dict[str, Any] = {
            "scouts": [r["spec"]["label"] for r in scouting if r["spec"]["terrain_seed"] == seed],
            "predicted": {
                "planned": utility_scores.predicted(p.get("planned_predicted")),
                "straight": utility_scores.predicted(p.get("straight_predicted")),
                "straight_penalty_policy": utility_scores.predicted(p.get("straight_predicted_penalty")),
            },
        }
        if "error" in p:
            entry["error"] = p["error"]
            per_seed[str(seed)] = entry
            continue
        entry["planned_waypoints"] = p["waypoints"]
        entry["planned_is_straight"] = len(p["waypoints"]) == 2
        scouts_local = maps.merged_local_map([r for r in scouting if r["spec"]["terrain_seed"] == seed])
        runs_by_route: dict[str, list[dict]] = {"planned": [], "straight": []}
        for (s_, name), r in zip(tags, walked, strict=True):
            if s_ == seed:
                runs_by_route[name].append(r)
        exp: dict[str, Any] = {}
        agree: dict[str, Any] = {}
        for name, rs in runs_by_route.items():
            wps = p["waypoints"] if name == "planned" else [cfg.utility_from, cfg.utility_to]
            rows = [experienced(cfg, r, wps) for r in rs]
            exp[name] = utility_scores.pool_rows(rows) if rows else None
            dense_path = np.array(_densify(wps, MAP_RES / 2))
            agree[name] = utility_scores.agreement(scouts_local, rs[0], dense_path) if rs else None
        entry["experienced"] = exp
        entry["map_agreement_along_route"] = agree
        entry["predicted_vs_felt"] = {
            name: utility_scores.predicted_vs_felt(entry["predicted"].get(name), exp.get(name))
            for name in ("planned", "straight")
        }
        entry["planned_beat_straight"] = (
            utility_scores.beat(exp["planned"], exp["straight"])
            if exp.get("planned") and exp.get("straight")
            else None
        )
        per_seed[str(seed)] = entry
        terrain = make_lunar(LunarConfig(seed=seed))
        fig = plots.utility_map(
            out_dir / f"utility_seed{seed}.png",
            seed,
            terrain,
            scouts_local,
            [r for r in scouting if r["spec"]["terrain_seed"] == seed],
            p["waypoints"],
            [cfg.utility_from, cfg.utility_to],
            runs_by_route,
        )
        if fig is not None:
            figures.append(fig)
    summary = utility_scores.summary(per_seed)
    bars = plots.utility_bars(out_dir / "utility_summary.png", per_seed)
    if bars is not None:
        figures.append(bars)
    return {
        "experiment": NAME,
        "protocol": {
            "seeds": list(cfg.seeds),
            "fresh_runs_per_route": cfg.runs,
            "scouts": list(_scouts(cfg)),
            "from": list(cfg.utility_from),
            "to": list(cfg.utility_to),
            "unknown": cfg.unknown,
            "weights": cfg.weights or "planner defaults",
            "slip_spread_m": slip_spread_m(cfg),
            "slippery_patches": cfg.slippery_patches,
            "fresh_noise_seed": f"seed·100 + {FRESH_NOISE_OFFSET} + run (scouts: seed·100)",
            "energy": "Σ E/(m·g) over the walk [m] = whole-walk CoT × distance",
            "sim_seconds_cap": cfg.sim_seconds,
            "scouts_sim_seconds_cap": lunar.scout_seconds(cfg),
        },
        "summary": summary,
        "per_seed": per_seed,
        "runs": [
            {
                "label": r["spec"]["label"],
                "key": r["key"],
                "fell": r["summary"]["fell"],
                "reached_goal": r["summary"]["reached_goal"],
                "worker_seconds": r["worker_seconds"],
            }
            for r in scouting + walked
        ],
        "figures": [f.name for f in figures if f is not None],
    }


def _densify(wps: list, step: float) -> list[tuple[float, float]]:
    pts: list[tuple[float, float]] = []
    for a, b in zip(wps[:-1], wps[1:], strict=True):
        a, b = np.asarray(a, float), np.asarray(b, float)
        n = max(1, int(math.ceil(np.hypot(*(b - a)) / step)))
        pts += [tuple(a + (b - a) * t) for t in np.arange(n) / n]
    pts.append(tuple(np.asarray(wps[-1], float)))
    return pts
