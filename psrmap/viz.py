"""The mission's own Rerun recording: terrain mesh, friction ground truth, routes, the layers' legend, and
the default blueprint.

Every process of a mission (server, scouts, planner) writes its own .rrd with the same application and
recording id (`PSRMAP_RECORDING_ID`); this one adds the context they share (logged once, static) and the
layout the viewer opens with. `psrmap mission` merges them all into `mission.rrd` and compacts it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from psrmap.mission.config import MissionConfig
from psrmap_common.recording import TIMELINE, legend_markdown, open_stream, scout_color
from scout_agent.run import ScoutRunConfig, build_world
from scout_agent.viz import SERIES, log_friction, log_terrain

MAP_LAYERS = ("elevation", "slip", "cot", "giim", "giam", "contacts")
PER_SCOUT_SERIES = ("joint_torque_nm",)  # 12 series per scout: one plot per scout, not one for all


def _top_down(centre: Sequence[float], span: float) -> rrb.EyeControls3D:
    """Straight down on `centre`, north (+y) up and east (+x) right: a map view."""
    cx, cy = centre
    return rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=[cx, cy, 1.2 * span],
        look_target=[cx, cy, 0.0],
        eye_up=[0.0, 1.0, 0.0],
    )


def default_blueprint(
    scout_ids: Sequence[str], centre: Sequence[float] = (10.0, 10.0), span: float = 25.0
) -> rrb.Blueprint:
    """The mission in 3-D (terrain, scouts, slips, routes, plans) beside a top-down view per shared layer
    (with the scouts' true trajectories and the plans over it) and the legend of their colour scales, the
    scouts' time series one plot per unit, the server's counters and the plans' breakdown table; the time
    panel on `sim_time`, the timeline every process logs on."""
    trails = [f"world/scouts/{sid}/trajectory" for sid in scout_ids]
    tabs = {name: f"map/{name}/**" for name in MAP_LAYERS} | {
        "counts": "map/counts/**",
        "planner cost": "map/cost",
    }
    layers: list[rrb.Spatial3DView | rrb.TextDocumentView] = [
        rrb.Spatial3DView(
            name=name,
            origin="/",
            contents=[entities, "plans/**", *trails],
            eye_controls=_top_down(centre, span),
        )
        for name, entities in tabs.items()
    ]
    layers.append(rrb.TextDocumentView(name="legend", origin="map/legend"))
    plots: list[rrb.TimeSeriesView] = []
    for group, (title, _) in SERIES.items():
        paths = [f"world/scouts/{sid}/series/{group}" for sid in scout_ids]
        if group in PER_SCOUT_SERIES:
            plots += [
                rrb.TimeSeriesView(name=f"{sid} {title}", origin="/", contents=[p])
                for sid, p in zip(scout_ids, paths, strict=True)
            ]
        else:
            plots.append(rrb.TimeSeriesView(name=title, origin="/", contents=paths))
    plots.append(rrb.TimeSeriesView(name="map server [cells, version]", origin="map/status"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="mission", origin="/", contents=["world/**", "plans/**"]),
            rrb.Vertical(
                rrb.Tabs(*layers, name="shared map"),
                rrb.Tabs(*plots, name="scouts"),
                rrb.TextDocumentView(name="plan breakdown", origin="plans/breakdown"),
                row_shares=[3, 2, 1],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=TIMELINE),
        collapse_panels=True,
    )


def log_mission_context(cfg: MissionConfig, path: Path, recording_id: str) -> None:
    """Write `path`: the terrain as a mesh, the friction patches, the routes, the layers' legend and the
    default blueprint, all static (the scouts of a mission do not log the terrain again)."""
    rec = open_stream(str(path), explicit_id=recording_id)
    world = build_world(
        ScoutRunConfig(
            scene=cfg.scene,
            slope_deg=cfg.slope,
            seed=cfg.seed,
            slippery_patches=cfg.slippery_patches if cfg.scene == "lunar" else 0,
        )
    )
    log_terrain(rec, world.terrain)
    log_friction(rec, world.friction, world.terrain)
    xs, ys = [], []
    for s in cfg.scouts:
        route = s.route()
        pts = [[x, y, float(world.terrain.height(x, y)) + 0.05] for x, y in route]
        rec.log(
            f"world/routes/{s.id}",
            rr.LineStrips3D([pts], colors=[scout_color(s.id)], radii=0.02, labels=[f"{s.id} route"]),
            static=True,
        )
        xs += [p[0] for p in route]
        ys += [p[1] for p in route]
    rec.log("map/legend", rr.TextDocument(legend_markdown(), media_type=rr.MediaType.MARKDOWN), static=True)
    xs += [cfg.plan_from[0], cfg.plan_to[0]]
    ys += [cfg.plan_from[1], cfg.plan_to[1]]
    centre = ((min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2)
    span = max(max(xs) - min(xs), max(ys) - min(ys)) + 6.0
    rec.send_blueprint(default_blueprint([s.id for s in cfg.scouts], centre, span))
    rec.flush()
    rec.disconnect()
