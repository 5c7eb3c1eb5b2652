"""`psrmap mission`: a whole mission on one machine — router, map server, N scouts, a rover planner.

The mission process itself runs the Zenoh router (the Python package's embedded router, on loopback) and
starts every component as its own process (`multiprocessing`, `spawn`: Zenoh sessions do not survive a
fork) through the same `psrmap` subcommands a team would start by hand on several machines. Each process
writes its console output and its Rerun recording into the run folder; all recordings share one recording id
and are merged into `mission.rrd` at the end.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import multiprocessing as mp
import os
import shutil
import socket
import subprocess
import sys
import time
import tomllib
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, cast

import numpy as np

from common.recording import use_viewer
from psrmap.agreement import elevation_agreement
from psrmap.progress import progress as progress_bar

DRIFT_KEYS = ("drift_xy_m", "drift_xy_pct", "drift_z_m", "drift_yaw_deg", "state_source")

__all__ = ["MissionConfig", "ScoutPlan", "load_config", "register", "run_mission"]

SCENES = ("lunar", "ramps")
UNKNOWN_POLICIES = ("forbid", "penalty", "infer")


class MissionError(ValueError):
    """A mission config or flag that cannot run; the message names what would have been valid."""


@dataclass(frozen=True)
class ScoutPlan:
    """One scout: id, start pose (x [m], y [m], yaw [rad]) in the map frame, goal (x, y), waypoints."""

    id: str
    start: tuple[float, float, float]
    goal: tuple[float, float]
    via: tuple[tuple[float, float], ...] = ()

    def route(self) -> list[tuple[float, float]]:
        """The route as map-frame points, start to goal."""
        return [(self.start[0], self.start[1]), *self.via, self.goal]


@dataclass(frozen=True)
class MissionConfig:
    """Everything a mission needs; `load_config` reads it from TOML, flags replace fields once."""

    map: str = "moon"
    res: float = 0.4  # cell size [m]
    sim_seconds: float = 150.0  # cap on each scout's walk [s]
    speed: float = 0.2  # [m/s]
    rate_hz: float = 5.0  # deltas per second per scout
    out: str = "runs"
    scene: str = "lunar"
    seed: int = 7
    slope: float = 15.0  # ramps scene only [deg]
    slippery_patches: int = 4
    scouts: tuple[ScoutPlan, ...] = ()
    plan_from: tuple[float, float] = (2.0, 2.0)
    plan_to: tuple[float, float] = (18.0, 18.0)
    unknown: str = "penalty"
    weights: dict[str, float] = field(default_factory=dict)
    rrd: bool = True  # write Rerun recordings
    secure: bool = True  # per-run credentials + router ACL (psrmap secure init) for every component
    zenoh_config: str | None = None  # an existing secure folder's router.json5 (agents' files beside it)
    timeout_s: float = 900.0  # the whole mission gives up after this long [s wall clock]
    # where the map frame's origin is on the Moon: latitude, longitude [deg], heading of the map's +x axis from
    # the south polar stereographic easting [deg]; exports are then in IAU_2015:30135 (`psrmap export`)
    origin: tuple[float, float, float] | None = None


def _pair(v: Any, what: str) -> tuple[float, float]:
    try:
        x, y = (float(c) for c in v)
    except (TypeError, ValueError):
        raise MissionError(f"{what} = {v!r}: need [x, y] in metres") from None
    return (x, y)


def _scout(d: dict[str, Any], i: int) -> ScoutPlan:
    where = f"[[scouts]] #{i + 1}"
    try:
        sid = str(d["id"])
        start = tuple(float(c) for c in d["start"])
        goal = _pair(d["goal"], f"{where} goal")
    except KeyError as exc:
        raise MissionError(
            f"{where}: missing {exc.args[0]!r}; a scout needs id, start, goal (via optional)"
        ) from None
    except (TypeError, ValueError):
        raise MissionError(f"{where}: start must be [x, y, yaw]") from None
    if len(start) != 3:
        raise MissionError(f"{where} start = {d['start']!r}: need [x, y, yaw]")
    via = tuple(_pair(p, f"{where} via") for p in d.get("via", []))
    return ScoutPlan(sid, (start[0], start[1], start[2]), goal, via)


_MISSION_KEYS = ("map", "res", "sim_seconds", "speed", "rate_hz", "out", "secure", "origin")
_TERRAIN_KEYS = ("scene", "seed", "slope", "slippery_patches")
_PLANNER_KEYS = ("from", "to", "unknown", "weights")
_SCOUT_KEYS = ("id", "start", "goal", "via")


def _origin(v: Any, where: str) -> tuple[float, float, float] | None:
    if v is None:
        return None
    try:
        vals = [float(c) for c in v]
        if len(vals) == 2:
            vals.append(0.0)
        lat, lon, heading = vals
    except (TypeError, ValueError):
        raise MissionError(
            f"{where}: [mission] origin = {v!r}: need [lat, lon] or [lat, lon, heading] in degrees"
        ) from None
    if not -90.0 <= lat < -60.0:
        raise MissionError(
            f"{where}: [mission] origin latitude {lat}: the south polar projection needs -90 <= lat < -60"
        )
    return (lat, lon, heading)


def load_config(path: str | Path | None = None) -> MissionConfig:
    """The mission config from a TOML file (None: the embedded default `mission_default.toml`)."""
    if path is None:
        text = resources.files("psrmap").joinpath("mission_default.toml").read_text()
        where = "the embedded default mission"
    else:
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise MissionError(f"mission config {path}: {exc.strerror}") from None
        where = str(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MissionError(f"{where}: not valid TOML ({exc})") from None
    known = {"mission", "terrain", "scouts", "planner"}
    unknown = set(doc) - known
    if unknown:
        raise MissionError(f"{where}: unknown section(s) {sorted(unknown)}; sections: {sorted(known)}")
    m, t, p = doc.get("mission", {}), doc.get("terrain", {}), doc.get("planner", {})
    for section, table, keys in (
        ("mission", m, _MISSION_KEYS),
        ("terrain", t, _TERRAIN_KEYS),
        ("planner", p, _PLANNER_KEYS),
        *(("scouts", s, _SCOUT_KEYS) for s in doc.get("scouts", [])),
    ):
        if not isinstance(table, dict):
            raise MissionError(f"{where}: [{section}] must be a table")
        extra = set(table) - set(keys)
        if extra:
            raise MissionError(
                f"{where}: unknown key(s) {sorted(extra)} in [{section}]; keys: {', '.join(keys)}"
            )
    base = MissionConfig()
    cfg = dataclasses.replace(
        base,
        map=str(m.get("map", base.map)),
        res=float(m.get("res", base.res)),
        sim_seconds=float(m.get("sim_seconds", base.sim_seconds)),
        speed=float(m.get("speed", base.speed)),
        rate_hz=float(m.get("rate_hz", base.rate_hz)),
        out=str(m.get("out", base.out)),
        secure=bool(m.get("secure", base.secure)),
        scene=str(t.get("scene", base.scene)),
        seed=int(t.get("seed", base.seed)),
        slope=float(t.get("slope", base.slope)),
        slippery_patches=int(t.get("slippery_patches", base.slippery_patches)),
        scouts=tuple(_scout(s, i) for i, s in enumerate(doc.get("scouts", []))),
        plan_from=_pair(p.get("from", base.plan_from), "[planner] from"),
        plan_to=_pair(p.get("to", base.plan_to), "[planner] to"),
        unknown=str(p.get("unknown", base.unknown)),
        weights={str(k): float(v) for k, v in p.get("weights", {}).items()},
        origin=_origin(m.get("origin"), where),
    )
    validate(cfg)
    return cfg


def validate(cfg: MissionConfig) -> None:
    """Raise `MissionError` naming the valid choices when the config cannot run."""
    if cfg.scene not in SCENES:
        raise MissionError(f"scene {cfg.scene!r}; scenes: {', '.join(SCENES)}")
    if cfg.unknown not in UNKNOWN_POLICIES:
        raise MissionError(f"unknown policy {cfg.unknown!r}; policies: {', '.join(UNKNOWN_POLICIES)}")
    if not cfg.scouts:
        raise MissionError("no scouts: give at least one [[scouts]] entry (id, start, goal)")
    ids = [s.id for s in cfg.scouts]
    if len(set(ids)) != len(ids):
        raise MissionError(f"scout ids must be unique, got {ids}")
    for name, v in (
        ("res", cfg.res),
        ("sim_seconds", cfg.sim_seconds),
        ("speed", cfg.speed),
        ("rate_hz", cfg.rate_hz),
    ):
        if not v > 0:
            raise MissionError(f"{name} = {v}: must be > 0")
    if cfg.zenoh_config:
        _credential_files(cfg)


def _credential_files(cfg: MissionConfig) -> dict[str, Path]:
    """The secure folder's file of every component, beside `cfg.zenoh_config` (the router's)."""
    router = Path(cfg.zenoh_config or "")
    needed = {n: router.with_name(f"{n}.json5") for n in ["server", "planner", *(s.id for s in cfg.scouts)]}
    missing = [str(p) for p in [router, *needed.values()] if not p.is_file()]
    if missing:
        raise MissionError(
            f"--zenoh-config {router}: need the router's file and, beside it, one per component "
            f"(psrmap secure init --scouts <the mission's scout ids> --planners planner); missing: "
            f"{', '.join(missing)}"
        )
    return needed


def with_scouts(cfg: MissionConfig, n: int) -> MissionConfig:
    """`cfg` with exactly `n` scouts: the first `n` of its list, more generated around the terrain if needed."""
    if n < 1:
        raise MissionError(f"--scouts {n}: need at least 1")
    scouts = list(cfg.scouts[:n])
    k = 0
    while len(scouts) < n:  # extra scouts start on a ring and walk through the centre
        import math

        a = 2 * math.pi * (k + 0.5) / max(n, 1)
        r = 7.0
        sx, sy = r * math.cos(a), r * math.sin(a)
        scouts.append(ScoutPlan(f"scout{len(scouts) + 1}", (sx, sy, a + math.pi), (-0.5 * sx, -0.5 * sy)))
        k += 1
    return dataclasses.replace(cfg, scouts=tuple(scouts))


# --------------------------------------------------------------------------------------------------------
# processes


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _run_component(target: Any, config: Any, conn: Any, log_path: str, env: dict[str, str]) -> None:
    """Process target: `target(config)` with stdout/stderr sent to a log file (at the fd level); its typed
    result (or the error that stopped it) goes back through `conn`."""
    os.environ.update(env)
    log = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(log, 1)
    os.dup2(log, 2)
    sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
    import logging
    import traceback

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    code = 0
    try:
        result = target(config)
        code = int(getattr(result, "exit_code", 0))
        conn.send(("ok", result))
    except Exception as exc:  # reported to the mission, which names the log
        traceback.print_exc()
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        code = 1
    finally:
        conn.close()
        sys.stdout.flush()
    sys.exit(code)


@dataclass
class _Proc:
    name: str
    proc: Any
    log: Path
    conn: Any  # the parent's end of the result pipe

    def result(self, timeout: float | None = None) -> tuple[str, Any]:
        """("ok", typed result) or ("error", why), once the component finished (or it died)."""
        if self.conn.poll(timeout):
            try:
                return self.conn.recv()  # type: ignore[no-any-return]
            except EOFError:
                pass
        self.proc.join(timeout=5)
        return "error", f"exit code {self.proc.exitcode}; see {self.log}"


def _spawn(ctx: Any, name: str, target: Any, config: Any, run_dir: Path, env: dict[str, str]) -> _Proc:
    """Start `target(config)` (a component's typed entry point) in a spawned process."""
    log = run_dir / "logs" / f"{name}.log"
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(
        target=_run_component, args=(target, config, child, str(log), env), name=name, daemon=False
    )
    p.start()
    child.close()
    return _Proc(name, p, log, parent)


def scout_config(
    cfg: MissionConfig, s: ScoutPlan, endpoint: str, run_dir: Path, zenoh_file: str | None
) -> Any:
    """The ScoutConfig of one of the mission's scouts."""
    from scout_agent.component import ScoutConfig
    from scout_agent.mapping import LinkConfig
    from scout_agent.run import ScoutRunConfig

    lunar = cfg.scene == "lunar"
    run = ScoutRunConfig(
        scene=cfg.scene,
        slope_deg=15.0 if lunar else cfg.slope,
        seed=cfg.seed if lunar else 0,
        start=tuple(s.start) if lunar else None,
        goal=tuple(s.goal) if lunar else None,  # type: ignore[arg-type]
        via=tuple(tuple(v) for v in s.via) if lunar else (),  # type: ignore[misc]
        speed=cfg.speed,
        sim_seconds=cfg.sim_seconds,
        slippery_patches=cfg.slippery_patches if lunar else 0,
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


def _status(session: Any, map_id: str, timeout: float = 2.0) -> Any | None:
    from common.query import get_status

    return get_status(session, map_id, timeout)


def _wait_for_server(session: Any, map_id: str, procs: Sequence[_Proc], deadline: float) -> Any:
    while time.monotonic() < deadline:
        st = _status(session, map_id, timeout=1.0)
        if st is not None:
            return st
        for p in procs:
            if not p.proc.is_alive():
                raise RuntimeError(f"{p.name} exited early with code {p.proc.exitcode}; see {p.log}")
        time.sleep(0.2)
    raise RuntimeError(
        f"the map server did not answer within the mission's start-up time; see {procs[0].log}"
    )


def rerun_exe() -> list[str]:
    """The `rerun` command line tool: the script on PATH, else the module of the installed rerun-sdk."""
    exe = shutil.which("rerun")
    return [exe] if exe else [sys.executable, "-m", "rerun"]


def merge_recordings(run_dir: Path) -> Path | None:
    """Merge every process's .rrd of the run into `mission.rrd` (the recordings share one recording id) and
    compact its chunks (`rerun rrd optimize`: the processes send small chunks as they go; the viewer loads
    and scrubs the compacted file much faster)."""
    parts = sorted((run_dir / "recordings").glob("*.rrd"))
    if not parts:
        return None
    dst = run_dir / "mission.rrd"
    res = subprocess.run(
        [*rerun_exe(), "rrd", "optimize", *map(str, parts), "-o", str(dst)],
        capture_output=True,
        text=True,
        check=False,
    )
    if res.returncode != 0:
        print(
            f"warning: rerun rrd optimize failed ({res.stderr.strip()[:300]}); the per-process recordings stay",
            file=sys.stderr,
        )
        return None
    return dst


def run_mission(cfg: MissionConfig, run_dir: Path | None = None, progress: bool = True) -> dict[str, Any]:
    """Run the mission, return its summary (also written to `<run_dir>/summary.json`)."""
    import zenoh

    from common.session import zenoh_config
    from map_server.component import run as run_server
    from map_server.service import ServerConfig
    from scout_agent.component import run as run_scout_component

    validate(cfg)
    if run_dir is None:
        run_dir = Path(cfg.out) / time.strftime("%Y%m%d-%H%M%S")
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "logs").mkdir(exist_ok=True)
    (run_dir / "recordings").mkdir(exist_ok=True)
    recording_id = f"psrmap-{cfg.map}-{uuid.uuid4().hex[:12]}"
    env = {"PSRMAP_RECORDING_ID": recording_id, "PYTHONUNBUFFERED": "1"}
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ctx = mp.get_context("spawn")
    t0 = time.monotonic()
    deadline = t0 + cfg.timeout_s
    summary: dict[str, Any] = {
        "run_dir": str(run_dir),
        "recording_id": recording_id,
        "router": endpoint,
        "config": _config_json(cfg),
    }
    (run_dir / "mission.json").write_text(json.dumps(summary["config"], indent=2))
    say = print if progress else (lambda *a, **k: None)
    procs: list[_Proc] = []
    server: _Proc | None = None
    creds: dict[str, str] = {}  # component -> its Zenoh config file (credentials)
    router_file = None
    if cfg.zenoh_config:
        router_file = Path(cfg.zenoh_config)
        creds = {n: str(p) for n, p in _credential_files(cfg).items()}
    elif cfg.secure:
        from psrmap.secure import secure_init

        lay = secure_init(
            run_dir / "secure", cfg.map, [s.id for s in cfg.scouts], ["planner"], ["server"], endpoint
        )
        creds = {name: str(path) for name, path in lay.agents.items()}
        router_file = lay.router
    with zenoh.open(zenoh_config(listen=[endpoint], mode="router", config_file=router_file)) as session:
        say(
            f"[mission] router listening on {endpoint}"
            + (" (credentials + ACL)" if creds else " (no credentials)")
            + f"; run folder {run_dir}"
        )
        try:
            server_cfg = ServerConfig(
                map_id=cfg.map,
                res=cfg.res,
                db=str(run_dir / "map.db"),
                connect=(endpoint,),
                rrd=str(run_dir / "recordings" / "server.rrd") if cfg.rrd else None,
                zenoh_config=creds.get("server"),
            )
            server = _spawn(ctx, "server", run_server, server_cfg, run_dir, env)
            _wait_for_server(session, cfg.map, [server], min(deadline, time.monotonic() + 60))
            say(f"[mission] map server up (map {cfg.map!r}, res {cfg.res} m, db {run_dir / 'map.db'})")
            _log_context(cfg, run_dir, recording_id)
            for s in cfg.scouts:
                sc = scout_config(cfg, s, endpoint, run_dir, creds.get(s.id))
                procs.append(_spawn(ctx, s.id, run_scout_component, sc, run_dir, env))
            say(
                f"[mission] {len(procs)} scouts walking (≤ {cfg.sim_seconds:g} s each): "
                + ", ".join(p.name for p in procs)
            )
            total = cfg.sim_seconds * len(procs)
            bar = progress_bar(round(total), "scouts", "sim-s", disable=not progress, every_s=15.0)
            while any(p.proc.is_alive() for p in procs):
                if time.monotonic() > deadline:
                    raise RuntimeError(f"mission timed out after {cfg.timeout_s:g} s")
                st = _status(session, cfg.map, timeout=1.0)
                if st is not None:
                    walked = sum(
                        min((v.last_seq + 1) / cfg.rate_hz, cfg.sim_seconds) for v in st.scouts.values()
                    )
                    bar.n = min(round(walked), round(total))
                    bar.set_postfix(
                        deltas=st.merged, cells=st.cells, alive=sum(v.alive for v in st.scouts.values())
                    )
                    bar.refresh()
                if server is not None and not server.proc.is_alive():
                    raise RuntimeError(f"the map server died (code {server.proc.exitcode}); see {server.log}")
                time.sleep(0.5)
            bar.n = bar.total
            bar.close()
            scouts: dict[str, Any] = {}
            for p in procs:
                kind, res = p.result(timeout=30)
                p.proc.join(timeout=10)
                scouts[p.name] = res.to_json() if kind == "ok" else {"error": f"{res}; see {p.log}"}
            summary["scouts"] = scouts
            # each scout's state-estimate drift at its goal, and how its own map agrees with the others'
            summary["drift"] = {
                sid: {k: s.get(k) for k in DRIFT_KEYS} for sid, s in scouts.items() if "error" not in s
            }
            summary["elevation_agreement"] = elevation_agreement(
                {s.id: run_dir / f"{s.id}_local.npz" for s in cfg.scouts}
            )
            summary["status"] = _status_json(_await_totals(session, cfg, scouts))
            say(
                f"[mission] scouts done; server merged {summary['status']['merged']} deltas into {summary['status']['cells']} cells"
            )
            summary["plan"], summary["comparison"] = _plan_and_compare(
                ctx, cfg, endpoint, run_dir, env, creds.get("planner")
            )
            summary["map_png"] = _plot(session, cfg, run_dir, summary)
        finally:
            for p in procs:
                if p.proc.is_alive():
                    p.proc.terminate()
                p.proc.join(timeout=10)
            if server is not None:
                server.proc.terminate()  # SIGTERM: the server flushes, closes its session, reports
                kind, res = server.result(timeout=20)
                summary["server"] = dataclasses.asdict(res) if kind == "ok" else {"error": res}
                server.proc.join(timeout=5)
                if server.proc.is_alive():
                    server.proc.kill()
    merged = merge_recordings(run_dir) if cfg.rrd else None
    summary["recording"] = str(merged) if merged else None
    summary["wall_seconds"] = round(time.monotonic() - t0, 1)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=_json_default))
    if progress:
        _print_report(summary)
    return summary


