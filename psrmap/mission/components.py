"""What the mission gives each component: a scout's `ScoutConfig` from the mission's config, and the plan
and route comparison run as planner components on the shared map.
"""

from __future__ import annotations

import dataclasses
from multiprocessing.context import SpawnContext
from pathlib import Path
from typing import Any, cast

import numpy as np

from consumer_planner.component import CompareConfig, MapSource, PlanConfig, compare, plan
from consumer_planner.costs import CostConfig, parse_weights
from psrmap.mission.config import MissionConfig, ScoutPlan
from psrmap.mission.processes import spawn
from scout_agent.component import ScoutConfig
from scout_agent.mapping import LinkConfig
from scout_agent.run import ScoutRunConfig

__all__ = ["plan_and_compare", "scout_config", "scout_sensor_seed"]


def scout_sensor_seed(seed: int, index: int) -> int | None:
    """The seed of the `index`-th scout's own errors (sensors, launch survey) in a mission of terrain `seed`:
    None for the first scout (the terrain seed, as a single `psrmap evaluate` walk of that seed), for every
    other one an independent stream derived from (seed, index) — scouts built and surveyed one by one share
    no error (`psrmap scout --sensor-seed` reproduces one by hand)."""
    if index == 0:
        return None
    return int(np.random.SeedSequence([seed, index, 0x5EED]).generate_state(1)[0])


def scout_config(
    cfg: MissionConfig, s: ScoutPlan, endpoint: str, run_dir: Path, zenoh_file: str | None
) -> ScoutConfig:
    """The ScoutConfig of one of the mission's scouts."""
    lunar = cfg.scene == "lunar"
    run = ScoutRunConfig(
        scene=cfg.scene,
        slope_deg=15.0 if lunar else cfg.slope,
        seed=cfg.seed if lunar else 0,
        sensor_seed=scout_sensor_seed(cfg.seed if lunar else 0, [p.id for p in cfg.scouts].index(s.id)),
        field_m=cfg.field_m if lunar else 20.0,
        start=tuple(s.start) if lunar else None,
        goal=tuple(s.goal) if lunar else None,  # type: ignore[arg-type]
        via=tuple(tuple(v) for v in s.via) if lunar else (),  # type: ignore[misc]
        speed=cfg.speed,
        sim_seconds=cfg.sim_seconds,
        slippery_patches=cfg.slippery_patches if lunar else 0,
        holdable_patches=cfg.holdable_patches,
        scout_id=s.id,
    )
    link = LinkConfig(cfg.map, (endpoint,), str(run_dir / f"{s.id}_outbox.db"), zenoh_config=zenoh_file)
    return ScoutConfig(
        run=run,
        res=cfg.res,
        delta_hz=cfg.rate_hz,
        link=link,
        save_map=str(run_dir / f"{s.id}_local.npz"),
        rrd=str(run_dir / "recordings" / f"{s.id}.rrd") if cfg.rrd else None,
        rrd_terrain=False,  # the terrain is in the mission's own recording, once
    )


def plan_and_compare(
    ctx: SpawnContext,
    cfg: MissionConfig,
    endpoint: str,
    run_dir: Path,
    env: dict[str, str],
    creds: str | None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The plan and the route comparison, each a planner component in its own process: their JSON summaries
    (or {"error": why})."""
    source = MapSource(map_id=cfg.map, connect=(endpoint,), zenoh_config=creds)
    cost = dataclasses.replace(CostConfig(), weights=parse_weights(",".join(f"{k}={v:g}" for k, v in cfg.weights.items())),
                               unknown=cast(Any, cfg.unknown))  # fmt: skip
    rrd = str(run_dir / "recordings" / "planner.rrd") if cfg.rrd else None
    p = spawn(ctx, "plan", plan, PlanConfig(source, cfg.plan_from, cfg.plan_to, cost, rrd=rrd), run_dir, env)
    kind, res = p.result(timeout=300)
    plan_json = res.to_json() if kind == "ok" else {"error": f"plan failed ({res}); see {p.log}"}
    # the comparison reads the slip layer as the map holds it (no spread): the paper's table of trajectories
    routes = [(s.id, tuple(tuple(pt) for pt in s.route())) for s in cfg.scouts]
    if plan_json.get("path"):
        routes.append(("planned", tuple((float(x), float(y)) for x, y in cast(list, plan_json["path"]))))
    cmp_cfg = CompareConfig(source, tuple(routes), dataclasses.replace(cost, slip_spread_m=0.0))  # type: ignore[arg-type]
    c = spawn(ctx, "compare", compare, cmp_cfg, run_dir, env)
    kind, res = c.result(timeout=300)
    comparison = res.to_json() if kind == "ok" else {"error": f"compare failed ({res}); see {c.log}"}
    return plan_json, comparison
