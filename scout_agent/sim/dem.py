"""The simulated orbiter's DEM of a procedural scene, and the lunar scene on a real DEM.

LOLA south-pole DEMs (e.g. PDS `LDEM_875S_5M`, 5 m/px, polar stereographic) resolve the relief a rover sees
from orbit, not the craters and rocks a foot meets. As OmniLRS does, the window of the DEM under the scene is
interpolated (bicubic, on the DEM's pixel centres) onto the simulator's heightfield
(`scout_agent.dem_reader.read_dem_window`), and the detail below the DEM's resolution is added procedurally and
seeded (`make_lunar`: small craters, rocks, roughness), so the ground truth stays exact: the heightfield the
simulator walks is the one `evaluate` scores against.

The other direction, for the procedural scenes: `write_orbital_dem` makes the DEM an orbiter would deliver of
a seeded field (`OrbitalDemConfig`: its relief averaged over 5 m pixels, smoothed, with per-pixel height noise
and a height/geolocation bias of the size the LOLA south-pole products state) and writes it as a GeoTIFF, which
the robot's localizer reads back with `dem_reader.read_dem_grid`, as it would a real LOLA tile.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

from scout_agent.dem_reader import LOLA_PIXEL_NOISE_M, DemError, DemGrid

__all__ = ["OrbitalDemConfig", "orbital_dem", "write_orbital_dem"]


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
    noise_m: float = LOLA_PIXEL_NOISE_M  # per-pixel height noise σ [m]
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