def _await_totals(session: Any, cfg: MissionConfig, scouts: dict[str, Any], wait_s: float = 15.0) -> Any:
    """The server's status once every scout's last delta is merged (scouts wait for acks before exiting)."""
    end = time.monotonic() + wait_s
    st = None
    while time.monotonic() < end:
        st = _status(session, cfg.map)
        if st is not None:
            done = all(
                sid in st.scouts and st.scouts[sid].last_seq + 1 >= deltas_sent(info)
                for sid, info in scouts.items()
                if "error" not in info
            )
            if done:
                return st
        time.sleep(0.3)
    return st


def deltas_sent(scout_summary: dict[str, Any]) -> int:
    """How many distinct deltas a scout published (its `--json` summary's `map.publisher.sent`)."""
    return int(scout_summary.get("map", {}).get("publisher", {}).get("sent", 0))


def _status_json(st: Any) -> dict[str, Any]:
    return {"error": "no status reply"} if st is None else st.to_json()


def _plan_and_compare(
    ctx: Any, cfg: MissionConfig, endpoint: str, run_dir: Path, env: dict[str, str], creds: str | None
) -> tuple[Any, Any]:
    from consumer_planner.component import CompareConfig, MapSource, PlanConfig, compare, plan
    from consumer_planner.costs import CostConfig, parse_weights

    source = MapSource(map_id=cfg.map, connect=(endpoint,), zenoh_config=creds)
    cost = dataclasses.replace(CostConfig(), weights=parse_weights(",".join(f"{k}={v:g}" for k, v in cfg.weights.items())),
                               unknown=cast(Any, cfg.unknown))  # fmt: skip
    rrd = str(run_dir / "recordings" / "planner.rrd") if cfg.rrd else None
    p = _spawn(ctx, "plan", plan, PlanConfig(source, cfg.plan_from, cfg.plan_to, cost, rrd=rrd), run_dir, env)
    kind, res = p.result(timeout=300)
    plan_json = res.to_json() if kind == "ok" else {"error": f"plan failed ({res}); see {p.log}"}
    # the comparison reads the slip layer as the map holds it (no spread): the paper's table of trajectories
    routes = [(s.id, tuple(tuple(pt) for pt in s.route())) for s in cfg.scouts]
    if plan_json.get("path"):
        routes.append(("planned", tuple((float(x), float(y)) for x, y in cast(list, plan_json["path"]))))
    cmp_cfg = CompareConfig(source, tuple(routes), dataclasses.replace(cost, slip_spread_m=0.0))  # type: ignore[arg-type]
    c = _spawn(ctx, "compare", compare, cmp_cfg, run_dir, env)
    kind, res = c.result(timeout=300)
    comparison = res.to_json() if kind == "ok" else {"error": f"compare failed ({res}); see {c.log}"}
    return plan_json, comparison


