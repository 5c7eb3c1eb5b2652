"""The scout's run, reusable: build the world from a `ScoutRunConfig`, walk the path, summarise.

`run_scout` steps a `loop.SimulatedScout` (the simulated Aliengo and the robot's software joined tick by tick)
and drives it with the robot's pilot (`control.pilot`) and localizer (`localization`), which read only the
robot's own records (`ProprioSample`, the estimate). `run_scout(config, on_tick=callback)` calls
`callback(sample, truth, robot)` every control tick, so the map estimators and the map publisher plug into the
same loop the `scout` command uses; `truth` and the summary's ground-truth figures are evaluation only.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np

from psrmap_common.defaults import DEFAULT_SEED
from scout_agent.control.pilot import Pilot, PilotConfig
from scout_agent.control.reflex import Felt
from scout_agent.dem_reader import DemWindow, read_dem_grid, read_dem_window
from scout_agent.errors import ScoutConfigError
from scout_agent.estimators import TickEstimates
from scout_agent.holding import PoseFix
from scout_agent.localization import LOCALIZE_MODES, DemReference, Localizer, LocalizerConfig, height_datum
from scout_agent.localization.localizer import MapSource
from scout_agent.loop import SimConfig, SimulatedScout
from scout_agent.onboard.software import OnboardSoftware
from scout_agent.robot import constants as C
from scout_agent.signals import GroundTruth, ProprioSample
from scout_agent.sim.dem import OrbitalDemConfig, write_orbital_dem
from scout_agent.sim.friction import (
    DEFAULT_MU,
    FrictionMap,
    Patch,
    lunar_slippery_patches,
    ramp_slippery_patch,
)
from scout_agent.sim.terrain import (
    PAPER_FIELD_M,
    LunarConfig,
    RampConfig,
    Terrain,
    make_lunar,
    make_ramps,
    route_slope_stats,
)
from scout_agent.state_estimation import StateEstimator
from scout_agent.state_estimation.consistency import ConsistencyTracker
from scout_agent.state_estimation.launch import HeightDatum
from scout_agent.state_estimation.standstill import StandstillPlanner

SCENES = ("ramps", "lunar")
OnTick = Callable[
    [ProprioSample, GroundTruth, OnboardSoftware], object
]  # may return the tick's TickEstimates
OnHazard = Callable[[Felt], object]
OnFix = Callable[[PoseFix], object]


STANDSTILL_MODES = ("auto", "on", "off")


@dataclass(frozen=True)
class ScoutRunConfig:
    scene: str = "ramps"  # one of SCENES
    slope_deg: float = 15.0  # ramps: α [deg]
    ramp: RampConfig = field(default_factory=RampConfig)  # ramps: lengths (slope_deg overrides its α)
    seed: int = DEFAULT_SEED  # lunar terrain (and noise) seed
    # the seed of this robot's own errors (sensor noise and biases, the lander's survey of its start); None:
    # `seed`. A mission gives each scout its own (`psrmap.mission.components.scout_sensor_seed`): robots
    # built and surveyed one by one do not share their error draws
    sensor_seed: int | None = None
    route: str | None = None  # lunar: a named route of lunar_routes(field_m) (start, via, goal)
    field_m: float = PAPER_FIELD_M  # lunar: the field's side [m]; the named routes scale with it
    start: tuple[float, ...] | None = None  # x, y [m][, yaw [rad]]; default: the scene's spawn; yaw
    # defaults to the heading of the first path segment
    goal: tuple[float, float] | None = None
    via: tuple[tuple[float, float], ...] = ()
    speed: float = 0.2  # commanded horizontal speed [m/s]
    sim_seconds: float | None = None  # time limit [s]; default: 2 × path length / speed + 10
    friction_default: float = DEFAULT_MU
    slippery_mu: float | None = None  # ramps: patch over the middle of the down-ramp
    slippery_patches: int = 0  # lunar: seeded patches, preferably on 10–20° descents
    holdable_patches: bool = False  # lunar: the old floor μ ≥ tan(slope) + 0.02 (paper experiments);
    # default: μ from the regolith distribution (`friction.RegolithFriction`), holdable or not
    patches: tuple[Patch, ...] = ()  # any scene: explicit rectangles
    sim: SimConfig = field(default_factory=SimConfig)
    scout_id: str = "scout1"
    dem: DemWindow | None = None  # lunar: the broad relief from a DEM window (seeded detail on top)
    hazard_control: bool = True  # friction estimate + adaptive gait + hazard reflex + detour (issue 24);
    # False: the fixed trot and friction cone of before, walking on whatever it feels
    pilot: PilotConfig = field(default_factory=PilotConfig)  # their settings (speed: `speed` above)
    localize: str = "on"  # one of LOCALIZE_MODES: match footholds against the DEM / shared map
    localizer: LocalizerConfig = field(default_factory=LocalizerConfig)
    orbital_dem: OrbitalDemConfig = field(default_factory=OrbitalDemConfig)  # procedural scenes' DEM
    standstills: str = "auto"  # one of STANDSTILL_MODES: stand at power-on and pause when the gyro bias's
    # heading budget is spent (state_estimation/standstill.py; settings: sim.estimator.standstill). "auto": on for
    # routes of `standstill_route_m` or more, where the gyro's drift dominates the heading error (100 m field:
    # 41 -> 12 deg); off for shorter ones, which would spend a quarter of their time standing for little gain
    standstill_route_m: float = 50.0


@dataclass(frozen=True)
class World:
    terrain: Terrain
    friction: FrictionMap
    waypoints: np.ndarray  # (k, 2) start, via…, goal
    start: tuple[float, float, float]


def build_world(cfg: ScoutRunConfig) -> World:
    if cfg.dem is not None and cfg.scene != "lunar":
        raise ScoutConfigError("--dem builds the lunar scene: use it with --scene lunar")
    if cfg.scene == "ramps":
        terrain = make_ramps(replace(cfg.ramp, slope_deg=cfg.slope_deg))
    elif cfg.scene == "lunar":
        if not 5.0 <= cfg.field_m <= 400.0:
            raise ScoutConfigError(f"--field {cfg.field_m:g}: valid lunar field sides are 5–400 m")
        lunar = LunarConfig(seed=cfg.seed, size_m=cfg.field_m)
        if cfg.dem is not None:
            base, info = read_dem_window(cfg.dem, lunar.res) if cfg.dem.size_m == lunar.size_m else (None, {})
            if base is None:
                raise ScoutConfigError(
                    f"DEM window size {cfg.dem.size_m:g} m: the lunar scene is {lunar.size_m:g} m"
                )
            lunar = replace(lunar, base=base, base_info=info)
        terrain = make_lunar(lunar)
    else:
        raise ScoutConfigError(f"unknown scene {cfg.scene!r}; valid: {', '.join(SCENES)}")
    patches: list[Patch] = []
    if cfg.slippery_mu is not None:
        if cfg.scene != "ramps":
            raise ScoutConfigError("slippery_mu applies to the ramps scene; use slippery_patches on lunar")
        patches.append(ramp_slippery_patch(terrain, cfg.slippery_mu))
    if cfg.slippery_patches:
        if cfg.scene != "lunar":
            raise ScoutConfigError("slippery_patches applies to the lunar scene; use slippery_mu on ramps")
        patches.extend(
            lunar_slippery_patches(
                terrain, cfg.slippery_patches, seed=cfg.seed, holdable=cfg.holdable_patches
            )
        )
    patches.extend(cfg.patches)
    friction = FrictionMap(cfg.friction_default, tuple(patches))
    start_xy: tuple[float, ...]
    if cfg.route is not None:
        routes = terrain.info.get("routes", {})
        if cfg.scene != "lunar" or cfg.route not in routes:
            raise ScoutConfigError(f"unknown route {cfg.route!r}; valid (lunar): direct, west, east")
        pts = routes[cfg.route]
        start_xy, via, goal = tuple(pts[0]), tuple(tuple(p) for p in pts[1:-1]), tuple(pts[-1])
    else:
        start_xy, via, goal = terrain.spawn[:2], cfg.via, terrain.goal
    if cfg.start is not None:
        start_xy = cfg.start[:2]
    if cfg.goal is not None:
        goal = cfg.goal
    if cfg.via:
        via = cfg.via
    waypoints = np.array([start_xy, *via, goal], dtype=float)
    xa, ya, xb, yb = terrain.extent
    for p in waypoints:
        if not (xa <= p[0] <= xb and ya <= p[1] <= yb):
            raise ScoutConfigError(
                f"waypoint {tuple(float(v) for v in p)} outside the terrain [{xa}, {xb}] × [{ya}, {yb}]"
            )
    if cfg.start is not None and len(cfg.start) == 3:
        yaw = float(cfg.start[2])
    else:
        d = waypoints[1] - waypoints[0]
        yaw = float(np.arctan2(d[1], d[0]))
    return World(terrain, friction, waypoints, (float(start_xy[0]), float(start_xy[1]), yaw))


PATH_EVERY_S = 1.0  # the summary's estimated path: one pose per simulated second


def use_standstills(cfg: ScoutRunConfig, waypoints: np.ndarray) -> bool:
    """Whether the scout stands to calibrate its gyro (`ScoutRunConfig.standstills`) on this route."""
    if cfg.standstills == "auto":
        return path_length(waypoints) >= cfg.standstill_route_m
    return cfg.standstills == "on"


def path_length(waypoints: np.ndarray) -> float:
    return float(np.sum(np.hypot(*np.diff(waypoints, axis=0).T)))


def dem_reference(cfg: ScoutRunConfig, world: World) -> DemReference | None:
    """The orbital DEM the scout localizes against: the `--dem` tile under the scene when given, else (lunar)
    the simulated orbiter's DEM of the scene, written as a GeoTIFF and read back through the same reader a
    real tile takes; none for the ramps testbed (a 3 m wide bench is below a DEM's pixel)."""
    if cfg.dem is not None:
        # the scene's heights are the DEM's minus the window's mean (read_dem_window): the map frame's
        # vertical datum, so the DEM the scout reads is expressed in it too (a mission states its datum once)
        grid = read_dem_grid(cfg.dem)
        return DemReference(replace(grid, z=grid.z - float(world.terrain.info.get("dem_datum_m", 0.0))))
    if cfg.scene != "lunar":
        return None
    with tempfile.TemporaryDirectory(prefix="psrmap-dem-") as tmp:
        path = Path(tmp) / f"orbital_{world.terrain.name}.tif"
        write_orbital_dem(world.terrain, path, replace(cfg.orbital_dem, seed=cfg.seed))
        xa, ya, xb, _ = world.terrain.extent
        return DemReference(read_dem_grid(DemWindow(str(path), xa, ya, size_m=xb - xa)))


class RunTally:
    """What the run's summary measures, tick by tick, beside the robot (evaluation only: it reads the truth):
    the true horizontal distance walked after the settle, the true path's ∫‖v_xy‖dt, ticks with a non-foot
    contact, the estimate against the truth (`ConsistencyTracker`), and the robot's own path every
    `PATH_EVERY_S`."""

    def __init__(self, start_xy: Sequence[float], settle_s: float, control_dt: float) -> None:
        self.prev_x, self.prev_y = start_xy[0], start_xy[1]
        self.settle_s = settle_s
        self.control_dt = control_dt
        self.distance = 0.0  # true horizontal distance walked since the settle [m]
        self.speed_path = 0.0  # ∫‖v_xy‖dt of the true base, whole run (the CoT distance's ground truth) [m]
        self.walk_t0: float | None = None
        self.nonfoot_ticks = 0
        self.path_estimate: list[list[float]] = []  # [t, x, y, z] of the robot's own estimate
        self.next_path_t = 0.0
        self.errors = ConsistencyTracker()  # the estimate against the truth, every tick

    def add(
        self, t: float, sample: ProprioSample, truth: GroundTruth, estimator: StateEstimator | None
    ) -> None:
        """One tick; `estimator` (None on the exact state) gives the covariance the error is judged by."""
        x, y, _ = truth.base.pos.tolist()
        if self.walk_t0 is None and t >= self.settle_s:
            self.walk_t0 = t
            self.prev_x, self.prev_y = x, y
        if self.walk_t0 is not None:
            self.distance += math.hypot(x - self.prev_x, y - self.prev_y)
            self.prev_x, self.prev_y = x, y
        if t >= self.next_path_t:
            self.next_path_t += PATH_EVERY_S
            self.path_estimate.append([round(t, 3), *(round(float(c), 3) for c in sample.base.pos)])
        self.nonfoot_ticks += truth.nonfoot_contacts > 0
        tb, eb = truth.base, sample.base
        if estimator is not None:
            self.errors.add_filter(tb.pos, tb.quat, eb.pos, eb.quat, estimator.ekf.P, estimator.ekf.R)
        else:
            self.errors.add(tb.pos, tb.quat, eb.pos, eb.quat, None, None)
        vx, vy, _ = truth.base.vel.tolist()
        self.speed_path += math.hypot(vx, vy) * self.control_dt


def scout_sim_config(cfg: ScoutRunConfig) -> SimConfig:
    """The simulated robot's configuration for `cfg`: its sensors' (and launch survey's) error draws seeded
    by `cfg.sensor_seed`, else by the terrain seed."""
    seed = cfg.seed if cfg.sensor_seed is None else cfg.sensor_seed
    return replace(cfg.sim, sensors=replace(cfg.sim.sensors, seed=seed))


def run_scout(
    cfg: ScoutRunConfig,
    on_tick: OnTick | None = None,
    progress: bool = True,
    world: World | None = None,
    on_hazard: OnHazard | None = None,
    datum_sources: Sequence[tuple[str, HeightDatum]] = (),
    map_source: MapSource | None = None,
    on_fix: OnFix | None = None,
) -> dict:
    """Walk the configured path until the goal, a fall, a hazard it cannot go around or the time limit;
    return the JSON summary. `on_tick` may return the tick's `TickEstimates` (the mapping does): the pilot
    feels them; `on_hazard` receives each hazard the reflex felt (the mapping records it in the map);
    `datum_sources` are where the scout may take its launch height datum (state_estimation/launch.py);
    `map_source`: the shared map around the scout, for localization (`scout_agent.localization`); `on_fix`
    receives each pose fix the localizer fused (`holding.PoseFix`: the mapping spreads it back over what it
    has not published yet)."""
    world = world or build_world(cfg)
    if cfg.localize not in LOCALIZE_MODES:
        raise ScoutConfigError(f"--localize {cfg.localize!r}: valid: {', '.join(LOCALIZE_MODES)}")
    if cfg.standstills not in STANDSTILL_MODES:
        raise ScoutConfigError(f"--standstill {cfg.standstills!r}: valid: {', '.join(STANDSTILL_MODES)}")
    sim_cfg = scout_sim_config(cfg)
    # the height datum of an honest start: the shared map where others have mapped, else the orbital DEM
    dem = dem_reference(cfg, world) if sim_cfg.state_source == "estimate" else None
    sources = list(datum_sources)
    if map_source is not None:
        sources.append(("map", height_datum(lambda x, y: map_source(x, y, 2.0))))
    if dem is not None:
        sources.append(("dem", height_datum(lambda x, y: dem)))
    scout = SimulatedScout(world.terrain, world.friction, sim_cfg, start=world.start, datum_sources=sources)
    robot = scout.robot  # the robot's software: the pilot and localizer below run on its estimate
    on, pc = cfg.hazard_control, cfg.pilot
    pilot_cfg = replace(
        pc,
        follower=replace(pc.follower, speed=cfg.speed),
        adaptive=pc.adaptive and on,
        reflex=pc.reflex and on,
    )
    # standstills (state_estimation/standstill.py): stand at power-on, pause when the gyro bias's heading
    # budget is spent; only a robot on its own estimate has a use for them
    planner = None
    est_cfg = robot.estimator.config.standstill
    if use_standstills(cfg, world.waypoints) and scout.config.state_source == "estimate" and est_cfg.enabled:
        planner = StandstillPlanner(robot.estimator, est_cfg)
    pilot = Pilot(
        world.waypoints,
        robot.controller,
        world.terrain.extent,
        pilot_cfg,
        hold=planner.hold if planner is not None else None,
    )
    localizer = None
    if cfg.localize == "on" and scout.config.state_source == "estimate":
        if dem is not None or map_source is not None:
            localizer = Localizer(robot.estimator, cfg.localizer, dem=dem, map_source=map_source)
    # the walking-time limit: twice the route at the commanded speed, and the power-on standstill's planned
    # extension (standstill.py: up to `start_max_s` while the board's tempco is unknown) beside it
    extra = planner.start_extension_s if planner is not None else 0.0
    limit = cfg.sim_seconds or 2.0 * path_length(world.waypoints) / max(cfg.speed, 0.05) + 10.0 + extra
    n_ticks = int(np.ceil(limit / scout.control_dt))
    bar = None
    if progress and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=n_ticks, unit="tick", desc=f"{cfg.scout_id} {world.terrain.name}", leave=False)
    next_line = 30.0 if progress and bar is None else math.inf  # not a terminal: a status line every 30 s
    wall0 = time.perf_counter()
    tally = RunTally(world.start[:2], scout.config.settle_s, scout.control_dt)
    tally_estimator = robot.estimator if scout.config.state_source == "estimate" else None
    sample = truth = None
    for k in range(n_ticks):
        # the robot's path follower: speed and turn rate from the robot's own estimate
        v, w = pilot.command(robot.state, scout.control_dt)
        if scout.t < scout.config.settle_s:
            pilot.follower.integral = 0.0
        # one control tick: command -> simulated Aliengo -> readings -> estimate (loop.py); truth beside it
        sample, truth = scout.step(v, w)
        tally.add(scout.t, sample, truth, tally_estimator)  # evaluation only
        # the robot's software reads its own record: pose fixes, then the map estimates, then the hazards felt
        if localizer is not None:  # before the mapper: what it publishes next is placed corrected
            if on_fix is None:
                localizer.on_tick(sample)
            else:
                _localize_and_report(localizer, robot.estimator, partial(localizer.on_tick, sample), on_fix)
        est = on_tick(sample, truth, robot) if on_tick is not None else None
        felt = pilot.feel(sample, est if isinstance(est, TickEstimates) else None)
        if felt is not None and on_hazard is not None:
            on_hazard(felt)
        if bar is not None and k % 50 == 0:
            bar.update(50)
        elif time.perf_counter() - wall0 >= next_line:
            next_line += 30.0
            print(
                f"[{cfg.scout_id}] {scout.t:.0f}/{limit:.0f} s simulated, {tally.distance:.1f} m walked",
                file=sys.stderr,
                flush=True,
            )
        if scout.fell or pilot.done:
            break
    if localizer is not None:  # the last stretch's fix, before the mapper releases what it holds
        if on_fix is None:
            localizer.finish()
        else:
            _localize_and_report(localizer, robot.estimator, localizer.finish, on_fix)
    if bar is not None:
        bar.close()
    wall = time.perf_counter() - wall0
    walked = scout.t - (tally.walk_t0 or scout.t)
    pos = scout.hardware.data.qpos[0:3]
    errors = tally.errors.summary()
    return {
        "scene": cfg.scene,
        "terrain": world.terrain.name,
        "scout": cfg.scout_id,
        "waypoints": world.waypoints.round(3).tolist(),
        "path_estimate": tally.path_estimate,  # [t s, x, y, z m]: where the scout believes it walked
        "speed_cmd_mps": cfg.speed,
        "fell": bool(scout.fell),
        "fall_xy": list(scout.hardware.fall_xy) if scout.hardware.fall_xy else None,
        "reached_goal": bool(pilot.reached),
        **pilot.summary(),
        "standstills": planner.summary() if planner is not None else None,
        "zaru": {"updates": robot.estimator.zaru_updates, "refused": robot.estimator.zaru_refused}
        if scout.config.state_source == "estimate"
        else None,
        # the legs' climb bias the revisited footholds calibrated (state_estimation/climb_calibration.py)
        "climb_calibration": {
            "bias_pct": round(100 * robot.estimator.climb.bias, 3),
            "std_pct": round(100 * robot.estimator.climb.std, 3),
            "pairs": robot.estimator.climb.samples,
            "refused": robot.estimator.climb.refused,
        }
        if scout.config.state_source == "estimate"
        else None,
        "final_xy": [float(pos[0]), float(pos[1])],
        "distance_m": round(tally.distance, 3),
        "mean_speed_mps": round(tally.distance / walked, 4) if walked > 0 else 0.0,
        "sim_seconds": round(scout.t, 3),
        "wall_seconds": round(wall, 2),
        "real_time_factor": round(scout.t / wall, 2) if wall > 0 else None,
        "nonfoot_contact_ticks": int(tally.nonfoot_ticks),
        "friction": world.friction.to_dict(),
        "state_source": scout.config.state_source,
        "sensors": scout.config.sensors.profile,
        "localization": localizer.report.used if localizer is not None else "off",
        "localization_stats": localizer.report.to_json() if localizer is not None else None,
        "launch": {
            "mode": scout.config.launch.mode,
            "datum": scout.launch.datum,
            "sigma_xy_m": scout.launch.sigma_xy_m,
            "sigma_yaw_deg": round(math.degrees(scout.launch.sigma_yaw_rad), 4),
            "sigma_z_m": scout.launch.sigma_z_m,
            "error_xy_m": _r4(math.hypot(scout.launch.x - world.start[0], scout.launch.y - world.start[1])),
            "error_yaw_deg": _r4(math.degrees(scout.launch.yaw - world.start[2])),
        },
        **drift(sample, truth, tally.distance),
        **errors,
        # the error the walk added after the start (consistency.py), as a share of the distance: drift_xy_pct
        # less the launch survey's error (issue 23's figure stays drift_xy_pct)
        "drift_after_start_xy_pct": _r4(100.0 * growth / tally.distance)
        if (growth := errors.get("pos_error_growth_final_m")) is not None and tally.distance > 0.05
        else None,
        "energy_truth_j": round(scout.hardware.energy_true_j, 3),
        "cot_whole_run_truth": _r4(
            scout.hardware.energy_true_j / (C.TOTAL_MASS * C.LUNAR_G * tally.speed_path)
        )
        if tally.speed_path > 0.05
        else None,
    }


