"""Each component is `run(config) -> Summary` on a frozen config: the CLI and the mission share them."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest
import zenoh

from consumer_planner.component import CompareConfig, MapSource, PlanConfig, compare, plan
from map_server.component import ServerSummary
from map_server.component import run as run_server
from map_server.errors import MapServerConfigError
from map_server.service import ServerConfig
from protocol import encode
from protocol.keys import delta_key
from protocol.messages import CellDelta
from protocol.testing import layer_cells
from psrmap_common.query import get_status
from psrmap_common.session import zenoh_config
from psrmap_mapcore import TiledMap, write_npz


def test_server_component_serves_until_stopped_and_reports_typed_totals(router, tmp_path):
    stop = threading.Event()
    up = threading.Event()
    cfg = ServerConfig(map_id="c1", res=0.4, db=str(tmp_path / "m.db"), connect=(router,))
    out: list[ServerSummary] = []
    t = threading.Thread(target=lambda: out.append(run_server(cfg, stop, on_up=lambda _s: up.set())))
    t.start()
    try:
        assert up.wait(20)
        with zenoh.open(zenoh_config(connect=[router], mode="client")) as s:
            for seq in range(3):
                layers = {"slip": layer_cells("slip", [seq, seq + 1], [0, 0])}
                s.put(delta_key("c1", "a"), encode(CellDelta("c1", "a", 1, seq, 0.0, 0.4, layers)))
            for _ in range(100):
                st = get_status(s, "c1", 1.0)
                if st is not None and st.merged == 3:
                    break
    finally:
        stop.set()
        t.join(30)
    (summary,) = out
    assert (summary.merged, summary.cells, summary.exit_code, summary.failure) == (3, 4, 0, None)


def test_server_component_names_a_bad_config():
    with pytest.raises(MapServerConfigError, match="need a cell size > 0"):
        run_server(ServerConfig(map_id="c1", res=0.0, connect=("tcp/127.0.0.1:1",)), threading.Event())


def test_planner_components_on_a_saved_map_match_the_cli_json(tmp_path, capsys):
    from psrmap.cli import main

    m = TiledMap(0.5)
    ix, iy = np.meshgrid(np.arange(20), np.arange(20))
    k = ix.size
    ones = np.ones(k)
    m.merge({"cot": {"ix": ix.ravel().astype(np.int32), "iy": iy.ravel().astype(np.int32),
                     "work": 1.0 + (ix.ravel() > 10), "dist": ones, "n": 5 * ones}})  # fmt: skip
    npz = write_npz(tmp_path / "m.npz", m.dense(0, 0, 19, 19))
    source = MapSource(npz=str(npz))
    got = plan(PlanConfig(source, (1.0, 1.0), (8.0, 9.0)))
    assert got.routes[0].path[0].tolist() == [1.25, 1.25] and got.goal_moved_m == 0.0
    assert main(["plan", "--npz", str(npz), "--from", "1,1", "--to", "8,9", "--json"]) == 0
    import json

    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(got.to_json()))
    both = compare(CompareConfig(source, (("a", ((1.0, 1.0), (8.0, 9.0))), ("b", ((1.0, 1.0), (1.0, 9.0))))))
    assert [r.name for r in both.routes] == ["a", "b"] and both.to_json()["routes"][1]["name"] == "b"


def test_mission_builds_scout_configs_as_the_cli_does(tmp_path):
    from psrmap.cli import build_parser
    from psrmap.mission import load_config
    from psrmap.mission.components import scout_config
    from scout_agent.cli import scout_config as cli_scout_config

    cfg = load_config()
    assert cfg.holdable_patches  # the default mission maps the paper's field (holdable patches)
    s = cfg.scouts[0]
    ours = scout_config(cfg, s, "tcp/127.0.0.1:7447", tmp_path, None)
    argv = ["scout", "--scout-id", s.id, "--map", cfg.map, "--res", str(cfg.res), "--connect", "tcp/127.0.0.1:7447",
            "--scene", cfg.scene, "--speed", str(cfg.speed), "--sim-seconds", str(cfg.sim_seconds),
            "--delta-hz", str(cfg.rate_hz), "--save-map", str(tmp_path / f"{s.id}_local.npz"),
            "--outbox", str(tmp_path / f"{s.id}_outbox.db"), "--seed", str(cfg.seed),
            "--slippery-patches", str(cfg.slippery_patches), *(["--holdable-patches"] if cfg.holdable_patches else []),
            "--start=" + ",".join(map(str, s.start)),
            "--goal=" + ",".join(map(str, s.goal)), *("--via=" + ",".join(map(str, v)) for v in s.via)]  # fmt: skip
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    theirs = cli_scout_config(args)
    assert dataclasses.replace(theirs, rrd_terrain=False, rrd=ours.rrd) == ours
