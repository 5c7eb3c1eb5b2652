"""`run_mission(cfg)`: router in-process, the map server, the scouts and the planner as spawned components.

The mission process runs the Zenoh router (the Python package's embedded router, on loopback), starts the
map server and waits for its status, starts every scout, follows them on the server's status (a progress
bar or status lines), collects each component's typed summary, waits until the server merged every delta,
plans and compares routes, draws `map.png` and merges the recordings. Everything lands in the run folder.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing as mp
import sys
import time
import uuid
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from consumer_planner.client import ClientConfig, query_region
from consumer_planner.errors import PlannerError
from map_server.component import run as run_server
from map_server.service import ServerConfig
from protocol.messages import Status
from psrmap.agreement import cross_scout_rms, elevation_agreement, map_elevation_rmse
from psrmap.errors import MissionRunError
from psrmap.mission.compile import compile_ahead
from psrmap.mission.components import plan_and_compare, scout_config
from psrmap.mission.config import DRIFT_KEYS, MissionConfig, _credential_files, server_names, validate
from psrmap.mission.processes import Proc, spawn
from psrmap.mission.recording import merge_recordings
from psrmap.mission.report import config_json, deltas_sent, json_default, print_report
from psrmap.plots import plot_map
from psrmap.progress import progress as progress_bar
from psrmap.secure import secure_init
from psrmap_common.query import get_status, wait_for_server
from psrmap_common.session import free_endpoint, zenoh_config
from psrmap_common.trust import Trust, load_trust
from psrmap_mapcore import read_npz
from scout_agent.component import run as run_scout_component
from scout_agent.run import ScoutRunConfig, build_world

__all__ = ["run_mission"]


def _status(
    session: zenoh.Session, map_id: str, timeout: float = 2.0, trust: Trust | Iterable[str] = ()
) -> Status | None:
    return get_status(session, map_id, timeout, trust)


def _wait_for_servers(
    session: zenoh.Session,
    map_id: str,
    procs: Sequence[Proc],
    deadline: float,
    shards: int = 1,
    trust: Trust | Iterable[str] = (),
) -> None:
    """Until every shard's server answers (psrmap_common.query.wait_for_server); MissionRunError if one died first or
    the deadline passed."""

    def alive() -> None:
        for p in procs:
            if not p.proc.is_alive():
                raise MissionRunError(f"{p.name} exited early with code {p.proc.exitcode}; see {p.log}")

    left = deadline - time.monotonic()
    if wait_for_server(session, map_id, left, shards=shards, trusted=trust, check=alive) is None:
        raise MissionRunError(
            f"the map server(s) did not all answer within the mission's start-up time; see {procs[0].log}"
        )


def run_mission(cfg: MissionConfig, run_dir: Path | None = None, progress: bool = True) -> dict[str, Any]:
    """Run the mission, return its summary (also written to `<run_dir>/summary.json`)."""
    validate(cfg)
    if run_dir is None:
        run_dir = Path(cfg.out) / time.strftime("%Y%m%d-%H%M%S")
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "logs").mkdir(exist_ok=True)
    (run_dir / "recordings").mkdir(exist_ok=True)
    recording_id = f"psrmap-{cfg.map}-{uuid.uuid4().hex[:12]}"
    env = {"PSRMAP_RECORDING_ID": recording_id, "PYTHONUNBUFFERED": "1"}
    endpoint = free_endpoint()
    ctx = mp.get_context("spawn")
    t0 = time.monotonic()
    deadline = t0 + max(cfg.timeout_s, 8.0 * cfg.sim_seconds)  # a 100 m field's walks take ~700 s each
    summary: dict[str, Any] = {
        "run_dir": str(run_dir),
        "recording_id": recording_id,
        "router": endpoint,
        "config": config_json(cfg),
    }
    (run_dir / "mission.json").write_text(json.dumps(summary["config"], indent=2))
    say = print if progress else (lambda *a, **k: None)
    procs: list[Proc] = []
    servers: list[Proc] = []
    creds: dict[str, str] = {}  # component -> its Zenoh config file (credentials)
    router_file = None
    if cfg.zenoh_config:
        router_file = Path(cfg.zenoh_config)
        creds = {n: str(p) for n, p in _credential_files(cfg).items()}
    elif cfg.secure:
        lay = secure_init(
            run_dir / "secure", cfg.map, [s.id for s in cfg.scouts], ["planner"], server_names(cfg), endpoint
        )
        creds = {name: str(path) for name, path in lay.agents.items()}
        router_file = lay.router
    trust = load_trust(
        None, router_file
    )  # with credentials: believe only the attested servers (psrmap_common.trust)
    with zenoh.open(zenoh_config(listen=[endpoint], mode="router", config_file=router_file)) as session:
        say(
            f"[mission] router listening on {endpoint}"
            + (" (credentials + ACL)" if creds else " (no credentials)")
            + f"; run folder {run_dir}"
        )
        try:
            for i, name in enumerate(server_names(cfg)):
                sharded = cfg.shards > 1
                server_cfg = ServerConfig(
                    map_id=cfg.map,
                    res=cfg.res,
                    tile=cfg.tile,
                    db=str(run_dir / (f"map.shard{i}.db" if sharded else "map.db")),
                    connect=(endpoint,),
                    rrd=str(run_dir / "recordings" / f"{name}.rrd") if cfg.rrd else None,
                    zenoh_config=creds.get(name),
                    shards=cfg.shards,
                    shard=i if sharded else None,
                )
                servers.append(spawn(ctx, name, run_server, server_cfg, run_dir, env))
            _wait_for_servers(
                session, cfg.map, servers, min(deadline, time.monotonic() + 60), cfg.shards, trust
            )
            where = (
                f"{cfg.shards} shards, db map.shard<i>.db" if cfg.shards > 1 else f"db {run_dir / 'map.db'}"
            )
            say(f"[mission] map server up (map {cfg.map!r}, res {cfg.res} m, {where})")
            _log_context(cfg, run_dir, recording_id)
            compile_ahead(say)  # a first run after install: one line, not a silent 0 %
            for s in cfg.scouts:
                sc = scout_config(cfg, s, endpoint, run_dir, creds.get(s.id))
                procs.append(spawn(ctx, s.id, run_scout_component, sc, run_dir, env))
            say(
                f"[mission] {len(procs)} scouts walking (≤ {cfg.sim_seconds:g} s each): "
                + ", ".join(p.name for p in procs)
            )
            total = cfg.sim_seconds * len(procs)
            bar = progress_bar(round(total), "scouts", "sim-s", disable=not progress, every_s=15.0)
            while any(p.proc.is_alive() for p in procs):
                if time.monotonic() > deadline:
                    raise MissionRunError(f"mission timed out after {deadline - t0:g} s")
                st = _status(session, cfg.map, 1.0, trust)
                if st is not None:
                    walked = sum(
                        min((v.last_seq + 1) / cfg.rate_hz, cfg.sim_seconds) for v in st.scouts.values()
                    )
                    bar.n = min(round(walked), round(total))
                    bar.set_postfix(
                        deltas=st.merged, cells=st.cells, alive=sum(v.alive for v in st.scouts.values())
                    )
                    bar.refresh()
                for server in servers:
                    if not server.proc.is_alive():
                        raise MissionRunError(
                            f"map server {server.name} died (code {server.proc.exitcode}); see {server.log}"
                        )
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
            summary["map_cross_scout_rms_m"] = cross_scout_rms(summary["elevation_agreement"])
            summary["errors"] = {
                sid: {k: s[k] for k in ERROR_KEYS if k in s} for sid, s in scouts.items() if "error" not in s
            }
            summary["status"] = _status_json(_await_totals(session, cfg, scouts, trust))
            truth = _map_truth(session, cfg, {s.id: run_dir / f"{s.id}_local.npz" for s in cfg.scouts})
            (
                summary["map_elevation_rmse_m"],
                summary["map_elevation_cells"],
                summary["scout_map_elevation_rmse_m"],
            ) = truth
            say(
                f"[mission] scouts done; server merged {summary['status']['merged']} deltas into {summary['status']['cells']} cells"
            )
            summary["plan"], summary["comparison"] = plan_and_compare(
                ctx, cfg, endpoint, run_dir, env, creds.get("planner")
            )
            summary["map_png"] = _plot(session, cfg, run_dir, summary)
        finally:
            for p in procs:
                if p.proc.is_alive():
                    p.proc.terminate()
                p.proc.join(timeout=10)
            for server in servers:
                server.proc.terminate()  # SIGTERM: the server flushes, closes its session, reports
            for server in servers:
                kind, res = server.result(timeout=20)
                # one server: "server" as before; a sharded map: "servers", one summary per shard
                out = dataclasses.asdict(res) if kind == "ok" else {"error": res}
                if cfg.shards == 1:
                    summary["server"] = out
                else:
                    summary.setdefault("servers", {})[server.name] = out
                server.proc.join(timeout=5)
                if server.proc.is_alive():
                    server.proc.kill()
    merged = merge_recordings(run_dir) if cfg.rrd else None
    summary["recording"] = str(merged) if merged else None
    summary["wall_seconds"] = round(time.monotonic() - t0, 1)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=json_default))
    if progress:
        print_report(summary)
    return summary


def _await_totals(
    session: zenoh.Session,
    cfg: MissionConfig,
    scouts: dict[str, Any],
    trust: Trust | Iterable[str] = (),
    wait_s: float = 15.0,
) -> Status | None:
    """The server's status once every scout's last delta is merged (scouts wait for acks before exiting)."""
    end = time.monotonic() + wait_s
    st = None
    while time.monotonic() < end:
        st = _status(session, cfg.map, 2.0, trust)
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


def _status_json(st: Status | None) -> dict[str, Any]:
    return {"error": "no status reply"} if st is None else st.to_json()


# each scout's estimate against truth (scout_agent.run / evaluate), as its summary reports them
ERROR_KEYS = ("sensors", "localization", "pos_error_max_m", "pos_error_final_m", "yaw_error_max_deg",
              "yaw_error_start_deg", "yaw_error_growth_max_deg", "nees_pos_mean", "inside_3sigma_frac",
              "localization_stats")  # fmt: skip


def _map_truth(
    session: zenoh.Session, cfg: MissionConfig, local_maps: dict[str, Path]
) -> tuple[float | None, int, dict[str, float | None]]:
    """The shared map's elevation RMSE against the terrain's truth over the cells with data (lunar scene), its
    cell count, and each scout's own map's (`local_maps`: the scouts' saved `.npz`)."""
    if cfg.scene != "lunar":
        return None, 0, {}
    terrain = build_world(ScoutRunConfig(scene="lunar", seed=cfg.seed, field_m=cfg.field_m)).terrain
    xa, ya, xb, yb = terrain.extent
    try:
        grid = query_region(
            session, cfg.map, (xa, ya, xb, yb), ClientConfig(connect=()), layers=("elevation", "height")
        )
    except PlannerError as exc:
        print(f"warning: no map elevation RMSE ({exc})", file=sys.stderr)
        return None, 0, {}
    own = {sid: map_elevation_rmse(read_npz(p), terrain)[0] for sid, p in local_maps.items() if p.is_file()}
    return (*map_elevation_rmse(grid, terrain), own)


def _plot(session: zenoh.Session, cfg: MissionConfig, run_dir: Path, summary: dict[str, Any]) -> str | None:
    """`map.png`: the shared map's layers with the scouts' routes and the planned path."""
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
    try:  # Rerun is optional here: without it the mission writes no recordings of its own
        from psrmap.viz import log_mission_context
    except ImportError:
        return
    log_mission_context(cfg, run_dir / "recordings" / "mission.rrd", recording_id)
