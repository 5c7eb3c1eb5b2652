"""Reading a digital elevation model (DEM) GeoTIFF: a window of it as a scene's relief (`read_dem_window`) or at
its own pixels (`read_dem_grid` → `DemGrid`).

Both sides use it: the simulated world builds a lunar scene on a real DEM's relief (`scout_agent.sim.terrain`,
`--dem`), and the robot's localizer reads the orbital DEM it is given (`scout_agent.localization.reference`),
the same file reader a real tile takes. The simulated orbiter that writes such a DEM of a procedural scene is
`scout_agent.sim.dem`.

Heights of a scene window are made relative to the window's mean (the launch site sits near z = 0); the DEM's
CRS units must be metres (projected CRS), as LOLA polar stereographic products are.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import map_coordinates

from scout_agent.errors import ScoutConfigError

# median per-pixel RMS height error of the LOLA 5 m/px south-pole site DEMs, low end (sim/dem.py: sources) [m]
LOLA_PIXEL_NOISE_M = 0.30

__all__ = ["LOLA_PIXEL_NOISE_M", "DemError", "DemGrid", "DemWindow", "read_dem_grid", "read_dem_window"]


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
    n = int(round(win.size_m / res)) + 1
    xs = win.x + np.arange(n) * res
    ys = win.y + np.arange(n) * res
    z_dem, col, row, (px, py), crs = _read_block(win, xs, ys)
    R, C = np.meshgrid(row, col, indexing="ij")  # (n, n): row iy along y, column ix along x
    z = map_coordinates(z_dem, [R, C], order=3, mode="nearest")
    datum = float(z.mean())
    z -= datum
    # dem_datum_m: the DEM height the scene's z = 0 stands for (the map frame's vertical datum)
    info = {"dem": str(win.path), "crs": crs, "dem_pixel_m": [px, py], "window_xy": [win.x, win.y],
            "size_m": win.size_m, "dem_relief_m": float(np.ptp(z)), "dem_datum_m": datum}  # fmt: skip
    return z, info


def _read_block(win: DemWindow, xs: np.ndarray, ys: np.ndarray, margin: int = 2):
    """The DEM block under the points xs × ys (DEM CRS, plus `margin` pixels) and their fractional
    (column, row) in it, the pixel size and the CRS; a `DemError` naming what would work otherwise."""
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
        # fractional pixel coordinates (pixel centres at integer + 0.5 in rasterio's convention)
        col = (xs - t.c) / t.a - 0.5
        row = (ys - t.f) / t.e - 0.5
        c0, c1 = int(np.floor(col.min())) - margin, int(np.ceil(col.max())) + 1 + margin
        r0, r1 = int(np.floor(row.min())) - margin, int(np.ceil(row.max())) + 1 + margin
        if c0 < 0 or r0 < 0 or c1 > ds.width or r1 > ds.height:
            xa, yb = t.c, t.f
            xb, ya = t.c + t.a * ds.width, t.f + t.e * ds.height
            raise DemError(
                f"--dem-window {win.x:g},{win.y:g}: the {win.size_m:g} m scene (plus {margin} DEM pixels of margin) "
                f"leaves the DEM, which covers x {min(xa, xb):.1f}..{max(xa, xb):.1f}, "
                f"y {min(ya, yb):.1f}..{max(ya, yb):.1f} [m, its CRS]"
            )
        block = ds.read(1, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True).astype(np.float64)
        crs = str(ds.crs) if ds.crs is not None else None
    if np.ma.is_masked(block) and block.mask.any():
        raise DemError(f"--dem-window {win.x:g},{win.y:g}: the window holds DEM nodata; move it")
    return np.asarray(block), col - c0, row - r0, (px, py), crs


@dataclass(frozen=True)
class DemGrid:
    """A DEM's heights at its own pixels in the scene frame: `z[iy, ix]` at pixel centre
    (x0 + ix·pixel_m, y0 + iy·pixel_m); `noise_m` the stated per-pixel height error."""

    z: np.ndarray
    x0: float
    y0: float
    pixel_m: float
    noise_m: float
    source: str

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear height at scene points (held constant beyond the outer pixel centres; NaN beyond the
        DEM's edge)."""
        u = (np.asarray(x, dtype=float) - self.x0) / self.pixel_m
        v = (np.asarray(y, dtype=float) - self.y0) / self.pixel_m
        ny, nx = self.z.shape
        inside = (u >= -0.5) & (v >= -0.5) & (u <= nx - 0.5) & (v <= ny - 0.5)
        out = map_coordinates(self.z, [np.clip(v, 0, ny - 1), np.clip(u, 0, nx - 1)], order=1, mode="nearest")
        return np.where(inside, out, np.nan)


def read_dem_grid(win: DemWindow, noise_m: float | None = None) -> DemGrid:
    """The DEM's own pixels under the scene window `win` (scene (0, 0) = DEM-CRS (win.x, win.y)), heights as
    stored (no resampling, no mean removal: the localizer fits the datum). `noise_m`: the per-pixel height
    error; default the file's PSRMAP_DEM_NOISE_M tag, else `LOLA_PIXEL_NOISE_M`."""
    import rasterio

    with rasterio.open(win.path) as ds:
        px = abs(ds.transform.a)
        tag = ds.tags().get("PSRMAP_DEM_NOISE_M")
    n = int(np.floor(win.size_m / px)) + 1
    xs = win.x + (np.arange(n) + 0.5) * px
    ys = win.y + (np.arange(n) + 0.5) * px
    z_dem, col, row, _, _ = _read_block(win, xs[:-1], ys[:-1], margin=0)
    R, C = np.meshgrid(row, col, indexing="ij")
    z = map_coordinates(z_dem, [R, C], order=1, mode="nearest")
    sigma = noise_m if noise_m is not None else float(tag) if tag else LOLA_PIXEL_NOISE_M
    return DemGrid(z, px / 2, px / 2, px, sigma, str(win.path))
