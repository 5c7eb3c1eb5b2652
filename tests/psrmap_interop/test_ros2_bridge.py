"""`psrmap ros2` against a real router and map server: what it puts on Zenoh is decoded here with `rosbags`
from the official message definitions (written out below, independently of the encoder's shipped copies),
and checked cell for cell against a `map` query; the key expressions, the attachment and the liveliness
tokens are checked against rmw_zenoh's layout."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest
import xxhash
import zenoh
from helpers import wait_until
from test_rmw_zenoh_wire import parse_qos_field, read_rmw_zenoh_attachment

from consumer_planner.client import ClientConfig, query_region
from consumer_planner.costs import build_costs
from protocol.codec import decode, encode
from protocol.keys import delta_key, status_key
from protocol.messages import CellDelta
from protocol.testing import layer_cells
from psrmap.ros2 import BridgeConfig, run_bridge

pytestmark = pytest.mark.slow

# grid_map_msgs (ROS 2 branch of ANYbotics/grid_map), field for field
GRID_MAP_MSG = """std_msgs/Header header
GridMapInfo info
string[] layers
string[] basic_layers
std_msgs/Float32MultiArray[] data
uint16 outer_start_index
uint16 inner_start_index
"""
GRID_MAP_INFO_MSG = """float64 resolution
float64 length_x
float64 length_y
geometry_msgs/Pose pose
"""


@pytest.fixture(scope="module")
def store():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    types = get_types_from_msg(GRID_MAP_INFO_MSG, "grid_map_msgs/msg/GridMapInfo")
    types.update(get_types_from_msg(GRID_MAP_MSG, "grid_map_msgs/msg/GridMap"))
    ts.register(types)
    return ts


def _fill(client: zenoh.Session, map_id: str) -> None:
    rng = np.random.default_rng(3)
    ix, iy = np.meshgrid(np.arange(2, 9), np.arange(-1, 5))
    ix, iy = ix.ravel(), iy.ravel()
    ones = np.ones(ix.size)
    z = 0.02 * ix + 0.01 * iy  # a gentle plane: every cell passable
    zero = np.zeros(ix.size)
    layers = {
        "elevation": {
            "ix": ix,
            "iy": iy,
            "n": ones,
            "sum": z,
            "sumsq": z * z,
            "sx": zero,
            "sy": zero,
            "sxx": zero,
            "syy": zero,
            "sxy": zero,
            "sxz": zero,
            "syz": zero,
            "min": z,
            "max": z,
        },
        "slip": {"ix": ix, "iy": iy, "n": 10 * ones, "events": rng.integers(0, 3, ix.size).astype(float)},
        "cot": layer_cells("cot", ix, iy, rng, scale=1.0)
        | {"work": rng.uniform(1.0, 3.0, ix.size), "dist": ones},
    }
    client.put(delta_key(map_id, "s1"), encode(CellDelta(map_id, "s1", 1, 0, 3.0, 0.4, layers)))
    end = time.monotonic() + 10
    while time.monotonic() < end:
        for r in client.get(status_key(map_id), timeout=2.0):
            if r.ok is not None and decode(r.ok.payload.to_bytes(), expected_type="status").merged >= 1:
                return
        time.sleep(0.1)
    raise AssertionError("the delta was not merged")


def test_bridge_publishes_grid_map_cost_and_path_as_rmw_zenoh_does(router, served_map, store) -> None:
    map_id, box = "rosmap", (0.0, -1.0, 4.0, 2.4)
    with served_map(map_id, 0.4) as (_, client):
        _fill(client, map_id)
        got: dict[str, list] = {}

        def on(sample: zenoh.Sample) -> None:
            att = sample.attachment.to_bytes() if sample.attachment is not None else None
            got.setdefault(str(sample.key_expr), []).append((sample.payload.to_bytes(), att))

        sub = client.declare_subscriber("0/psrmap/**", on)
        stop = threading.Event()
        cfg = BridgeConfig(map_id, box, (router,), plan_from=(1.0, -0.2), plan_to=(3.4, 1.8))
        t = threading.Thread(target=lambda: run_bridge(cfg, stop, log=lambda *a: None), daemon=True)
        t.start()
        try:
            end = time.monotonic() + 20
            while time.monotonic() < end and len(got) < 3:
                time.sleep(0.1)
            tokens = [
                str(r.ok.key_expr) for r in client.liveliness().get("@ros2_lv/0/**", timeout=3.0) if r.ok
            ]
        finally:
            stop.set()
            t.join(timeout=20)
            sub.undeclare()
        grid = query_region(client, map_id, box, ClientConfig(connect=(router,)))

    expect = {
        "psrmap/grid_map": "grid_map_msgs/msg/GridMap",
        "psrmap/cost": "nav_msgs/msg/OccupancyGrid",
        "psrmap/plan": "nav_msgs/msg/Path",
    }
    keys = {}
    for topic, typename in expect.items():
        pkg, _, name = typename.split("/")
        key = f"0/{topic}/{pkg}::msg::dds_::{name}_/{store.hash_rihs01(typename)}"
        assert key in got, (key, list(got))
        keys[topic] = key
        payload, att = got[key][0]
        assert payload[:4] == b"\x00\x01\x00\x00"  # CDR little endian encapsulation
        assert att is not None and len(att) == 33  # int64, int64, LEB128 length 16, 16-byte GID
        seq, stamp, gid = read_rmw_zenoh_attachment(att)
        assert seq == 1 and abs(stamp - time.time_ns()) < 60e9
        # the publisher's liveliness token: MP entity, mangled names, same type and hash; its GID hashes it
        token = next(tok for tok in tokens if f"/MP/%/%/psrmap_bridge/%{topic.replace('/', '%')}/" in tok)
        assert (
            token.startswith("@ros2_lv/0/")
            and f"/{pkg}::msg::dds_::{name}_/{store.hash_rihs01(typename)}/" in token
        )
        # its QoS field as rmw_zenoh parses it: reliable, transient local, keep last 1 (depth 42 is the default)
        assert parse_qos_field(token.rsplit("/", 1)[1]) == {"reliability": 1, "durability": 1, "history": 1,
                                                             "depth": 1}  # fmt: skip
        h = xxhash.xxh3_128_intdigest(token.encode())
        assert gid == (h & (2**64 - 1)).to_bytes(8, "little") + (h >> 64).to_bytes(8, "little")
    assert any("/NN/%/%/psrmap_bridge" in tok for tok in tokens)

    # GridMap: every layer's value and count, cell for cell, in grid_map's index convention
    msg = store.deserialize_cdr(got[keys["psrmap/grid_map"]][0][0], "grid_map_msgs/msg/GridMap")
    res, w, h = msg.info.resolution, grid.w, grid.h
    assert res == pytest.approx(0.4) and msg.info.length_x == pytest.approx(w * res)
    xa, ya, _, _ = grid.bounds_m()
    assert msg.info.pose.position.x == pytest.approx(xa + w * res / 2)
    for name, arr in zip(msg.layers, msg.data, strict=True):
        assert [d.label for d in arr.layout.dim] == ["column_index", "row_index"]
        m = np.asarray(arr.data, dtype=np.float32).reshape(arr.layout.dim[0].size, arr.layout.dim[1].size)
        base = name.removesuffix("_count")
        want = grid.count(base) if name.endswith("_count") else grid.value(base)
        for iy in range(h):
            for ix in range(w):
                # cell (i, j): x = centre + length_x/2 - (i + .5) res  ->  i = w-1-ix, j = h-1-iy; column-major
                i, j = w - 1 - ix, h - 1 - iy
                v = m[j, i]
                assert (np.isnan(v) and np.isnan(want[iy, ix])) or v == pytest.approx(want[iy, ix], rel=1e-6)
    assert {"elevation", "elevation_count", "slip", "cot"} <= set(msg.layers)

    occ = store.deserialize_cdr(got[keys["psrmap/cost"]][0][0], "nav_msgs/msg/OccupancyGrid")
    assert (occ.info.width, occ.info.height) == (w, h) and occ.info.origin.position.x == pytest.approx(xa)
    data = np.asarray(occ.data, dtype=np.int8).reshape(h, w)
    costs = build_costs(grid)
    assert ((data == -1) == (~costs.known & np.isfinite(costs.cost))).all()
    assert ((data == 100) == ~np.isfinite(costs.cost)).all()
    known = costs.known & np.isfinite(costs.cost)
    assert (np.diff(data[known][np.argsort(costs.cost[known])]) >= 0).all()  # ordered like the costs

    path = store.deserialize_cdr(got[keys["psrmap/plan"]][0][0], "nav_msgs/msg/Path")
    pts = [(p.pose.position.x, p.pose.position.y) for p in path.poses]
    assert (
        len(pts) >= 2
        and pts[0] == pytest.approx((1.0, -0.2), abs=0.3)
        and pts[-1] == pytest.approx((3.4, 1.8), abs=0.3)
    )


def test_bridge_refuses_bad_options_with_the_valid_form(capsys) -> None:
    from psrmap.cli import main

    for argv, msg in (
        (["--box", "1,1,0,0"], "x0 <= x1"),
        (["--box", "0,0,1,1", "--rate", "0"], "positive"),
        (["--box", "0,0,1,1", "--plan-from", "1,1"], "go together"),
        (["--box", "0,0,1,1", "--prefix", "psrmap"], "starts with '/'"),
        (["--box", "0,0,1,1", "--resync-s", "nan"], "period > 0"),
    ):
        with pytest.raises(SystemExit) as exc:
            main(["ros2", "--map", "m", "--connect", "tcp/127.0.0.1:1", *argv])
        assert exc.value.code == 2
        assert msg in capsys.readouterr().err


def test_query_out_writes_geotiff_and_mcap(router, served_map, tmp_path, capsys) -> None:
    import rasterio
    from rosbags.rosbag2 import Reader

    from psrmap.cli import main
    from psrmap_interop.ros2_messages import grid_map_layers, typestore

    map_id = "qmap"
    with served_map(map_id, 0.4) as (_, client):
        _fill(client, map_id)
        grid = query_region(client, map_id, (0.0, -1.0, 4.0, 2.4), ClientConfig(connect=(router,)))
        common = ["query", "--map", map_id, "--connect", router, "--box", "0,-1,4,2.4"]
        assert main([*common, "--out", str(tmp_path / "q.tif"), "--origin=-89.5,10"]) == 0
        assert main([*common, "--out", str(tmp_path / "bag"), "--format", "mcap"]) == 0
        out = capsys.readouterr().out
    assert '"format": "geotiff"' in out and '"format": "mcap"' in out
    with rasterio.open(tmp_path / "q.tif") as ds:
        bands = {d: i + 1 for i, d in enumerate(ds.descriptions)}
        elev = ds.read(bands["elevation value"])[::-1]  # back to row = iy (south first)
        np.testing.assert_allclose(elev, grid.value("elevation"), equal_nan=True, rtol=1e-6)
        assert "South Polar" in ds.crs.to_wkt()
    with Reader(
        tmp_path / "bag"
    ) as reader:  # the one writer psrmap export uses: the map and the planner's cost
        msgs = {c.topic: (c, raw) for c, _, raw in reader.messages()}
    assert set(msgs) == {"/psrmap/grid_map", "/psrmap/cost"}
    conn, raw = msgs["/psrmap/grid_map"]
    layers = grid_map_layers(typestore().deserialize_cdr(raw, conn.msgtype))
    np.testing.assert_allclose(layers["cot"], grid.value("cot"), equal_nan=True, rtol=1e-6)


def test_a_late_subscriber_gets_the_last_map_from_the_cache(router, served_map, store) -> None:
    """Transient local: a subscriber that joins after the map was published (as RViz started later would,
    through rmw_zenoh's advanced subscriber with history) still receives it."""
    import zenoh.ext as zext

    map_id = "latemap"
    with served_map(map_id, 0.4) as (_, client):
        _fill(client, map_id)
        stop = threading.Event()
        cfg = BridgeConfig(map_id, (0.0, -1.0, 4.0, 2.4), (router,))
        done: list[dict] = []
        t = threading.Thread(
            target=lambda: done.append(run_bridge(cfg, stop, log=lambda *a: None)), daemon=True
        )
        t.start()
        try:
            time.sleep(3.0)  # the bridge has published by now; nobody was listening
            got: list[bytes] = []
            conf = zenoh.Config()
            conf.insert_json5("mode", '"client"')
            conf.insert_json5("connect/endpoints", f'["{router}"]')
            conf.insert_json5("scouting/multicast/enabled", "false")
            with zenoh.open(conf) as late:
                key = f"0/psrmap/grid_map/grid_map_msgs::msg::dds_::GridMap_/{store.hash_rihs01('grid_map_msgs/msg/GridMap')}"
                sub = zext.declare_advanced_subscriber(
                    late,
                    key,
                    lambda s: got.append(s.payload.to_bytes()),
                    history=zext.HistoryConfig(detect_late_publishers=True, max_samples=1),
                )
                end = time.monotonic() + 10
                while not got and time.monotonic() < end:
                    time.sleep(0.1)
                sub.undeclare()
        finally:
            stop.set()
            t.join(timeout=20)
    assert got, "the late subscriber received nothing"
    msg = store.deserialize_cdr(got[0], "grid_map_msgs/msg/GridMap")
    assert "elevation" in msg.layers and done and done[0]["published"]["grid_map"] == 1


def _put_cells(client: zenoh.Session, map_id: str, seq: int, ix: np.ndarray, iy: np.ndarray) -> None:
    rng = np.random.default_rng(seq)
    layers = {
        "cot": layer_cells("cot", ix, iy, rng, scale=1.0)
        | {"work": np.ones(ix.size), "dist": np.ones(ix.size)}
    }
    client.put(delta_key(map_id, "s2"), encode(CellDelta(map_id, "s2", 1, seq, 4.0 + seq, 0.4, layers)))


def _merged(client: zenoh.Session, map_id: str, n: int) -> None:
    end = time.monotonic() + 10
    while time.monotonic() < end:
        for r in client.get(status_key(map_id), timeout=2.0):
            if r.ok is not None and decode(r.ok.payload.to_bytes(), expected_type="status").merged >= n:
                return
        time.sleep(0.05)
    raise AssertionError(f"{n} deltas were not merged")


def _grid_maps_seen(client: zenoh.Session) -> list[int]:
    """A list that grows by one with every GridMap the bridge publishes (any domain; ROS 2 key layout)."""
    seen: list[int] = []
    client.declare_subscriber("*/psrmap/grid_map/**", lambda s: seen.append(len(seen)))
    return seen


def _start_bridge(cfg: BridgeConfig, stop: threading.Event) -> tuple[threading.Thread, list[dict]]:
    """The bridge in a thread; its summary lands in the returned list when `stop` is set."""
    done: list[dict] = []
    t = threading.Thread(target=lambda: done.append(run_bridge(cfg, stop, log=lambda *a: None)), daemon=True)
    t.start()
    return t, done


def _bridge_publishing(
    cfg: BridgeConfig, stop: threading.Event, maps: list[int]
) -> tuple[threading.Thread, list[dict]]:
    """`_start_bridge`, returning once the bridge's first GridMap is on the wire (`maps` counts them)."""
    seen = len(maps)
    t, done = _start_bridge(cfg, stop)
    if not wait_until(lambda: len(maps) > seen):
        stop.set()
        t.join(timeout=20)
        raise AssertionError("the bridge published no first map")
    return t, done


def test_the_bridge_requeries_only_when_a_tile_in_its_box_changed(router, served_map) -> None:
    """Issue 16: the bridge follows the servers' tile-change notices. A change 100 m away (another tile)
    costs no query and publishes nothing; a change inside the box is published within a tick."""
    map_id = "watchmap"
    with served_map(map_id, 0.4) as (_, client):
        _fill(client, map_id)  # cells 2..8 x -1..4: tile (0, 0) and (0, -1)
        stop = threading.Event()
        cfg = BridgeConfig(map_id, (0.0, -1.0, 4.0, 2.4), (router,), rate_hz=10.0, resync_s=60.0)
        maps = _grid_maps_seen(client)
        t, done = _bridge_publishing(cfg, stop, maps)
        try:
            far = np.arange(250, 260)  # 100 m east: tile (3, 0), outside the box
            for seq in range(1, 6):
                _put_cells(client, map_id, seq, far, np.zeros(10, int))
            _merged(client, map_id, 6)
            time.sleep(1.5)  # 15 ticks of the bridge
            stop.set()
            t.join(timeout=20)
            outside = done[0]
            stop.clear()
            t, done = _bridge_publishing(cfg, stop, maps)
            _put_cells(client, map_id, 6, np.array([3, 4]), np.array([1, 1]))  # inside the box
            _merged(client, map_id, 7)
            time.sleep(1.5)
        finally:
            stop.set()
            t.join(timeout=20)
    assert outside["published"]["grid_map"] == 1 and outside["queries"] == 1, outside
    assert outside["changes_in_box"] == 0 and outside["resyncs"] == 0
    inside = done[0]
    assert inside["published"]["grid_map"] == 2 and inside["queries"] == 2, inside
    assert inside["changes_in_box"] >= 1


def test_a_lost_notice_is_caught_by_the_resync(router, tmp_path) -> None:
    """A server that announces no tile changes (changes off: as if every notice were lost): the bridge's
    periodic status check sees its version move and re-queries."""
    from dataclasses import replace

    from map_server.service import MapService, ServerConfig

    map_id = "quietmap"
    cfg_server = replace(ServerConfig(), map_id=map_id, res=0.4, connect=(router,), changes=False)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{router}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    with MapService(cfg_server).start(), zenoh.open(conf) as client:
        time.sleep(0.5)
        _fill(client, map_id)
        stop = threading.Event()
        cfg = BridgeConfig(map_id, (0.0, -1.0, 4.0, 2.4), (router,), rate_hz=10.0, resync_s=0.5)
        maps = _grid_maps_seen(client)
        t, done = _bridge_publishing(cfg, stop, maps)
        try:
            _put_cells(client, map_id, 1, np.array([3]), np.array([1]))
            _merged(client, map_id, 2)
            assert wait_until(lambda: len(maps) >= 2), "the resync did not republish the changed map"
        finally:
            stop.set()
            t.join(timeout=20)
    res = done[0]
    assert res["changes_in_box"] == 0 and res["resyncs"] >= 1 and res["published"]["grid_map"] == 2, res


def test_without_a_box_the_bridge_and_export_cover_the_whole_map_as_it_grows(
    router, served_map, store, tmp_path, capsys
) -> None:
    """No --box: the bridge publishes the cells holding data (the extent in the servers' status), and again,
    wider, when the map grows anywhere; `psrmap query` and `psrmap export --connect` return the same whole map."""
    import rasterio

    from psrmap.cli import main

    map_id, res = "wholemap", 0.4
    key = f"0/psrmap/grid_map/grid_map_msgs::msg::dds_::GridMap_/{store.hash_rihs01('grid_map_msgs/msg/GridMap')}"
    with served_map(map_id, res) as (_, client):
        _fill(client, map_id)  # cells ix 2..8, iy -1..4
        got: list[bytes] = []
        sub = client.declare_subscriber(key, lambda s: got.append(s.payload.to_bytes()))
        stop = threading.Event()
        t, done = _start_bridge(BridgeConfig(map_id, None, (router,), rate_hz=10.0, resync_s=60.0), stop)
        try:
            wait_until(lambda: len(got) >= 1)
            _put_cells(client, map_id, 1, np.array([30]), np.array([7]))  # far east and north: the map grows
            _merged(client, map_id, 2)
            wait_until(lambda: len(got) >= 2)
        finally:
            stop.set()
            t.join(timeout=20)
            sub.undeclare()
        capsys.readouterr()
        assert main(["query", "--map", map_id, "--connect", router]) == 0
        queried = json.loads(capsys.readouterr().out)
        assert main(["export", "--format", "geotiff", "--connect", router, "--map", map_id,
                     "--out", str(tmp_path / "whole.tif")]) == 0  # fmt: skip
    assert done and done[0]["published"]["grid_map"] == 2, done
    assert (queried["ix0"], queried["iy0"], queried["w"], queried["h"]) == (2, -1, 29, 9)
    first, second = (store.deserialize_cdr(b, "grid_map_msgs/msg/GridMap") for b in got[:2])
    # cells 2..8 x -1..4: 7 x 6 cells, centred at x = (2 + 9) / 2 * res, y = (-1 + 5) / 2 * res
    assert (first.info.length_x, first.info.length_y) == pytest.approx((7 * res, 6 * res))
    assert (first.info.pose.position.x, first.info.pose.position.y) == pytest.approx((5.5 * res, 2 * res))
    elev = np.asarray(first.data[list(first.layers).index("elevation")].data)
    assert elev.size == 42 and np.isfinite(elev).all()  # every published cell holds data
    assert (second.info.length_x, second.info.length_y) == pytest.approx((29 * res, 9 * res))  # 2..30 x -1..7
    with rasterio.open(tmp_path / "whole.tif") as ds:
        assert (ds.width, ds.height) == (29, 9)
        assert tuple(ds.transform)[:6] == pytest.approx((res, 0.0, 2 * res, 0.0, -res, 8 * res))
