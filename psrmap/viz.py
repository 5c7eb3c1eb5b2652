"""The mission's own Rerun recording: terrain mesh, friction ground truth, and the default blueprint.

Every process of a mission (server, scouts, planner) writes its own .rrd with the same application and
recording id (`PSRMAP_RECORDING_ID`); this one adds the context they share and the layout the viewer opens
with. `psrmap mission` merges them all into `mission.rrd`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import rerun as rr
import rerun.blueprint as rrb

APP_ID = "psrmap"


MAP_LAYERS = ("elevation", "slip", "cot", "giim", "giam", "contacts")


def default_blueprint(scout_ids: list[str]) -> rrb.Blueprint:
    """The mission in 3-D (terrain, scouts, slips, routes, plans) beside one top-down view per shared layer
    (each with the plans over it), the scouts' estimates and signals, and the plans' breakdowns."""
    estimates = [
        rrb.TimeSeriesView(name=f"{sid} estimates", origin=f"world/scouts/{sid}/estimates")
        for sid in scout_ids
    ]
    signals = [
        rrb.TimeSeriesView(name=f"{sid} signals", origin=f"world/scouts/{sid}/signals") for sid in scout_ids
    ]
    layers = [
        rrb.Spatial3DView(name=name, origin="/", contents=[f"map/{name}/**", "plans/**"])
        for name in MAP_LAYERS
    ]
    layers.append(rrb.Spatial3DView(name="counts", origin="/", contents=["map/counts/**", "plans/**"]))
    layers.append(rrb.Spatial3DView(name="planner cost", origin="/", contents=["map/cost/**", "plans/**"]))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="mission", origin="/", contents=["world/**", "plans/**"]),
            rrb.Vertical(
                rrb.Tabs(*layers, name="shared map"),
                rrb.Tabs(*estimates, *signals, rrb.TimeSeriesView(name="server", origin="map/status")),
                rrb.TextDocumentView(name="plan breakdown", origin="plans"),
                row_shares=[3, 2, 1],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def log_mission_context(cfg: Any, path: Path, recording_id: str) -> None:
    """Write `path`: the terrain as a mesh, the friction patches, the routes, and the default blueprint."""
    from scout_agent.run import ScoutRunConfig, build_world
    from scout_agent.viz import log_friction, log_terrain

    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.save(str(path))
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
    for s in cfg.scouts:
        pts = [[x, y, float(world.terrain.height(x, y)) + 0.05] for x, y in s.route()]
        rec.log(
            f"world/routes/{s.id}", rr.LineStrips3D([pts], colors=[255, 255, 255], radii=0.02), static=True
        )
    rec.send_blueprint(default_blueprint([s.id for s in cfg.scouts]))
    rec.flush()
    rec.disconnect()
