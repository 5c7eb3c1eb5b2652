"""What footholds are matched against: heights with a per-point uncertainty, NaN where nothing is known.

- `DemReference`: an orbital DEM (`scout_agent.dem_reader.DemGrid`, simulated or a real LOLA tile), bilinear
  between pixel centres; each height's σ is the DEM's stated per-pixel error combined with what a 5 m pixel
  cannot show (the craters and rocks a foot stands on: `subpixel_m`).
- `GridReference`: a regular grid of planes (height at the cell centre and gradient) and σ (the shared map's
  elevation layer: the plane fit of its statistics, σ from the footholds' scatter about it and their count,
  `map_reference`), NaN in cells without data.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from protocol.layers import plane_fit
from scout_agent.dem_reader import DemGrid

__all__ = ["DemReference", "GridReference", "HeightReference", "height_datum", "map_reference"]


class HeightReference(Protocol):
    @property
    def name(self) -> str: ...

    @property
    def cell_m(self) -> float:
        """The reference's own resolution: the scale of its independent errors [m]."""
        ...

    def heights(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(height, σ) [m] at map-frame points (any shape); NaN where the reference knows nothing."""
        ...


@dataclass(frozen=True)
class DemReference:
    dem: DemGrid
    # σ of the relief below the DEM's resolution at a foothold [m]: the craters, rocks and curvature a 5 m
    # pixel's mean cannot show (true foothold heights minus the noise-free simulated DEM along the 100 m
    # field's direct route: 0.13 m, seed 31; benchmarks/dem_match.py)
    subpixel_m: float = 0.13
    name: str = "dem"

    @property
    def cell_m(self) -> float:
        return self.dem.pixel_m

    def heights(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = self.dem.height(x, y)
        return h, np.where(np.isnan(h), np.nan, float(np.hypot(self.dem.noise_m, self.subpixel_m)))


@dataclass(frozen=True)
class GridReference:
    """Per cell (lower-left corner (x0 + ix·res, y0 + iy·res)): height z at its centre, gradient gx, gy
    (z = z + gx·dx + gy·dy within the cell), σ of a foothold's height about that plane."""

    z: np.ndarray
    sigma: np.ndarray
    x0: float
    y0: float
    res: float
    gx: np.ndarray | None = None
    gy: np.ndarray | None = None
    name: str = "map"
    # per cell, σ of the vertical datum of whoever mapped it [m] (NaN: not stated): common to a scout's cells
    # nearby, so a height fix adds its mean square whole instead of averaging it over the cells
    datum_sigma: np.ndarray | None = None
    # per cell, the RMS horizontal σ of whoever placed it [m] (the `placement` layer; NaN: not stated): common to
    # a scout's cells nearby like the datum, so a place fix adds its mean square whole
    place_sigma: np.ndarray | None = None

    @property
    def cell_m(self) -> float:
        return self.res

    def heights(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ix = np.floor((np.asarray(x) - self.x0) / self.res).astype(np.int64)
        iy = np.floor((np.asarray(y) - self.y0) / self.res).astype(np.int64)
        h, w = self.z.shape
        inside = (ix >= 0) & (iy >= 0) & (ix < w) & (iy < h)
        ixc, iyc = np.clip(ix, 0, w - 1), np.clip(iy, 0, h - 1)
        z = self.z[iyc, ixc]
        if self.gx is not None and self.gy is not None:
            dx = np.asarray(x) - (self.x0 + (ixc + 0.5) * self.res)
            dy = np.asarray(y) - (self.y0 + (iyc + 0.5) * self.res)
            z = z + self.gx[iyc, ixc] * dx + self.gy[iyc, ixc] * dy
        return (np.where(inside, z, np.nan), np.where(inside, self.sigma[iyc, ixc], np.nan))

    def datum_var(self, x: np.ndarray, y: np.ndarray) -> float:
        """Mean square of `datum_sigma` over the cells under the points that have one [m²]; 0 without."""
        return self._mean_square(self.datum_sigma, x, y)

    def place_var(self, x: np.ndarray, y: np.ndarray) -> float:
        """Mean square of `place_sigma` over the cells under the points that have one [m²]; 0 without."""
        return self._mean_square(self.place_sigma, x, y)

    def _mean_square(self, per_cell: np.ndarray | None, x: np.ndarray, y: np.ndarray) -> float:
        if per_cell is None:
            return 0.0
        ix = np.floor((np.asarray(x) - self.x0) / self.res).astype(np.int64)
        iy = np.floor((np.asarray(y) - self.y0) / self.res).astype(np.int64)
        h, w = per_cell.shape
        inside = (ix >= 0) & (iy >= 0) & (ix < w) & (iy < h)
        d = per_cell[iy[inside], ix[inside]]
        d = d[np.isfinite(d)]
        return float(np.mean(d**2)) if len(d) else 0.0


def map_reference(
    stats: dict[str, np.ndarray],
    x0: float,
    y0: float,
    res: float,
    min_count: float = 2.0,
    floor_m: float = 0.01,
) -> GridReference:
    """The shared map's elevation as a reference: per cell the plane of `protocol.layers.plane_fit` (its
    height at the centre and its gradient along the directions the footholds span). σ of a foothold about it:
    the footholds' scatter about the plane (rocks, the foot's sinkage) with the plane's own uncertainty
    (scatter/√n) and `floor_m` (how well the map's cells are placed); cells with fewer than `min_count`
    footholds are unknown. `stats`: elevation statistics (n, sum, sumsq, sx, ...) as (h, w) arrays, x, y of
    the moments relative to each cell's centre (the layer's convention); (x0, y0) the lower-left corner of
    cell [0, 0]."""
    n = np.asarray(stats["n"], dtype=float)
    z0, gx, gy, _ = plane_fit(stats)
    nn = np.maximum(n, 1.0)
    mz = stats["sum"] / nn
    cxz = stats["sxz"] / nn - stats["sx"] / nn * mz
    cyz = stats["syz"] / nn - stats["sy"] / nn * mz
    resid = np.maximum(stats["sumsq"] / nn - mz**2 - gx * cxz - gy * cyz, 0.0)  # scatter about the plane
    sigma = np.sqrt(resid * (1.0 + 1.0 / nn) + floor_m**2)
    known = (n >= min_count) & np.isfinite(z0)
    nan = np.where(known, 0.0, np.nan)
    return GridReference(
        z0 + nan, sigma + nan, x0, y0, res, np.where(known, gx, 0.0), np.where(known, gy, 0.0)
    )


def height_datum(get: Callable[[float, float], HeightReference | None]):
    """A launch height datum (`state_estimation.launch.HeightDatum`: (x, y) -> (height, σ) or None) read from
    the reference `get(x, y)` returns (a DEM, or the shared map around the launch point)."""

    def datum(x: float, y: float) -> tuple[float, float] | None:
        ref = get(x, y)
        if ref is None:
            return None
        px, py = np.array([x]), np.array([y])
        h, s = ref.heights(px, py)
        if not (np.isfinite(h[0]) and np.isfinite(s[0])):
            return None
        datum = ref.datum_var(px, py) if isinstance(ref, GridReference) else 0.0
        return (float(h[0]), float(np.sqrt(s[0] ** 2 + datum)))

    return datum
