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
    MissionConfig,
    MissionError,
    deltas_sent,
    load_config,
    merge_recordings,
    rerun_exe,
    with_scouts,
)
from psrmap.mission.run import run_mission

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
    from psrmap_mapcore import TiledMap

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


def _short_mission(scouts: int, sim_seconds: float, **changes) -> MissionConfig:
    """The default mission cut short: `scouts` scouts, no recordings, a plan over their first metres."""
    base = {"rrd": False, "timeout_s": 400.0, "plan_from": (1.6, 1.6), "plan_to": (2.8, 2.8)}
    return dataclasses.replace(
        with_scouts(load_config(), scouts), sim_seconds=sim_seconds, **(base | changes)
    )


def test_a_mission_on_an_existing_secure_folder(tmp_path: Path) -> None:
    from psrmap.secure import secure_init

    cfg = _short_mission(1, 6.0, plan_to=(2.0, 2.0))
    lay = secure_init(tmp_path / "sec", cfg.map, [s.id for s in cfg.scouts], ["planner"])
    bad = dataclasses.replace(cfg, zenoh_config=str(tmp_path / "nowhere" / "router.json5"))
    with pytest.raises(MissionError, match="missing"):
        run_mission(bad, tmp_path / "bad", progress=False)
    summary = run_mission(
        dataclasses.replace(cfg, zenoh_config=str(lay.router)), tmp_path / "run", progress=False
    )
    assert summary["status"]["merged"] == deltas_sent(summary["scouts"]["scout1"]) > 0
    assert not (tmp_path / "run" / "secure").exists()  # no fresh credentials: the given ones were used


def _recording_index(rrd: Path) -> tuple[dict[str, set[str]], dict[str, bool]]:
    """entity -> timelines its temporal chunks carry; entity -> has static data."""
    from rerun.chunk import RrdReader

    timelines: dict[str, set[str]] = {}
    static: dict[str, bool] = {}
    for chunk in RrdReader(rrd).stream():
        e = chunk.entity_path.rstrip("/") or "/"
        if chunk.is_static:
            static[e] = True
        else:
            timelines.setdefault(e, set()).update(chunk.timeline_names)
    return timelines, static


def _views(container):  # every view of a blueprint container, depth first
    for item in getattr(container, "contents", []):
        if hasattr(item, "origin"):
            yield item
        else:
            yield from _views(item)


def test_every_blueprint_entity_has_data_on_sim_time(mission: tuple[dict, Path]) -> None:
    """The default view (timeline sim_time) shows scouts, map, plans together: every entity the default
    blueprint shows has data on sim_time (or static data, shown on every timeline), and every view's
    contents match entities of the recording."""
    from psrmap.viz import default_blueprint
    from psrmap_common.recording import TIMELINE

    summary, _ = mission
    timelines, static = _recording_index(Path(summary["recording"]))
    entities = set(timelines) | set(static)
    for e, tls in timelines.items():
        assert TIMELINE in tls, f"{e} is logged on {sorted(tls)}, not on {TIMELINE}"
    blueprint = default_blueprint(sorted(summary["scouts"]))
    assert blueprint.time_panel is not None
    for view in _views(blueprint.root_container):
        origin = str(view.origin).strip("/")
        patterns = view.contents if isinstance(view.contents, list) else [view.contents]
        for pat in patterns:
            pat = str(pat).replace("$origin", origin).strip("/")
            if pat.endswith("**"):
                base = "/" + pat[:-2].rstrip("/")
                hits = [e for e in entities if e == base or e.startswith(base.rstrip("/") + "/")]
            else:
                hits = [e for e in entities if e == "/" + pat]
            assert hits, f"view {view.name!r}: nothing in the recording matches {pat!r}"


def _last_value(rrd: Path, entity: str, column: str) -> list:
    from rerun.chunk import RrdReader

    best, best_t = None, -1
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        names = rb.schema.names
        ts = rb.column(names.index("sim_time")).cast("int64").to_pylist()
        vals = rb.column(names.index(column)).to_pylist()
        for t, v in zip(ts, vals, strict=True):
            if v is not None and t >= best_t:
                best, best_t = v, t
    assert best is not None, f"{entity} has no {column}"
    return best


