"""A lunar scene on a real digital elevation model (DEM): a GeoTIFF window as the broad relief.

LOLA south-pole DEMs (e.g. PDS `LDEM_875S_5M`, 5 m/px, polar stereographic) resolve the relief a rover sees
from orbit, not the craters and rocks a foot meets. As OmniLRS does, the window of the DEM under the scene is
interpolated (bicubic, on the DEM's pixel centres) onto the simulator's heightfield, and the detail below the
DEM's resolution is added procedurally and seeded (`make_lunar`: small craters, rocks, roughness), so the
ground truth stays exact: the heightfield the simulator walks is the one `evaluate` scores against.

Heights are made relative to the window's mean (the launch site sits near z = 0); the DEM's CRS units must be
metres (projected CRS), as LOLA polar stereographic products are.

The other direction, for the procedural scenes: `write_orbital_dem` makes the DEM an orbiter would deliver of
a seeded field (`OrbitalDemConfig`: its relief averaged over 5 m pixels, smoothed, with per-pixel height noise
and a height/geolocation bias of the size the LOLA south-pole products state) and writes it as a GeoTIFF, and
`read_dem_grid` reads a window of any such DEM (simulated or a real LOLA tile) at its own pixel size in the
scene frame, for localization against it (`scout_agent.localization`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates

from scout_agent.errors import ScoutConfigError

__all__ = [
    "DemGrid",
    "DemWindow",
    "OrbitalDemConfig",
    "read_dem_grid",
    "read_dem_window",
    "write_orbital_dem",
]


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


# ------------------------------------------------------------------------------ a simulated orbital DEM


@dataclass(frozen=True)
class OrbitalDemConfig:
    """What an orbiter's DEM of the scene looks like. Defaults after Barker et al., LOLA 5 m/px south-pole
    site DEMs (NASA PGDA product 78, "High-Resolution LOLA Topography for Lunar South Pole Sites"): track
    geolocation uncertainty ≈ 10–20 cm horizontally and 2–4 cm vertically (the bias: one draw for the whole
    tile), median per-pixel RMS height error 0.30–0.50 m (interpolation between LOLA spots: ~90 % of the
    5 m pixels are interpolated), which is the per-pixel noise here (low end: these sites' best coverage)."""

    pixel_m: float = 5.0  # DEM pixel size [m] (LOLA south-pole site DEMs: 5 m/px; large-area ones 20 m/px)
    smooth_px: float = 0.5  # Gaussian smoothing σ [pixels]: LOLA's ~5 m spot and the gridding's interpolation
    noise_m: float = 0.30  # per-pixel height noise σ [m]
    bias_z_m: float = 0.03  # σ of the tile's vertical bias [m] (one draw)
    bias_xy_m: float = 0.15  # σ of the tile's horizontal geolocation bias, per axis [m] (one draw)
    seed: int = 0

    def __post_init__(self) -> None:
        if (
            not self.pixel_m > 0
            or self.noise_m < 0
            or self.smooth_px < 0
            or self.bias_z_m < 0
            or self.bias_xy_m < 0
        ):
            raise DemError(
                f"orbital DEM {self}: need pixel_m > 0 and non-negative smoothing, noise and biases"
            )


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


def orbital_dem(terrain, cfg: OrbitalDemConfig = OrbitalDemConfig()) -> DemGrid:
    """The orbiter's view of `terrain` (a `scout_agent.sim.terrain.Terrain`): each pixel the mean of the true
    heights over its footprint (sampled where the tile's horizontal bias puts it), smoothed, plus per-pixel
    noise and the tile's vertical bias, all seeded."""
    rng = np.random.default_rng(cfg.seed + 7919)
    xa, ya, xb, yb = terrain.extent
    nx = max(2, int(np.floor((xb - xa) / cfg.pixel_m)))
    ny = max(2, int(np.floor((yb - ya) / cfg.pixel_m)))
    bx, by = rng.normal(0.0, cfg.bias_xy_m, 2)
    bz = rng.normal(0.0, cfg.bias_z_m)
    k = max(2, int(round(cfg.pixel_m / terrain.res)))  # samples per pixel side
    off = (np.arange(k) + 0.5) / k * cfg.pixel_m
    cx = xa + np.arange(nx) * cfg.pixel_m  # pixel lower-left corners
    cy = ya + np.arange(ny) * cfg.pixel_m
    X = (cx[:, None] + off[None, :]).ravel() + bx
    Y = (cy[:, None] + off[None, :]).ravel() + by
    z = terrain.height(X[None, :], Y[:, None]).reshape(ny, k, nx, k).mean(axis=(1, 3))
    if cfg.smooth_px > 0:
        z = gaussian_filter(z, cfg.smooth_px, mode="nearest")
    z = z + rng.normal(0.0, cfg.noise_m, z.shape) + bz
    return DemGrid(z, xa + cfg.pixel_m / 2, ya + cfg.pixel_m / 2, cfg.pixel_m, cfg.noise_m, "simulated")


def write_orbital_dem(terrain, path: str | Path, cfg: OrbitalDemConfig = OrbitalDemConfig()) -> DemGrid:
    """`orbital_dem` written as a one-band GeoTIFF in the scene's local frame (psrmap_interop.geotiff: the map's
    elevation band, NaN nodata, the noise and bias it was made with as tags); the same file `read_dem_grid`
    (and `--dem`) reads."""
    from psrmap_interop.geotiff import write_geotiff

    g = orbital_dem(terrain, cfg)
    h = g.pixel_m / 2
    write_geotiff(path, {"elevation": g.z}, {}, g.pixel_m, g.x0 - h, g.y0 - h,
                  tags={"PSRMAP_DEM": f"simulated orbital DEM of {terrain.name}: {cfg}",
                        "PSRMAP_DEM_NOISE_M": f"{cfg.noise_m:g}"})  # fmt: skip
    return g


def read_dem_grid(win: DemWindow, noise_m: float | None = None) -> DemGrid:
    """The DEM's own pixels under the scene window `win` (scene (0, 0) = DEM-CRS (win.x, win.y)), heights as
    stored (no resampling, no mean removal: the localizer fits the datum). `noise_m`: the per-pixel height
    error; default the file's PSRMAP_DEM_NOISE_M tag, else the LOLA figure of `OrbitalDemConfig`."""
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
    sigma = noise_m if noise_m is not None else float(tag) if tag else OrbitalDemConfig().noise_m
    return DemGrid(z, px / 2, px / 2, px, sigma, str(win.path))
