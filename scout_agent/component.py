"""The scout as a component: `run(ScoutConfig) -> ScoutSummary`.

What `psrmap scout` does, as a function on a frozen config: build the world, walk it (`run.run_scout`)
with the estimators and the map deltas attached (`mapping.open_mapping`, publishing when `link` is set),
log to Rerun when asked, and return a typed summary. The CLI parses its options into a `ScoutConfig` and
calls this; the mission starts it in a spawned process and receives the `ScoutSummary` back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from psrmap_common.defaults import DEFAULT_DELTA_HZ, DEFAULT_RES_M
from psrmap_common.recording import ViewerUnavailable, use_viewer, viewer_url
from psrmap_common.trust import load_trust
from scout_agent.control.reflex import Felt
from scout_agent.errors import ScoutConfigError
from scout_agent.localization.shared_map import SharedMapSource
from scout_agent.mapping import LinkConfig, MappingSession, open_mapping
from scout_agent.run import ScoutRunConfig, World, build_world, run_scout

__all__ = ["LinkConfig", "ScoutConfig", "ScoutSummary", "run"]


@dataclass(frozen=True)
class ScoutConfig:
    """One scout's walk and mapping. run: the world and the walk; res [m] and delta_hz: the cells and how
    often a delta leaves; link: publish to a map service (None: local map only); save_map: `.npz` path of
    the scout's own map; mapping=False walks without estimators or map; rrd: Rerun recording path
    (rrd_terrain=False leaves the terrain to the mission's recording); viewer / connect_viewer: stream
    live to a spawned or running Rerun viewer; progress: progress bar or status lines."""

    run: ScoutRunConfig
    res: float = DEFAULT_RES_M
    delta_hz: float = DEFAULT_DELTA_HZ
    link: LinkConfig | None = None
    save_map: str | None = None
    mapping: bool = True
    rrd: str | None = None
    rrd_terrain: bool = True
    viewer: bool = False
    connect_viewer: str | None = None
    progress: bool = True


@dataclass(frozen=True)
class ScoutSummary:
    """How the walk went. `report` is the full JSON summary (`psrmap scout --json`); the fields above it
    are the ones a caller decides on."""

    scout: str
    fell: bool
    reached_goal: bool
    distance_m: float
    sim_seconds: float
    deltas_sent: int  # distinct deltas published (0 without a link)
    all_acked: bool | None  # every published delta acknowledged (None without a link)
    saved_map: str | None
    report: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return self.report


def run(config: ScoutConfig) -> ScoutSummary:
    """Walk and map as configured. Raises ScoutConfigError (bad config or input file), ScoutLinkError
    (no router answers) or common's ViewerUnavailable (no display / no viewer at the URL) before the walk
    starts."""
    cfg = config.run
    try:
        use_viewer(config.viewer, config.connect_viewer)  # ViewerUnavailable before any work
        world = build_world(cfg)
    except ViewerUnavailable:
        raise
    except ValueError as exc:
        raise ScoutConfigError(str(exc)) from None
    on_tick = logger = None
    if config.rrd or viewer_url():
        from scout_agent import viz  # lazy: Rerun only when recording

        rec = viz.open_recording(config.rrd)
        if config.rrd_terrain:  # a mission logs the terrain once in its own recording
            viz.log_terrain(rec, world.terrain)
            viz.log_friction(rec, world.friction, world.terrain)
        logger = viz.ScoutLogger(rec, cfg.scout_id, height=world.terrain.height)
        on_tick = lambda sample, truth, sim: logger.log_tick(sample, truth)  # noqa: E731
    if config.mapping:
        on_estimates = logger.log_estimates if logger is not None else None
        with open_mapping(cfg.scout_id, config.res, config.delta_hz, config.link, config.save_map, on_tick,
                          on_estimates) as mapping:  # fmt: skip
            hazard_sinks = [mapping.on_hazard] + ([logger.log_hazard] if logger is not None else [])

            def on_hazard(felt: Felt) -> None:
                for sink in hazard_sinks:
                    sink(felt)

            source = _shared_map_source(cfg, config, mapping, world)
            try:
                report = run_scout(cfg, on_tick=mapping.on_tick, progress=config.progress, world=world,
                                   on_hazard=on_hazard, map_source=source, on_fix=mapping.on_fix)  # fmt: skip
            finally:
                if source is not None:
                    source.close()
        report["map"] = mapping.summary
    else:
        report = run_scout(cfg, on_tick=on_tick, progress=config.progress, world=world)
        report["map"] = None
    if logger is not None:
        logger.finish()
        logger.rec.flush()
    m = report["map"] or {}
    return ScoutSummary(
        scout=cfg.scout_id,
        fell=bool(report["fell"]),
        reached_goal=bool(report["reached_goal"]),
        distance_m=float(report["distance_m"]),
        sim_seconds=float(report["sim_seconds"]),
        deltas_sent=int(m.get("publisher", {}).get("sent", 0)),
        all_acked=m.get("all_acked"),
        saved_map=m.get("saved"),
        report=report,
    )


def _shared_map_source(
    cfg: ScoutRunConfig, config: ScoutConfig, mapping: MappingSession, world: World
) -> SharedMapSource | None:
    """The shared map the scout publishes to, followed for localization (`--localize on` and a link)."""
    mapper = mapping.mapper
    if cfg.localize != "on" or config.link is None or mapper is None or mapper.publisher is None:
        return None

    pub = mapper.publisher
    xa, ya, xb, yb = world.terrain.extent
    trust = load_trust(None, config.link.zenoh_config)  # believe the servers the publisher believes
    return SharedMapSource(pub.transport.session, config.link.map_id, mapper.local, (xa, ya, xb, yb), trust)
