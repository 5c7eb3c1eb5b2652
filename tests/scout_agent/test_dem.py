"""A lunar scene on a DEM the test writes (5 m/px, Moon polar stereographic, like a LOLA tile): the DEM's relief
is the scene's broad relief, the seeded detail sits on top, a scout walks it, and `evaluate` scores the map
against that terrain."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from psrmap.cli import main
from scout_agent.dem_reader import DemWindow
from scout_agent.run import ScoutRunConfig, build_world

TILT_DEG = 4.0
X0, Y0, PX, N = 10_000.0, -20_000.0, 5.0, 40  # upper-left corner [m], pixel [m], pixels per side


def _dem_height(X, Y):
    """The test DEM's surface: a 4° slope rising east and a broad 2 m swell [m]."""
    z = 1500.0 + np.tan(np.radians(TILT_DEG)) * (X - X0)
    return z + 2.0 * np.exp(-((X - X0 - 100) ** 2 + (Y - Y0 + 100) ** 2) / (2 * 30.0**2))


@pytest.fixture(scope="module")
def dem(tmp_path_factory: pytest.TempPathFactory) -> Path:
    import rasterio
    from rasterio.crs import CRS
    from rasterio.transform import Affine

    cols, rows = np.meshgrid(np.arange(N), np.arange(N))
    z = _dem_height(X0 + (cols + 0.5) * PX, Y0 - (rows + 0.5) * PX)
    path = tmp_path_factory.mktemp("dem") / "ldem_test.tif"
    with rasterio.open(path, "w", driver="GTiff", width=N, height=N, count=1, dtype="float32",
                       crs=CRS.from_string("IAU_2015:30135"), transform=Affine(PX, 0.0, X0, 0.0, -PX, Y0),
                       nodata=-9999.0) as ds:  # fmt: skip
        ds.write(z.astype("float32"), 1)
    return path


def test_the_dem_relief_is_the_scene_relief(dem: Path) -> None:
    win = DemWindow(str(dem), X0 + 60.0, Y0 - 140.0)
    world = build_world(ScoutRunConfig(scene="lunar", seed=0, dem=win))
    t = world.terrain
    assert t.name == "dem0" and t.info["dem_pixel_m"] == [PX, PX]
    # east minus west edge, row by row: the DEM's own rise over the 20 m (the seeded craters and rocks on top
    # are small; the median ignores the rows they cross)
    ys = win.y + np.arange(t.z.shape[0]) * t.res
    want = np.median(_dem_height(win.x + 20.0, ys) - _dem_height(win.x, ys))
    assert want > 1.0  # the window holds real relief
    assert np.median(t.z[:, -1] - t.z[:, 0]) == pytest.approx(want, abs=0.15)
    plain = build_world(ScoutRunConfig(scene="lunar", seed=0)).terrain
    assert plain.info["craters"] == t.info["craters"]  # the same seeded detail on either relief


@pytest.mark.slow
def test_scout_walks_a_dem_scene_and_evaluate_scores_it(dem: Path, capsys) -> None:
    argv = ["evaluate", "--scene", "lunar", "--seed", "0", "--dem", str(dem), f"--dem-window={X0 + 60},{Y0 - 140}",
            "--route", "direct", "--json"]  # fmt: skip
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["terrain"] == "dem0" and not out["fell"] and out["reached_goal"]
    # the height datum is the DEM's at the surveyed start (never the simulator's): the map's shape is right to
    # the same 0.2 m as before, and its offset lies within 3σ of the datum's stated uncertainty
    assert out["launch"]["datum"] == "dem" and out["localization"] != "off"
    assert 0.0 < out["elevation_rmse_relative_m"] < 0.2 and out["elevation_cells"] > 50
    assert abs(out["elevation_bias_m"]) <= 3 * out["launch"]["sigma_z_m"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--dem-window=0,0"], "leaves the DEM"),
        (["--scene", "ramps"], "--scene lunar"),
    ],
)
def test_bad_dem_use_is_refused_with_the_valid_form(
    dem: Path, capsys, extra: list[str], message: str
) -> None:
    argv = ["scout", "--scene", "lunar", "--dem", str(dem), "--sim-seconds", "1", *extra]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and message in capsys.readouterr().err