def _position_variances(P: np.ndarray) -> np.ndarray:
    """(x, y, z) variances [m²] of a (3, 3) position covariance, x and y both its larger horizontal axis (the
    form of `holding.PoseFix`)."""
    big = float(max(np.linalg.eigvalsh(P[:2, :2])[-1], 0.0))
    return np.array([big, big, float(max(P[2, 2], 0.0))])


def _localize_and_report(
    localizer: Localizer, estimator: StateEstimator, step: Callable[[], object], on_fix: OnFix
) -> None:
    """One step of the localizer (its tick, or its `finish`); the change of the estimate a fused fix made goes
    to `on_fix` (the learnt height drift the tick took off is dead reckoning, not a fix)."""
    p0, P0 = estimator.ekf.p.copy(), estimator.position_covariance()
    fixes = localizer.report.fixes
    localizer.height_profile = localizer.height_profile_var = None
    step()
    if localizer.report.fixes != fixes:
        change = estimator.ekf.p - p0
        change[2] += localizer.drift_step_m
        var_after = _position_variances(estimator.position_covariance())
        on_fix(PoseFix(change, _position_variances(P0), var_after, localizer.height_profile,
                       localizer.height_profile_var))  # fmt: skip


def _r4(v: float) -> float:
    return round(float(v), 4)