def _plot(session: Any, cfg: MissionConfig, run_dir: Path, summary: dict[str, Any]) -> str | None:
    """`map.png`: the shared map's layers with the scouts' routes and the planned path."""
    from consumer_planner.client import ClientConfig, query_region
    from consumer_planner.errors import PlannerError
    from psrmap.plots import plot_map

    pts = np.array([p for s in cfg.scouts for p in s.route()] + [cfg.plan_from, cfg.plan_to], dtype=float)
    (xa, ya), (xb, yb) = pts.min(axis=0) - 2.0, pts.max(axis=0) + 2.0
    try:
        grid = query_region(session, cfg.map, (xa, ya, xb, yb), ClientConfig(connect=()))
    except PlannerError as exc:
        print(f"warning: no map picture ({exc})", file=sys.stderr)
        return None
    plan = summary.get("plan") or {}
    title = f"map {cfg.map!r} after {len(cfg.scouts)} scouts, {summary['status'].get('merged')} deltas"
    out = plot_map(grid, {s.id: s.route() for s in cfg.scouts}, run_dir / "map.png", title, plan.get("path"))
    return str(out)


def _log_context(cfg: MissionConfig, run_dir: Path, recording_id: str) -> None:
    """The terrain mesh, friction map and default blueprint, in the mission's own recording."""
    if not cfg.rrd:
        return
    try:
        from psrmap.viz import log_mission_context
    except ImportError:
        return
    log_mission_context(cfg, run_dir / "recordings" / "mission.rrd", recording_id)