def test_map_layers_lie_under_the_trajectories(mission: tuple[dict, Path]) -> None:
    """Read the recording back and place every mapped elevation cell the way Rerun draws a GridMap
    (translation = the image's lower-left corner, image row 0 drawn at the top): each lies under a scout's
    true trajectory (within a leg's reach + a cell), and the mirrored placement would not."""
    from rerun.chunk import RrdReader

    summary, _ = mission
    rrd = Path(summary["recording"])
    trail = np.concatenate(
        [
            np.asarray(_last_value(rrd, f"/world/scouts/{sid}/trajectory", "LineStrips3D:strips")[0])[:, :2]
            for sid in summary["scouts"]
        ]
    )
    tiles = sorted(
        {c.entity_path for c in RrdReader(rrd).stream() if c.entity_path.startswith("/map/elevation/")}
    )
    assert tiles
    right, mirrored = [], []
    for tile in tiles:
        data = np.asarray(_last_value(rrd, tile, "GridMap:data")[0], dtype=np.uint8)
        fmt = _last_value(rrd, tile, "GridMap:format")[0]
        cell = float(np.ravel(_last_value(rrd, tile, "GridMap:cell_size"))[0])
        x0, y0, _ = np.ravel(_last_value(rrd, tile, "GridMap:translation"))
        h, w = int(fmt["height"]), int(fmt["width"])
        img = data.reshape(h, w, 4)
        rows, cols = np.nonzero(img[..., 3] > 0)
        xs = x0 + (cols + 0.5) * cell
        right.append(np.column_stack([xs, y0 + (h - 1 - rows + 0.5) * cell]))
        mirrored.append(np.column_stack([xs, y0 + (rows + 0.5) * cell]))

    def dist(pts: np.ndarray) -> np.ndarray:
        return np.min(np.linalg.norm(pts[:, None, :] - trail[None, :, :], axis=2), axis=1)

    d_right, d_mirror = dist(np.concatenate(right)), dist(np.concatenate(mirrored))
    assert len(d_right) >= 5
    assert d_right.max() < 0.8, d_right.max()
    assert np.median(d_mirror) > 2.0, np.median(d_mirror)


def test_a_mission_on_a_sharded_map(tmp_path: Path) -> None:
    """`psrmap mission --shards 2`: two map-server shards (secured, each its own credentials and file); every
    scout delta lands exactly once over the shards, the plan queries both, and the shards' files together
    hold exactly the scouts' own maps."""
    from map_server.merge import Merger
    from map_server.store import MapStore
    from protocol.partition import Partition
    from psrmap_mapcore import TiledMap

    # 4-cell (1.6 m) tiles: the scouts' first metres cross several, so both shards get cells (at the default
    # 64 cells, 25.6 m, the whole 20 m field is one tile and one shard would hold everything)
    cfg = _short_mission(2, 10.0, shards=2, tile=4)
    with pytest.raises(MissionError, match="1 .one server. to 16"):
        run_mission(dataclasses.replace(cfg, shards=0), tmp_path / "bad", progress=False)
    with pytest.raises(MissionError, match="power of two"):
        run_mission(dataclasses.replace(cfg, tile=48), tmp_path / "bad", progress=False)
    run_dir = tmp_path / "run"
    summary = run_mission(cfg, run_dir, progress=False)
    sent = sum(
        deltas_sent(s) for s in summary["scouts"].values()
    )  # parts: a delta split over shards counts per part
    st = summary["status"]
    assert st["merged"] == sent > 0 and not st["rejected"]
    assert set(summary["servers"]) == {"server0", "server1"}
    assert "error" not in summary["plan"], summary["plan"]
    assert (run_dir / "secure" / "server1.json5").exists()
    part = Partition(2, 4)
    got: dict[str, dict[str, float]] = {}
    for i in range(2):
        tiled = TiledMap(cfg.res, 4)
        store = MapStore(str(run_dir / f"map.shard{i}.db"), cfg.map, cfg.res, 4)
        store.load(Merger(tiled, cfg.map))
        store.close()
        for name, g in tiled.grids.items():  # each shard holds only the tiles it owns
            tiles = np.array(list(g.slots), np.int64).reshape(-1, 2)
            assert (part.shard_of_tiles(tiles[:, 0], tiles[:, 1]) == i).all(), (i, name)
        assert tiled.cells > 0, f"shard {i} holds no cells"
        for layer, stats in tiled.totals().items():
            for s, v in stats.items():
                got.setdefault(layer, {}).setdefault(s, 0.0)
                got[layer][s] += v
    expected: dict[str, float] = {}
    for npz in sorted(run_dir.glob("scout*_local.npz")):
        for k, v in _local_totals(npz).items():
            expected[k] = expected.get(k, 0.0) + v
    assert expected
    for key, total in expected.items():
        layer, stat = key.split("/", 1)
        assert got[layer][stat] == pytest.approx(total, rel=1e-9, abs=1e-9), key