def drift(sample: ProprioSample | None, truth: GroundTruth | None, distance_m: float) -> dict:
    """The state estimate's error against ground truth at the end of a run: horizontal [m] and as a share of
    the horizontal distance walked [%], vertical [m], heading [deg]."""
    if sample is None or truth is None:
        return {}
    e, g = sample.base, truth.base
    dxy = float(np.hypot(*(e.pos[:2] - g.pos[:2])))
    yaw_e = _yaw(e.quat)
    yaw_g = _yaw(g.quat)
    dyaw = (yaw_e - yaw_g + np.pi) % (2 * np.pi) - np.pi
    return {
        "drift_xy_m": _r4(dxy),
        "drift_xy_pct": _r4(100.0 * dxy / distance_m) if distance_m > 0.05 else None,
        "drift_z_m": _r4(e.pos[2] - g.pos[2]),
        "drift_yaw_deg": _r4(np.degrees(dyaw)),
    }


def _yaw(quat: np.ndarray) -> float:
    w, x, y, z = (float(v) for v in quat)
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def terrain_stats(world: World) -> dict:
    if world.terrain.name.startswith("lunar"):
        return route_slope_stats(world.terrain)
    return world.terrain.slope_stats()


__all__ = [
    "SCENES",
    "drift",
    "ScoutRunConfig",
    "RunTally",
    "World",
    "build_world",
    "run_scout",
    "terrain_stats",
]