def _config_json(cfg: MissionConfig) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(cfg), default=_json_default))


def _json_default(o: Any) -> Any:
    if isinstance(o, Path):
        return str(o)
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)


def _print_report(summary: dict[str, Any]) -> None:
    print()
    print(f"Mission finished in {summary['wall_seconds']} s — run folder {summary['run_dir']}")
    st = summary.get("status", {})
    print(
        f"  map server: {st.get('merged')} deltas merged, {st.get('cells')} cells, rejected {st.get('rejected')}"
    )
    for sid, s in summary.get("scouts", {}).items():
        if "error" in s:
            print(f"  {sid}: {s['error']}")
            continue
        print(
            f"  {sid}: {s.get('distance_m', float('nan')):.1f} m in {s.get('sim_seconds', float('nan')):.0f} s, "
            f"fell={s.get('fell')}, reached_goal={s.get('reached_goal')}, deltas={deltas_sent(s)}, "
            f"slip events felt={s.get('map', {}).get('slip_events')}, "
            f"drift {s.get('drift_xy_pct')} % / z {s.get('drift_z_m')} m / yaw {s.get('drift_yaw_deg')}°"
        )
    for pair, a in (summary.get("elevation_agreement") or {}).items():
        print(
            f"  own maps {pair}: {a['cells']} shared elevation cells, differ by {a['mean_diff_m']:+.3f} m "
            f"(RMS {a['rms_diff_m']:.3f} m)"
        )
    plan = summary.get("plan") or {}
    if "error" in plan:
        print(f"  plan: {plan['error']}")
    else:
        moved = plan.get("goal_moved_m") or 0.0
        print(
            f"  plan: {plan.get('length_m', float('nan')):.1f} m, cost {plan.get('cost', float('nan')):.2f}"
            + (
                f" (goal cell forbidden by the map: moved {moved:.2f} m to the nearest passable cell)"
                if moved
                else ""
            )
        )
    comparison = summary.get("comparison") or {}
    if comparison.get("routes"):
        print()
        from consumer_planner.table import route_table

        print(route_table(comparison["routes"]))
        print(
            "(routes costed on the slip layer as the map holds it; the planner itself spreads slip rates over "
            f"{(summary.get('plan') or {}).get('slip_spread_m', '?')} m when it plans)"
        )
    elif "error" in comparison:
        print(f"  comparison: {comparison['error']}")
    if summary.get("map_png"):
        print(f"\nMap picture: {summary['map_png']}")
    if summary.get("recording"):
        print(f"Recording: rerun {summary['recording']}")


