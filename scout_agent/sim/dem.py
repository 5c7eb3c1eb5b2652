"""A lunar scene on a real digital elevation model (DEM): a GeoTIFF window as the broad relief.

LOLA south-pole DEMs (e.g. PDS `LDEM_875S_5M`, 5 m/px, polar stereographic) resolve the relief a rover sees
from orbit, not the craters and rocks a foot meets. As OmniLRS does, the window of the DEM under the scene is
interpolated (bicubic, on the DEM's pixel centres) onto the simulator's heightfield, and the detail below the
DEM's resolution is added procedurally and seeded (`make_lunar`: small craters, rocks, roughness), so the
ground truth stays exact: the heightfield the simulator walks is the one `evaluate` scores against.

Heights are made relative to the window's mean (the launch site sits near z = 0); the DEM's CRS units must be
metres (projected CRS), as LOLA polar stereographic products are.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import map_coordinates

from scout_agent.errors import ScoutConfigError

__all__ = ["DemWindow", "read_dem_window"]


@dataclass(frozen=True)
class DemWindow:
    """Where the scene lies on the DEM: its (0, 0) corner at `x, y` in the DEM's CRS [m], axes along the
    DEM's x (east) and y (north), `size_m` square."""

    path: str
    x: float
    y: float
    size_m: float = 20.0


class DemError(ScoutConfigError):
    """A DEM that cannot make a scene; the message says what would."""


def read_dem_window(win: DemWindow, res: float) -> tuple[np.ndarray, dict]:
    """The window resampled to a (n, n) heightfield at `res` [m] (row = y, column = x, relative to the
    window's mean) and facts about it (CRS, DEM pixel size, heights)."""
    import rasterio
    from rasterio.windows import Window

    path = Path(win.path)
    if not path.exists():
        raise DemError(f"--dem {win.path}: no such file; give a GeoTIFF DEM (e.g. a LOLA LDEM_*.tif)")
    try:
        ds = rasterio.open(path)
    except rasterio.errors.RasterioIOError as exc:
        raise DemError(f"--dem {win.path}: not a raster GDAL can read ({exc}); give a GeoTIFF DEM") from None
    with ds:
        if ds.crs is not None and ds.crs.is_geographic:
            raise DemError(
                f"--dem {win.path}: CRS {ds.crs} is in degrees; give a projected DEM in metres "
                "(e.g. Moon polar stereographic, IAU_2015:30135)"
            )
        t = ds.transform
        if t.b != 0 or t.d != 0:
            raise DemError(f"--dem {win.path}: rotated rasters are not supported")
        px, py = abs(t.a), abs(t.e)
        n = int(round(win.size_m / res)) + 1
        xs = win.x + np.arange(n) * res
        ys = win.y + np.arange(n) * res
        # fractional pixel coordinates (pixel centres at integer + 0.5 in rasterio's convention)
        col = (xs - t.c) / t.a - 0.5
        row = (ys - t.f) / t.e - 0.5
        c0, c1 = int(np.floor(col.min())) - 2, int(np.ceil(col.max())) + 3
        r0, r1 = int(np.floor(row.min())) - 2, int(np.ceil(row.max())) + 3
        if c0 < 0 or r0 < 0 or c1 > ds.width or r1 > ds.height:
            xa, yb = t.c, t.f
            xb, ya = t.c + t.a * ds.width, t.f + t.e * ds.height
            raise DemError(
                f"--dem-window {win.x:g},{win.y:g}: the {win.size_m:g} m scene (plus 2 DEM pixels of margin) "
                f"leaves the DEM, which covers x {min(xa, xb):.1f}..{max(xa, xb):.1f}, "
                f"y {min(ya, yb):.1f}..{max(ya, yb):.1f} [m, its CRS]"
            )
        block = ds.read(1, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True).astype(np.float64)
        crs = str(ds.crs) if ds.crs is not None else None
    if np.ma.is_masked(block) and block.mask.any():
        raise DemError(f"--dem-window {win.x:g},{win.y:g}: the window holds DEM nodata; move it")
    z_dem = np.asarray(block)
    R, C = np.meshgrid(row - r0, col - c0, indexing="ij")  # (n, n): row iy along y, column ix along x
    z = map_coordinates(z_dem, [R, C], order=3, mode="nearest")
    z -= z.mean()
    info = {"dem": str(path), "crs": crs, "dem_pixel_m": [px, py], "window_xy": [win.x, win.y],
            "size_m": win.size_m, "dem_relief_m": float(np.ptp(z))}  # fmt: skip
    return z, info
