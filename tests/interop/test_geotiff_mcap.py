"""GeoTIFF and rosbag2/MCAP exports read back with rasterio and rosbags: values, nodata, CRS, transform, band
descriptions; one map point found again in the projected Moon frame; the bag's topics and messages."""

from __future__ import annotations

import json
import math
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

    from interop.ros2_messages import grid_map_layers, typestore
    from mapcore import read_npz

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