# --------------------------------------------------------------------------------------------------------
# CLI


def register(sub: Any) -> None:
    p = sub.add_parser(
        "mission",
        help="run a whole mission: router, map server, N scouts, a planner query (embedded defaults)",
        description="Start a Zenoh router, the map server and N scouts on a seeded lunar terrain; when they are "
        "done, plan a path across the explored area and compare the scouts' routes. Everything lands in "
        "runs/<timestamp>/.",
    )
    p.add_argument("--config", help="mission TOML file (default: the embedded mission_default.toml)")
    p.add_argument("--scouts", type=int, help="number of scouts (default: as many as the config lists, 3)")
    p.add_argument("--seed", type=int, help="terrain seed")
    p.add_argument("--sim-seconds", type=float, help="cap on each scout's walk [s of simulated time]")
    p.add_argument("--out", help="parent folder of the run folder (default runs/)")
    p.add_argument("--run-dir", help="exact run folder (default <out>/<timestamp>)")
    p.add_argument("--no-rrd", action="store_true", help="do not write Rerun recordings")
    p.add_argument(
        "--zenoh-config",
        metavar="ROUTER.json5",
        help="use an existing `psrmap secure init` folder: its router.json5 (the agents' files beside "
        "it: server, planner and one per scout id) instead of fresh per-run credentials",
    )
    p.add_argument(
        "--no-secure",
        action="store_true",
        help="no per-run credentials and router ACL (every component talks to an open loopback router)",
    )
    p.add_argument(
        "--viewer",
        action="store_true",
        help="spawn a local Rerun viewer and stream the whole mission to it live (besides the .rrd files)",
    )
    p.add_argument(
        "--connect-viewer",
        metavar="URL",
        help="stream the mission live to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    p.add_argument("--quiet", action="store_true", help="no progress output, only the final JSON path")
    p.set_defaults(func=_cmd_mission, parser=p)


def _cmd_mission(args: argparse.Namespace) -> int:
    try:
        cfg = load_config(args.config)
        if args.scouts is not None:
            cfg = with_scouts(cfg, args.scouts)
        changes: dict[str, Any] = {}
        if args.seed is not None:
            changes["seed"] = args.seed
        if args.sim_seconds is not None:
            changes["sim_seconds"] = args.sim_seconds
        if args.out is not None:
            changes["out"] = args.out
        if args.no_rrd:
            changes["rrd"] = False
        if args.no_secure:
            changes["secure"] = False
        if args.zenoh_config:
            changes["zenoh_config"] = args.zenoh_config
        cfg = dataclasses.replace(cfg, **changes)
        validate(cfg)
        if (args.viewer or args.connect_viewer) and not cfg.rrd:
            raise MissionError("--viewer/--connect-viewer stream the recordings: drop --no-rrd")
        use_viewer(args.viewer, args.connect_viewer)  # the components inherit PSRMAP_VIEWER_URL
    except (MissionError, ValueError) as exc:
        args.parser.error(str(exc))
    summary = run_mission(cfg, Path(args.run_dir) if args.run_dir else None, progress=not args.quiet)
    if args.quiet:
        print(Path(summary["run_dir"]) / "summary.json")
    ok = all("error" not in s for s in summary.get("scouts", {}).values())
    with contextlib.suppress(Exception):
        ok = ok and "error" not in summary["plan"]
    return 0 if ok else 1
