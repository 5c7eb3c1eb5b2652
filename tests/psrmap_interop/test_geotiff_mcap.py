"""GeoTIFF and rosbag2/MCAP exports read back with rasterio and rosbags: values, nodata, CRS, transform, band
descriptions; one map point found again in the projected Moon frame; the bag's topics and messages."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from psrmap.cli import main

RES = 0.5


@pytest.fixture
def npz(tmp_path: Path) -> Path:
    """A 6 x 8 map: elevation rising north, a slip layer with unknown cells, counts."""
    h, w = 6, 8
    n = np.full((h, w), 4.0)
    n[0, :3] = 0.0  # three unknown cells in the south-west corner
    iy = np.arange(h)[:, None] * np.ones((1, w))
    elev = np.where(n > 0, 0.1 * iy + 0.01 * np.arange(w)[None, :], np.nan)
    arrays = {"res": RES, "ix0": 2, "iy0": -1, "w": w, "h": h, "elevation/n": n, "elevation/value": elev,
              "slip/n": n * 2, "slip/events": np.where(n > 0, 1.0, 0.0)}  # fmt: skip
    path = tmp_path / "map.npz"
    np.savez(path, **arrays)
    return path


def _run(argv: list[str], capsys) -> dict:
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_geotiff_local_frame_reads_back(npz: Path, tmp_path: Path, capsys) -> None:
    import rasterio

    out = tmp_path / "map.tif"
    _run(["export", "--format", "geotiff", "--npz", str(npz), "--out", str(out)], capsys)
    with rasterio.open(out) as ds:
        assert ds.count == 4 and ds.descriptions == (
            "elevation value",
            "elevation count",
            "slip value",
            "slip count",
        )
        assert ds.crs.is_projected is False and "not georeferenced" in ds.tags()["PSRMAP_CRS"]
        assert "LOCAL_CS" in ds.crs.to_wkt()
        assert ds.tags(1)["unit"] == "m" and ds.tags(2)["unit"] == "observations"
        assert math.isnan(ds.nodata)
        # top-left corner = (x of column 0, y of the north edge): ix0 = 2, iy0 = -1, h = 6 at 0.5 m
        assert tuple(ds.transform)[:6] == pytest.approx((RES, 0.0, 1.0, 0.0, -RES, 2.5))
        elev = ds.read(1)
        # the map cell (ix = 2 + 5, iy = -1 + 4) at x = 3.75, y = 1.75: elevation 0.1 * 4 + 0.01 * 5
        r, c = ds.index(3.75, 1.75)
        assert elev[r, c] == pytest.approx(0.45, abs=1e-6)
        assert np.isnan(ds.read(1)[-1, :3]).all() and (ds.read(2)[-1, :3] == 0).all()  # south-west unknown


def test_geotiff_on_the_moon_lands_each_cell_where_it_lies(npz: Path, tmp_path: Path, capsys) -> None:
    import rasterio
    from rasterio.crs import CRS
    from rasterio.warp import transform

    lat, lon, heading = -89.45, 222.7, 30.0
    out = tmp_path / "moon.tif"
    _run(["export", "--format", "geotiff", "--npz", str(npz), "--out", str(out),
          f"--origin={lat},{lon},{heading}"], capsys)  # fmt: skip
    with rasterio.open(out) as ds:
        assert "Moon (2015) - Sphere / Ocentric / South Polar" in ds.crs.to_wkt()
        geo = CRS.from_string("IAU_2015:30100")
        # the file's CRS projects like IAU_2015:30135 itself
        (e0,), (n0,) = transform(geo, ds.crs, [lon], [lat])
        (e1,), (n1,) = transform(geo, CRS.from_string("IAU_2015:30135"), [lon], [lat])
        assert (e0, n0) == pytest.approx((e1, n1), abs=1e-6)
        # the map point (3.75, 1.75): its pixel centre, projected, then back to latitude/longitude: its great-circle
        # distance and bearing from the origin are the map point's distance and direction (heading applied)
        x, y = 3.75, 1.75
        elev = ds.read(1)
        hit = None
        for r in range(ds.height):
            for c in range(ds.width):
                E, N = ds.xy(r, c)
                dist = math.hypot(E - e0, N - n0)
                if abs(dist - math.hypot(x, y) * 1.0) < 0.3:
                    ang = math.degrees(math.atan2(N - n0, E - e0)) - heading
                    if abs((ang - math.degrees(math.atan2(y, x)) + 180) % 360 - 180) < 4:
                        hit = (r, c, E, N)
        assert hit is not None
        r, c, E, N = hit
        assert elev[r, c] == pytest.approx(0.45, abs=1e-6)
        (lon_p,), (lat_p,) = transform(ds.crs, geo, [E], [N])
        R = 1_737_400.0
        p1, p2 = math.radians(lat), math.radians(lat_p)
        dl = math.radians(lon_p - lon)
        ground = R * math.acos(
            min(1.0, math.sin(p1) * math.sin(p2) + math.cos(p1) * math.cos(p2) * math.cos(dl))
        )
        assert ground == pytest.approx(math.hypot(x, y), abs=0.05)  # metres on the Moon = metres in the map


def test_export_refuses_bad_origin_and_existing_bag(npz: Path, tmp_path: Path, capsys) -> None:
    for argv, msg in (
        (["--format", "geotiff", "--out", str(tmp_path / "a.tif"), "--origin=10,0"], "-90 <= lat < -60"),
        (["--format", "geotiff", "--out", str(tmp_path / "a.tif"), "--origin=x"], "LAT,LON[,HEADING]"),
        (["--format", "mcap", "--out", str(tmp_path)], "new folder"),
    ):
        with pytest.raises(SystemExit) as exc:
            main(["export", "--npz", str(npz), *argv])
        assert exc.value.code == 2 and msg in capsys.readouterr().err


def test_mcap_export_reads_back_with_rosbags(npz: Path, tmp_path: Path, capsys) -> None:
    from rosbags.rosbag2 import Reader

    from psrmap_interop.ros2_messages import grid_map_layers, typestore
    from psrmap_mapcore import read_npz

    run = tmp_path / "run"
    run.mkdir()
    summary = {"scouts": {"scout1": {"path_estimate": [[0.0, 1.0, 0.0, 0.3], [1.0, 1.2, 0.1, 0.3], [2.0, 1.4, 0.2, 0.31]]}},
               "plan": {"path": [[1.25, -0.25], [4.75, 1.75]]}}  # fmt: skip
    (run / "summary.json").write_text(json.dumps(summary))
    bag = tmp_path / "bag"
    _run(["export", "--format", "mcap", "--npz", str(npz), "--out", str(bag), "--run-dir", str(run)], capsys)
    grid = read_npz(npz)
    store = typestore()
    with Reader(bag) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        assert topics == {"/psrmap/grid_map": "grid_map_msgs/msg/GridMap", "/psrmap/cost": "nav_msgs/msg/OccupancyGrid",
                          "/psrmap/scouts/scout1/path": "nav_msgs/msg/Path", "/psrmap/plan": "nav_msgs/msg/Path"}  # fmt: skip
        paths = []
        for conn, _, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == "/psrmap/grid_map":
                layers = grid_map_layers(msg)
                np.testing.assert_allclose(
                    layers["elevation"], grid.value("elevation"), equal_nan=True, rtol=1e-6
                )
                np.testing.assert_array_equal(layers["slip_count"], grid.count("slip"))
            elif conn.topic == "/psrmap/scouts/scout1/path":
                paths.append([(p.pose.position.x, p.pose.position.y) for p in msg.poses])
        assert [len(p) for p in paths] == [1, 2, 3] and paths[-1][-1] == pytest.approx((1.4, 0.2))
    assert any(bag.glob("*.mcap"))


def test_mcap_read_by_foxglove_mcap_ros2_support(npz: Path, tmp_path: Path, capsys) -> None:
    """The MCAP read with Foxglove's `mcap` + `mcap-ros2-support` (their reader, their CDR decoder built from the
    schema text the file carries): every channel's metadata holds what rosbag2_storage_mcap records (the offered
    QoS profile in rosbag2's YAML: transient local, reliable, keep last 1; the RIHS01 type hash), and the decoded
    GridMap and OccupancyGrid hold the map cell for cell."""
    import yaml
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from psrmap_mapcore import read_npz

    bag = tmp_path / "bag"
    _run(["export", "--format", "mcap", "--npz", str(npz), "--out", str(bag)], capsys)
    (mcap_file,) = bag.glob("*.mcap")
    # type hashes from the upstream definitions (grid_map_msgs' ROS 2 branch, ROS 2 Jazzy's nav_msgs)
    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg("float64 resolution\nfloat64 length_x\nfloat64 length_y\ngeometry_msgs/Pose pose\n",
                                   "grid_map_msgs/msg/GridMapInfo"))  # fmt: skip
    ts.register(get_types_from_msg("std_msgs/Header header\nGridMapInfo info\nstring[] layers\nstring[] basic_layers\n"
                                   "std_msgs/Float32MultiArray[] data\nuint16 outer_start_index\n"
                                   "uint16 inner_start_index\n", "grid_map_msgs/msg/GridMap"))  # fmt: skip
    with mcap_file.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: c for c in summary.channels.values()}
        schemas = summary.schemas
    assert set(channels) == {"/psrmap/grid_map", "/psrmap/cost"}
    for topic, typename in (("/psrmap/grid_map", "grid_map_msgs/msg/GridMap"),
                            ("/psrmap/cost", "nav_msgs/msg/OccupancyGrid")):  # fmt: skip
        ch = channels[topic]
        assert ch.message_encoding == "cdr" and schemas[ch.schema_id].encoding == "ros2msg"
        assert schemas[ch.schema_id].name == typename
        assert ch.metadata["topic_type_hash"] == ts.hash_rihs01(typename)
        (profile,) = yaml.safe_load(ch.metadata["offered_qos_profiles"])
        assert (profile["durability"], profile["reliability"], profile["history"], profile["depth"]) == (
            "transient_local", "reliable", "keep_last", 1)  # fmt: skip
        assert profile["liveliness"] == "automatic" and profile["deadline"] == {
            "sec": 9223372036,
            "nsec": 854775807,
        }
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    for t in meta["topics_with_message_count"]:
        tm = t["topic_metadata"]
        assert tm["offered_qos_profiles"][0]["durability"] == "transient_local"
        assert tm["type_description_hash"] == channels[tm["name"]].metadata["topic_type_hash"]

    grid = read_npz(npz)
    with mcap_file.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = {ch.topic: msg for _, ch, _, msg in reader.iter_decoded_messages()}
    gm = decoded["/psrmap/grid_map"]
    h, w = grid.h, grid.w
    assert gm.info.resolution == pytest.approx(RES) and gm.info.length_x == pytest.approx(w * RES)
    for name, arr in zip(gm.layers, gm.data, strict=True):
        assert [d.label for d in arr.layout.dim] == ["column_index", "row_index"]
        assert (arr.layout.dim[0].size, arr.layout.dim[1].size) == (h, w)
        m = np.asarray(arr.data, dtype=np.float32).reshape(h, w)  # column-major over (i along x, j along y)
        base = name.removesuffix("_count")
        want = grid.count(base) if name.endswith("_count") else grid.value(base)
        # grid_map cell (i, j) is map cell (ix, iy) = (w-1-i, h-1-j)
        np.testing.assert_allclose(m[::-1, ::-1], want, equal_nan=True, rtol=1e-6)
    assert {"elevation", "elevation_count", "slip", "slip_count"} == set(gm.layers)
    occ = decoded["/psrmap/cost"]
    assert (occ.info.width, occ.info.height) == (w, h)
    xa, ya, _, _ = grid.bounds_m()
    assert (occ.info.origin.position.x, occ.info.origin.position.y) == pytest.approx((xa, ya))
    cells = np.asarray(occ.data, dtype=np.int8).reshape(h, w)
    assert (cells[0, :3] == -1).all() and ((cells[1:] >= 0) & (cells[1:] <= 100)).all()


def test_the_moon_geotiff_is_identified_as_iau_2015_30135_and_its_bands_have_unit_types(
    npz: Path, tmp_path: Path, capsys
) -> None:
    """GDAL's view of the file (rasterio on GDAL, exporting the dataset's CRS as WKT2: rasterio 1.4's default
    WKT1 loses variant A and the identifier's version for every IAU CRS): the side-car's CRS carries the ID
    IAU_2015:30135 and `to_authority()` finds it; the GeoTIFF keys alone (the .tif copied without its
    side-car) are identified as IAU_2015:30135 too; both project like that CRS. Each band has a unit type
    (what `gdalinfo` prints as "Unit Type")."""
    import rasterio
    from rasterio.crs import CRS
    from rasterio.warp import transform

    from psrmap_interop.geotiff import pam_path

    out = tmp_path / "moon.tif"
    _run(
        ["export", "--format", "geotiff", "--npz", str(npz), "--out", str(out), "--origin=-89.45,222.7,30"],
        capsys,
    )
    assert pam_path(out).exists()
    iau = CRS.from_string("IAU_2015:30135")
    geo = CRS.from_string("IAU_2015:30100")
    with rasterio.Env(OSR_WKT_FORMAT="WKT2_2019"), rasterio.open(out) as ds:
        assert ds.crs.to_authority() == ("IAU_2015", "30135")
        assert 'ID["IAU",30135,2015]' in ds.crs.to_wkt(version="WKT2_2019")
        assert ds.units == ("m", "observations", "1", "observations")  # elevation [m], counts, slip [1]
        crs = ds.crs
    alone = tmp_path / "alone.tif"
    shutil.copyfile(out, alone)
    with rasterio.Env(OSR_WKT_FORMAT="WKT2_2019"), rasterio.open(alone) as ds:  # the GeoTIFF keys only
        keys_crs = ds.crs
        assert ds.crs.to_authority() == ("IAU_2015", "30135") and 'ID["IAU",30135,2015]' not in ds.crs.to_wkt(
            version="WKT2_2019"
        )
    for c in (crs, keys_crs):
        (e,), (n,) = transform(geo, c, [222.7], [-89.45])
        (e1,), (n1,) = transform(geo, iau, [222.7], [-89.45])
        assert (e, n) == pytest.approx((e1, n1), abs=1e-6)
    # overwritten without an origin: the side-car goes with the old CRS, the file is in its local frame again
    _run(["export", "--format", "geotiff", "--npz", str(npz), "--out", str(out)], capsys)
    assert not pam_path(out).exists()
    with rasterio.Env(OSR_WKT_FORMAT="WKT2_2019"), rasterio.open(out) as ds:
        assert ds.crs.to_authority() is None and "not georeferenced" in ds.crs.to_wkt()
