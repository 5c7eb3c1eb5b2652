"""`psrmap scout`: walk one simulated Aliengo on the ramps or the lunar field, headless.

    psrmap scout --scene ramps --slope 15 [--slippery 0.25]
    psrmap scout --scene lunar --seed 7 [--route west | --start x,y,yaw --goal x,y --via x,y …]
                 [--slippery-patches 4] [--patch x0,y0,x1,y1,MU …] --speed 0.2 [--sim-seconds S]
                 [--rrd PATH] [--json]

`psrmap evaluate` (the same walk scored against ground truth, `scout_agent.evaluate`) is registered here too, on
the same arguments. `add_scout_arguments` and `config_from_args` are public so other commands reuse them.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

from protocol.keys import id_arg
from psrmap_common.cli_parser import non_negative_int, positive_float
from psrmap_common.defaults import DEFAULT_RES_M, DEFAULT_SEED
from psrmap_common.errors import UsageError, ViewerUnavailable
from psrmap_common.jit import COMPILE_NOTICE, uncached
from psrmap_common.recording import use_viewer
from scout_agent import component, evaluate
from scout_agent.component import ScoutConfig
from scout_agent.dem_reader import DemWindow
from scout_agent.errors import ScoutConfigError, ScoutLinkError
from scout_agent.evaluate import evaluate_run
from scout_agent.localization import LOCALIZE_MODES
from scout_agent.loop import STATE_SOURCES, SimConfig
from scout_agent.mapping import add_mapping_arguments, publish_link
from scout_agent.onboard.drivers import CONTACT_SOURCES, ContactDetection
from scout_agent.run import SCENES, STANDSTILL_MODES, ScoutRunConfig, build_world
from scout_agent.sim.friction import Patch
from scout_agent.sim.sensors import IMU_PRESETS, SENSOR_PROFILES, SensorConfig
from scout_agent.sim.sensors.imu import IMU_ERROR_PRESETS
from scout_agent.sim.terrain import LUNAR_ROUTES, PAPER_FIELD_M, RampConfig
from scout_agent.state_estimation import kernels
from scout_agent.state_estimation.launch import LAUNCH_MODES, LaunchSurvey


def _floats(n_min: int, n_max: int, what: str):
    def parse(text: str) -> tuple[float, ...]:
        try:
            vals = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{what}: expected numbers separated by commas, got {text!r}"
            ) from None
        if not n_min <= len(vals) <= n_max:
            count = f"{n_min}" if n_min == n_max else f"{n_min} or {n_max}"
            raise argparse.ArgumentTypeError(
                f"{what}: expected {count} numbers separated by commas, got {text!r}"
            )
        return vals

    return parse


def _patch(text: str) -> Patch:
    try:
        return Patch.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_scout_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", choices=SCENES, default="ramps", help="ramps testbed or 20×20 m lunar field")
    p.add_argument("--slope", type=float, default=15.0, help="ramps: angle α in degrees, 0–25 (default 15)")
    p.add_argument(
        "--ramp-lengths",
        type=_floats(5, 5, "approach,up,platform,down,exit lengths"),
        metavar="A,U,P,D,E",
        help="ramps: horizontal segment lengths [m] (default 1.5,3,2,3,2)",
    )
    p.add_argument(
        "--seed",
        type=non_negative_int,
        default=DEFAULT_SEED,
        help=f"lunar terrain and sensor-noise seed (default {DEFAULT_SEED})",
    )
    p.add_argument(
        "--sensor-seed",
        type=non_negative_int,
        default=None,
        help="seed of this robot's own errors (sensor noise and biases, the launch survey); default: --seed. "
        "A mission gives each scout after the first its own",
    )
    p.add_argument("--route", choices=tuple(LUNAR_ROUTES), help="lunar: a named corner-to-corner route")
    p.add_argument(
        "--field",
        type=float,
        default=PAPER_FIELD_M,
        metavar="L",
        help="lunar: side of the square field [m], 5–400 (default 20, the paper's); the named routes and "
        "the default start/goal scale with it (100 m: 137 m corner to corner)",
    )
    p.add_argument(
        "--dem",
        metavar="FILE.tif",
        help="lunar: take the broad relief from this GeoTIFF DEM (projected, metres; e.g. a LOLA "
        "LDEM_*.tif); craters, rocks and roughness below its resolution are added, seeded",
    )
    p.add_argument(
        "--dem-window",
        type=_floats(2, 2, "x,y of the scene's corner in the DEM's CRS"),
        metavar="X,Y",
        help="with --dem: the DEM-CRS coordinates [m] of the scene's (0, 0) corner; the --field L scene "
        "extends east and north from it (default: the DEM's centre minus L/2)",
    )
    p.add_argument("--start", type=_floats(2, 3, "x,y[,yaw] start"), help="start x,y[,yaw] [m, rad]")
    p.add_argument("--goal", type=_floats(2, 2, "x,y goal"), help="goal x,y [m]")
    p.add_argument(
        "--via",
        type=_floats(2, 2, "x,y via point"),
        action="append",
        default=[],
        help="intermediate waypoint x,y (repeatable)",
    )
    p.add_argument("--speed", type=float, default=0.2, help="commanded speed [m/s] (default 0.2)")
    p.add_argument("--sim-seconds", type=positive_float, help="simulated time limit [s]")
    p.add_argument("--friction", type=float, default=0.7, help="regolith friction (default 0.7)")
    p.add_argument(
        "--slippery",
        type=float,
        metavar="MU",
        help="ramps: friction patch over the down-ramp, any 0 < MU ≤ 2 (below tan α: ground no robot holds)",
    )
    p.add_argument(
        "--slippery-patches",
        type=int,
        default=0,
        metavar="N",
        help="lunar: N seeded patches, μ from a loose-regolith distribution (may be unholdable)",
    )
    p.add_argument(
        "--holdable-patches",
        action="store_true",
        help="lunar: keep every patch holdable (μ ≥ tan(steepest slope) + 0.02, the paper experiments' world)",
    )
    p.add_argument(
        "--patch",
        type=_patch,
        action="append",
        default=[],
        metavar="x0,y0,x1,y1,MU",
        help="friction rectangle (repeatable)",
    )
    p.add_argument(
        "--state",
        choices=STATE_SOURCES,
        default="estimate",
        help="base state the robot runs on: its own estimate (default) or the simulator's exact "
        "state (evaluation only)",
    )
    p.add_argument(
        "--imu",
        choices=tuple(IMU_PRESETS),
        default="bmi088",
        help="IMU the sensor model imitates: consumer MEMS (default) or a tactical-grade part",
    )
    p.add_argument(
        "--contact",
        choices=CONTACT_SOURCES,
        default="pressure",
        help="foot contact from the 1-D foot pressure sensors (default) or from joint torques",
    )
    p.add_argument(
        "--sensors",
        choices=SENSOR_PROFILES,
        default="realistic",
        help="sensor errors: what a real robot has (default: IMU temperature drift, scale, misalignment, "
        "lever arm, lost packets, joint offsets, link lengths, foot-sensor drift) or the ideal models",
    )
    p.add_argument(
        "--launch",
        choices=LAUNCH_MODES,
        default="survey",
        help="the start the scout is given: a lander survey with stated error and no simulator height "
        "(default) or the exact pose and ground height (comparison only)",
    )
    p.add_argument(
        "--launch-sigma",
        type=_floats(2, 2, "launch survey σ xy [m], yaw [deg]"),
        metavar="XY_M,YAW_DEG",
        help="launch survey σ: horizontal per axis [m] and heading [deg] (default 0.15,1)",
    )
    p.add_argument(
        "--no-hazard-control",
        action="store_true",
        help="walk with the fixed trot and friction cone of before: no friction estimate, adaptive gait, "
        "hazard reflex or detour (for before/after comparisons)",
    )
    p.add_argument(
        "--localize",
        choices=LOCALIZE_MODES,
        default="on",
        help="match the scout's footholds against the orbital DEM (lunar: --dem, or the scene's simulated "
        "orbiter DEM) and the shared map it publishes to, and correct its pose (default on)",
    )
    p.add_argument(
        "--standstill",
        choices=STANDSTILL_MODES,
        default="auto",
        help="on: stand still at power-on (20 s) and pause whenever the gyro bias's heading budget is spent, "
        "fusing zero-rate updates while standing; the time it costs is reported. auto (default): on for routes "
        "of 50 m or more, off (walk at once) for shorter ones",
    )
    p.add_argument("--scout-id", default="scout1", type=id_arg("scout"), help="scout id ([A-Za-z0-9_-]+)")


def _sim_config(
    state: str,
    contact: str,
    imu: str = "bmi088",
    sensors: str = "realistic",
    launch: LaunchSurvey | None = None,
) -> SimConfig:
    base = SimConfig()
    prof = SensorConfig.named(sensors)
    prof = replace(prof, imu=IMU_PRESETS[imu])
    if sensors == "realistic":
        prof = replace(prof, imu_errors=IMU_ERROR_PRESETS[imu])
    return replace(
        base,
        state_source=state,
        sensors=prof,
        contact=ContactDetection(source=contact),
        launch=launch or LaunchSurvey(),
    )


def _launch(args: argparse.Namespace) -> LaunchSurvey:
    if args.launch_sigma is None:
        return LaunchSurvey(mode=args.launch)
    xy, yaw = args.launch_sigma
    if not (0.0 <= xy <= 100.0 and 0.0 <= yaw <= 180.0):
        raise UsageError(f"--launch-sigma {xy},{yaw}: need 0 ≤ xy ≤ 100 m and 0 ≤ yaw ≤ 180 deg")
    return LaunchSurvey(mode=args.launch, sigma_xy_m=xy, sigma_yaw_deg=yaw)


def config_from_args(args: argparse.Namespace) -> ScoutRunConfig:
    if not 0.0 <= args.slope <= 25.0:
        raise UsageError(f"--slope {args.slope}: valid range is 0–25 degrees")
    if not 0.0 < args.speed <= 0.5:
        raise UsageError(f"--speed {args.speed}: valid range is 0 < speed ≤ 0.5 m/s")
    if args.slippery is not None and args.scene != "ramps":
        raise UsageError("--slippery applies to --scene ramps; on lunar use --slippery-patches N or --patch")
    if args.slippery is not None and not 0.0 < args.slippery <= 2.0:
        raise UsageError(f"--slippery {args.slippery}: valid range is 0 < MU ≤ 2")
    if args.slippery_patches and args.scene != "lunar":
        raise UsageError("--slippery-patches applies to --scene lunar; on ramps use --slippery MU or --patch")
    if args.holdable_patches and not args.slippery_patches:
        raise UsageError("--holdable-patches applies to --slippery-patches N (lunar)")
    if args.slippery_patches < 0:
        raise UsageError("--slippery-patches must be ≥ 0")
    if args.field != PAPER_FIELD_M and args.scene != "lunar":
        raise UsageError("--field applies to --scene lunar")
    if not 5.0 <= args.field <= 400.0:
        raise UsageError(f"--field {args.field:g}: valid lunar field sides are 5–400 m")
    if args.route and args.scene != "lunar":
        raise UsageError(f"--route applies to --scene lunar (routes: {', '.join(LUNAR_ROUTES)})")
    ramp = RampConfig()
    if args.ramp_lengths is not None:
        if args.scene != "ramps":
            raise UsageError("--ramp-lengths applies to --scene ramps")
        if min(args.ramp_lengths) < 0.5:
            raise UsageError(f"--ramp-lengths {args.ramp_lengths}: each segment must be ≥ 0.5 m")
        a, u, pl, d, e = args.ramp_lengths
        ramp = RampConfig(approach_m=a, up_m=u, platform_m=pl, down_m=d, exit_m=e)
    cfg = ScoutRunConfig(
        scene=args.scene,
        slope_deg=args.slope,
        ramp=ramp,
        seed=args.seed,
        sensor_seed=args.sensor_seed,
        route=args.route,
        field_m=args.field,
        start=args.start,
        goal=tuple(args.goal) if args.goal else None,
        via=tuple(tuple(v) for v in args.via),
        speed=args.speed,
        sim_seconds=args.sim_seconds,
        friction_default=args.friction,
        slippery_mu=args.slippery,
        slippery_patches=args.slippery_patches,
        holdable_patches=args.holdable_patches,
        patches=tuple(args.patch),
        scout_id=args.scout_id,
        sim=_sim_config(args.state, args.contact, args.imu, args.sensors, _launch(args)),
        dem=_dem(args),
        hazard_control=not args.no_hazard_control,
        localize=args.localize,
        standstills=args.standstill,
    )
    try:
        build_world(cfg)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return cfg


def _dem(args: argparse.Namespace) -> DemWindow | None:
    if args.dem is None:
        if args.dem_window is not None:
            raise UsageError("--dem-window needs --dem FILE.tif")
        return None
    if args.scene != "lunar":
        raise UsageError("--dem builds the lunar scene: add --scene lunar")
    if args.dem_window is not None:
        x, y = args.dem_window
        return DemWindow(args.dem, x, y, size_m=args.field)
    try:
        import rasterio

        with rasterio.open(args.dem) as ds:
            b = ds.bounds
    except Exception as exc:  # rasterio raises its own error types for unreadable files
        raise UsageError(f"--dem {args.dem}: cannot read it as a GeoTIFF ({exc})") from None
    h = args.field / 2
    return DemWindow(args.dem, (b.left + b.right) / 2 - h, (b.bottom + b.top) / 2 - h, size_m=args.field)


def _compile_notice(args: argparse.Namespace) -> None:
    """One line before a first run's silent numba compile of the state estimator's kernels."""
    if not args.quiet and args.state != "exact" and uncached([kernels.propagate, kernels.update]):
        print(f"psrmap scout: {COMPILE_NOTICE}", file=sys.stderr, flush=True)


def scout_config(args: argparse.Namespace) -> ScoutConfig:
    """The parsed options as a ScoutConfig, or a usage error naming what would be valid."""
    return ScoutConfig(
        run=config_from_args(args),
        res=args.res,
        delta_hz=args.delta_hz,
        link=publish_link(args),
        save_map=args.save_map,
        mapping=not args.no_map,
        rrd=args.rrd,
        rrd_terrain=not args.no_rrd_terrain,
        viewer=args.viewer,
        connect_viewer=args.connect_viewer,
        progress=not args.quiet,
    )


def cmd_scout(args: argparse.Namespace) -> int:
    cfg = scout_config(args)
    try:  # the viewer before the compile notice: a bad place for a viewer is the one line said
        use_viewer(cfg.viewer, cfg.connect_viewer)
    except ViewerUnavailable as exc:  # one line: nothing is wrong with the command, only the place
        raise UsageError(str(exc), usage=False) from None
    except ValueError as exc:  # a bad --connect-viewer URL
        raise UsageError(str(exc)) from None
    cfg = replace(cfg, viewer=False, connect_viewer=None)  # streams go to the viewer use_viewer named
    _compile_notice(args)
    try:
        result = component.run(cfg)
    except (ScoutConfigError, ScoutLinkError) as exc:
        raise UsageError(str(exc)) from None
    summary = result.report
    if args.json:
        print(json.dumps(summary))
    else:
        state = (
            "FELL at {}".format(summary["fall_xy"])
            if summary["fell"]
            else (
                "reached the goal"
                if summary["reached_goal"]
                else (f"stopped: {summary['gave_up']}" if summary["gave_up"] else "stopped (time limit)")
            )
        )
        if summary["hazard_stops"]:
            state += f"; {len(summary['hazard_stops'])} hazard stop(s), detour {summary['detour_m']:.2f} m"
        print(
            f"{summary['terrain']}: {state}; {summary['distance_m']:.2f} m at {summary['mean_speed_mps']:.3f} m/s, "
            f"{summary['sim_seconds']:.1f} s simulated, {summary['real_time_factor']}× real time; "
            f"state {summary['state_source']}, drift {summary.get('drift_xy_m')} m horizontal "
            f"({summary.get('drift_xy_pct')} % of distance), {summary.get('drift_z_m')} m vertical, "
            f"{summary.get('drift_yaw_deg')}° yaw; {summary.get('sensors')} sensors, largest position error "
            f"{summary.get('pos_error_max_m')} m, inside 3σ {summary.get('inside_3sigma_frac')} of the ticks"
        )
    return 1 if result.fell else 0


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "scout",
        help="walk a simulated Aliengo (ramps or lunar terrain)",
        description=__doc__.split("\n\n")[0],
    )
    add_scout_arguments(p)
    add_mapping_arguments(p)
    p.add_argument("--rrd", metavar="PATH", help="write a Rerun recording")
    p.add_argument(
        "--viewer", action="store_true", help="spawn a local Rerun viewer and stream the walk to it live"
    )
    p.add_argument(
        "--connect-viewer",
        metavar="URL",
        help="stream the walk live to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    p.add_argument(
        "--no-rrd-terrain",
        action="store_true",
        help="do not log the terrain and friction patches (the mission's own recording holds them)",
    )
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_scout)
    register_evaluate(subparsers)
    return p


def cmd_evaluate(args: argparse.Namespace) -> int:
    if not args.res > 0:
        raise UsageError(f"--res {args.res}: need a cell size > 0 [m]")
    out = evaluate_run(config_from_args(args), args.res, progress=not args.quiet and not args.json)
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k}: {v}")
    return 1 if out["fell"] else 0


def register_evaluate(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "evaluate",
        help="run one scout and score its map and detectors against ground truth",
        description=(evaluate.__doc__ or "").split("\n\n")[0],
    )
    add_scout_arguments(p)
    p.add_argument(
        "--res", type=float, default=DEFAULT_RES_M, help=f"map cell size [m] (default {DEFAULT_RES_M})"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_evaluate)
    return p


__all__ = [
    "add_scout_arguments",
    "cmd_evaluate",
    "cmd_scout",
    "config_from_args",
    "register",
    "register_evaluate",
    "scout_config",
]
