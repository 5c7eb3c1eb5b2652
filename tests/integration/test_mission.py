"""A short mission end to end: real router, map server, two scout processes, planner; then its outputs.

Checks that the server's totals equal the sum of what the scouts sent (each scout also keeps its own local
map of exactly what it published), that a plan comes back, and that the recording verifies and holds the
entities every component is expected to log.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from psrmap.mission import (
    MissionError,
    deltas_sent,
    load_config,
    merge_recordings,
    rerun_exe,
    run_mission,
    with_scouts,
)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def mission(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    run_dir = tmp_path_factory.mktemp("mission")
    cfg = with_scouts(load_config(), 2)
    # plan between two points both scouts' first metres explored (scout1 leaves (1.5, 1.5) heading north-east)
    cfg = dataclasses.replace(
        cfg, sim_seconds=14.0, timeout_s=400.0, plan_from=(1.6, 1.6), plan_to=(2.8, 2.8)
    )
    summary = run_mission(cfg, run_dir, progress=False)
    return summary, run_dir


def _local_totals(path: Path) -> dict[str, float]:
    data = np.load(path)
    out: dict[str, float] = {}
    for key in data.files:
        if "/" not in key:
            continue
        layer, stat = key.split("/", 1)
        if stat in ("n", "sum", "work", "dist", "events", "nonfoot"):
            out[key] = float(np.nansum(data[key]))
    return out


def test_scouts_walked_and_published(mission: tuple[dict, Path]) -> None:
    summary, run_dir = mission
    assert set(summary["scouts"]) == {"scout1", "scout2"}
    for s in summary["scouts"].values():
        assert "error" not in s, s
        assert s["fell"] is False
        assert s["distance_m"] > 1.0
        assert deltas_sent(s) > 10 and s["map"]["all_acked"] is True
    st = summary["status"]
    assert st["merged"] == sum(deltas_sent(s) for s in summary["scouts"].values())
    assert st["duplicates"] >= 0 and not st["rejected"]
    assert st["cells"] > 20
    assert (run_dir / "map.db").exists() and (run_dir / "summary.json").exists()
    assert summary["map_png"] == str(run_dir / "map.png") and (run_dir / "map.png").stat().st_size > 10_000
    on_disk = json.loads((run_dir / "summary.json").read_text())
    assert on_disk["status"]["merged"] == st["merged"]


def test_server_totals_equal_sum_of_scouts(mission: tuple[dict, Path]) -> None:
    _, run_dir = mission
    from map_server.merge import Merger
    from map_server.store import MapStore  # reopen the persisted map exactly as a new server would
    from map_server.tiles import TiledMap

    cfg = load_config()
    tiled = TiledMap(cfg.res, 64)
    store = MapStore(str(run_dir / "map.db"), cfg.map, cfg.res, 64)
    store.load(Merger(tiled, cfg.map))
    store.close()
    expected: dict[str, float] = {}
    for npz in sorted(run_dir.glob("scout*_local.npz")):
        for k, v in _local_totals(npz).items():
            expected[k] = expected.get(k, 0.0) + v
    assert expected, "the scouts saved no local maps"
    got = tiled.totals()
    for key, total in expected.items():
        layer, stat = key.split("/", 1)
        assert got[layer][stat] == pytest.approx(total, rel=1e-9, abs=1e-9), key


def test_plan_and_comparison(mission: tuple[dict, Path]) -> None:
    summary, _ = mission
    plan = summary["plan"]
    assert "error" not in plan, plan
    assert len(plan["path"]) >= 2 and plan["length_m"] > 0 and np.isfinite(plan["cost"])
    assert "breakdown" in plan
    comparison = summary["comparison"]
    assert "error" not in comparison, comparison
    names = {r["name"] for r in comparison["routes"]}
    assert {"scout1", "scout2"} <= names


def test_recording_verifies_and_holds_entities(mission: tuple[dict, Path]) -> None:
    summary, run_dir = mission
    rrd = Path(summary["recording"])
    assert rrd.exists()
    res = subprocess.run(
        [*rerun_exe(), "rrd", "verify", str(rrd)], capture_output=True, text=True, check=False
    )
    assert res.returncode == 0, res.stderr[-2000:]
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd)
    recs = reader.recordings()
    assert [r.recording_id for r in recs] == [summary["recording_id"]]
    entities = {chunk.entity_path for chunk in reader.stream()}
    prefixes = ["/world/terrain", "/world/scouts/scout1", "/world/scouts/scout2", "/map/", "/plans/"]
    for prefix in prefixes:
        assert any(e.startswith(prefix) for e in entities), (prefix, sorted(entities)[:40])
    assert reader.blueprints(), "no default blueprint in the mission recording"


def test_bad_config_is_rejected_with_reason(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[terrain]\nscene = "mars"\n[[scouts]]\nid = "a"\nstart = [1, 1, 0]\ngoal = [2, 2]\n')
    with pytest.raises(MissionError, match="scenes: lunar, ramps"):
        load_config(bad)
    bad.write_text("[[scouts]]\nid = 'a'\nstart = [1, 1]\ngoal = [2, 2]\n")
    with pytest.raises(MissionError, match=r"\[x, y, yaw\]"):
        load_config(bad)
    bad.write_text("[mission]\nsim_second = 10\n")
    with pytest.raises(
        MissionError, match=r"unknown key\(s\) \['sim_second'\] in \[mission\]; keys: .*sim_seconds"
    ):
        load_config(bad)
    with pytest.raises(MissionError, match="at least 1"):
        with_scouts(load_config(), 0)


def test_merge_recordings_without_parts_returns_none(tmp_path: Path) -> None:
    (tmp_path / "recordings").mkdir()
    assert merge_recordings(tmp_path) is None


def test_the_mission_runs_secured_by_default(mission: tuple[dict, Path]) -> None:
    _, run_dir = mission
    router = json.loads((run_dir / "secure" / "router.json5").read_text())
    assert router["access_control"]["default_permission"] == "deny"
    assert (run_dir / "secure" / "scout1.json5").is_file() and (run_dir / "secure" / "server.json5").is_file()


def test_a_mission_on_an_existing_secure_folder(tmp_path: Path) -> None:
    from psrmap.secure import secure_init

    cfg = dataclasses.replace(with_scouts(load_config(), 1), sim_seconds=6.0, rrd=False, timeout_s=300.0,
                              plan_from=(1.6, 1.6), plan_to=(2.0, 2.0))
    lay = secure_init(tmp_path / "sec", cfg.map, [s.id for s in cfg.scouts], ["planner"])
    bad = dataclasses.replace(cfg, zenoh_config=str(tmp_path / "nowhere" / "router.json5"))
    with pytest.raises(MissionError, match="missing"):
        run_mission(bad, tmp_path / "bad", progress=False)
    summary = run_mission(dataclasses.replace(cfg, zenoh_config=str(lay.router)), tmp_path / "run", progress=False)
    assert summary["status"]["merged"] == deltas_sent(summary["scouts"]["scout1"]) > 0
    assert not (tmp_path / "run" / "secure").exists()  # no fresh credentials: the given ones were used
