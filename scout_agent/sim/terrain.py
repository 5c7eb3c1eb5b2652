"""Terrains as heightfields with exact ground truth: the ramp testbed and a seeded 20×20 m lunar field.

A `Terrain` is a regular grid of heights (`z[iy, ix]`, row along y, column along x, `res` metres apart,
lower-left sample at `(x0, y0)`) that MuJoCo collides with as a triangulated heightfield. `height(x, y)` and
`slope_deg(x, y)` evaluate the very triangles MuJoCo uses (each cell split along its (ix, iy)-(ix+1, iy+1)
diagonal), so they are exact, not interpolations of a smoother surface.

Lunar terrain, after OmniLRS ("lunaryard", BSD-3): coarse uniform noise bicubic-upsampled plus fine noise
(fields larger than the paper's 20 m: a self-affine relief with LOLA's scaling instead, `FractalRelief`);
craters by a hard-core Poisson process per size class, ellipticity 0.85–1, random rotation, cosine bowl with
a raised rim; rocks by a Thomas cluster process as smooth bumps. What a trot can cross is capped where
routes run (see `LunarConfig`): craters touching a surveyed corridor get depth/diameter ≤ 0.15, rocks there
≤ 0.1 m with smooth shoulders; elsewhere deep craters (up to 1 m deep, 2.5 m wide) remain as hazards.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.ndimage import gaussian_filter, zoom

from scout_agent.errors import ScoutConfigError

# The paper's three corner-to-corner routes on the 20 m lunar field: direct, and two via landmarks.
LUNAR_ROUTES: dict[str, tuple[tuple[float, float], ...]] = {
    "direct": ((1.5, 1.5), (18.5, 18.5)),
    "west": ((1.5, 1.5), (5.0, 13.0), (18.5, 18.5)),
    "east": ((1.5, 1.5), (13.0, 5.0), (18.5, 18.5)),
}
PAPER_FIELD_M = 20.0  # the paper's lunar field; `--field L` scales it
ROUTE_MARGIN_M = 1.5  # route ends this far from the field's edges, at any size


def lunar_routes(size_m: float = PAPER_FIELD_M) -> dict[str, tuple[tuple[float, float], ...]]:
    """The paper's routes stretched onto a `size_m` field: the ends stay `ROUTE_MARGIN_M` from the corners,
    the via points keep their place relative to the field (100 m: direct is 137 m corner to corner)."""
    if size_m < 2 * ROUTE_MARGIN_M + 2.0:
        raise ScoutConfigError(f"lunar field {size_m:g} m: too small; valid: ≥ {2 * ROUTE_MARGIN_M + 2:g} m")
    k = (size_m - 2 * ROUTE_MARGIN_M) / (PAPER_FIELD_M - 2 * ROUTE_MARGIN_M)
    return {
        name: tuple(
            (ROUTE_MARGIN_M + (x - ROUTE_MARGIN_M) * k, ROUTE_MARGIN_M + (y - ROUTE_MARGIN_M) * k)
            for x, y in pts
        )
        for name, pts in LUNAR_ROUTES.items()
    }


@dataclass(frozen=True)
class Terrain:
    """A heightfield with exact height/slope queries. Arrays are not copied; treat them as read-only."""

    z: np.ndarray  # (ny, nx) heights [m], row iy along y, column ix along x
    res: float  # grid spacing [m]
    x0: float  # x of column 0 [m]
    y0: float  # y of row 0 [m]
    name: str = "terrain"
    spawn: tuple[float, float, float] = (0.0, 0.0, 0.0)  # default start x, y, yaw
    goal: tuple[float, float] = (0.0, 0.0)  # default goal x, y
    info: dict = field(default_factory=dict)  # generator facts (segments, craters, hazards, ...)

    @property
    def shape(self) -> tuple[int, int]:
        return self.z.shape

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) [m]."""
        ny, nx = self.z.shape
        return self.x0, self.y0, self.x0 + (nx - 1) * self.res, self.y0 + (ny - 1) * self.res

    def _locate(self, x, y):
        ny, nx = self.z.shape
        u = (np.asarray(x, dtype=float) - self.x0) / self.res
        v = (np.asarray(y, dtype=float) - self.y0) / self.res
        u = np.clip(u, 0.0, nx - 1 - 1e-9)
        v = np.clip(v, 0.0, ny - 1 - 1e-9)
        ix = np.floor(u).astype(int)
        iy = np.floor(v).astype(int)
        return ix, iy, u - ix, v - iy

    def _corners(self, ix, iy):
        z = self.z
        return z[iy, ix], z[iy, ix + 1], z[iy + 1, ix], z[iy + 1, ix + 1]

    def height(self, x, y):
        """Exact terrain height [m] at (x, y) (arrays broadcast); clamped to the field's edge outside it."""
        xb, yb = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        return self.height_at_points(xb.ravel(), yb.ravel()).reshape(xb.shape)

    def height_at_points(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """`height` at the points (x, y), two float arrays (n,): the simulator's per-tick lookup."""
        out = np.empty(len(x))
        heights_at(self.z, self.x0, self.y0, self.res, x, y, out)
        return out

    def gradient(self, x, y):
        """(dz/dx, dz/dy) of the triangle under (x, y)."""
        ix, iy, fx, fy = self._locate(x, y)
        z00, z10, z01, z11 = self._corners(ix, iy)
        lower = fx >= fy
        gx = np.where(lower, z10 - z00, z11 - z01) / self.res
        gy = np.where(lower, z11 - z10, z01 - z00) / self.res
        return gx, gy

    def normal(self, x, y) -> np.ndarray:
        """Unit upward normal(s) (..., 3)."""
        gx, gy = self.gradient(x, y)
        n = np.stack([-np.asarray(gx), -np.asarray(gy), np.ones_like(gx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def slope_deg(self, x, y):
        """Exact inclination of the ground at (x, y) [deg]."""
        gx, gy = self.gradient(x, y)
        return np.degrees(np.arctan(np.hypot(gx, gy)))

    def slope_grid_deg(self) -> np.ndarray:
        """(ny-1, nx-1) steepest-triangle slope per cell [deg]."""
        z = self.z
        g1 = np.hypot(z[:-1, 1:] - z[:-1, :-1], z[1:, 1:] - z[:-1, 1:])
        g2 = np.hypot(z[1:, 1:] - z[1:, :-1], z[1:, :-1] - z[:-1, :-1])
        return np.degrees(np.arctan(np.maximum(g1, g2) / self.res))

    def slope_stats(self, mask: np.ndarray | None = None) -> dict[str, float]:
        """Slope percentiles [deg] over the cells (optionally a boolean (ny-1, nx-1) mask)."""
        s = self.slope_grid_deg()
        if mask is not None:
            s = s[mask]
        p = np.percentile(s, [50, 95, 99, 100])
        return {
            "median": float(p[0]),
            "p95": float(p[1]),
            "p99": float(p[2]),
            "max": float(p[3]),
            "relief_m": float(self.z.max() - self.z.min()),
        }

    def corridor_mask(self, waypoints, half_width: float) -> np.ndarray:
        """(ny-1, nx-1) cells whose centre lies within `half_width` of the polyline `waypoints`."""
        ny, nx = self.z.shape
        xs = self.x0 + (np.arange(nx - 1) + 0.5) * self.res
        ys = self.y0 + (np.arange(ny - 1) + 0.5) * self.res
        X, Y = np.meshgrid(xs, ys)
        return _polyline_distance(X, Y, waypoints) <= half_width


@njit(cache=True, nogil=True)
def heights_at(
    z: np.ndarray, x0: float, y0: float, res: float, x: np.ndarray, y: np.ndarray, out: np.ndarray
) -> None:
    """`Terrain.height` of the grid `z` (origin x0, y0, spacing res) at the points (x, y) (n,) into `out` (n,),
    compiled: the simulator asks every tick."""
    ny, nx = z.shape
    for i in range(x.shape[0]):
        u = min(max((x[i] - x0) / res, 0.0), nx - 1 - 1e-9)
        v = min(max((y[i] - y0) / res, 0.0), ny - 1 - 1e-9)
        ix, iy = int(np.floor(u)), int(np.floor(v))
        fx, fy = u - ix, v - iy
        z00, z10, z01, z11 = z[iy, ix], z[iy, ix + 1], z[iy + 1, ix], z[iy + 1, ix + 1]
        if fx >= fy:  # triangle (00, 10, 11) below the diagonal, else (00, 11, 01)
            out[i] = z00 + fx * (z10 - z00) + fy * (z11 - z10)
        else:
            out[i] = z00 + fy * (z01 - z00) + fx * (z11 - z01)


def _polyline_distance(X, Y, waypoints) -> np.ndarray:
    d = np.full(np.shape(X), np.inf)
    pts = np.asarray(waypoints, dtype=float)
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        ab = b - a
        t = np.clip(((X - a[0]) * ab[0] + (Y - a[1]) * ab[1]) / max(ab @ ab, 1e-12), 0.0, 1.0)
        d = np.minimum(d, np.hypot(X - a[0] - t * ab[0], Y - a[1] - t * ab[1]))
    return d


# ---------------------------------------------------------------------------------------------- ramps


@dataclass(frozen=True)
class RampConfig:
    """The paper's testbed along +x: flat approach, up-ramp, platform, down-ramp, flat exit."""

    slope_deg: float = 15.0  # ramp angle α [deg], 0–25
    approach_m: float = 1.5  # flat before the up-ramp [m]
    up_m: float = 3.0  # horizontal length of the up-ramp [m]
    platform_m: float = 2.0  # flat platform [m]
    down_m: float = 3.0  # horizontal length of the down-ramp [m]
    exit_m: float = 2.0  # flat after the down-ramp [m]
    width_m: float = 3.0  # testbed width (y from -width/2) [m]
    res: float = 0.05  # grid spacing [m]; segment boundaries are snapped to it


def ramp_profile(cfg: RampConfig) -> tuple[np.ndarray, np.ndarray]:
    """Breakpoints (xs, zs) of the piecewise-linear ramp profile, boundaries snapped to the grid."""
    snap = lambda v: round(v / cfg.res) * cfg.res  # noqa: E731
    lengths = [snap(v) for v in (cfg.approach_m, cfg.up_m, cfg.platform_m, cfg.down_m, cfg.exit_m)]
    xs = np.concatenate([[0.0], np.cumsum(lengths)])
    t = np.tan(np.radians(cfg.slope_deg))
    top = lengths[1] * t
    zs = np.array([0.0, 0.0, top, top, top - lengths[3] * t, top - lengths[3] * t])
    return xs, zs


def make_ramps(cfg: RampConfig = RampConfig()) -> Terrain:
    if not 0.0 <= cfg.slope_deg <= 25.0:
        raise ScoutConfigError(f"ramp slope {cfg.slope_deg}° out of range; valid: 0–25°")
    xs, zs = ramp_profile(cfg)
    nx = int(round(xs[-1] / cfg.res)) + 1
    ny = int(round(cfg.width_m / cfg.res)) + 1
    gx = np.arange(nx) * cfg.res
    row = np.interp(gx, xs, zs)
    z = np.tile(row, (ny, 1))
    segments = {
        "approach": (xs[0], xs[1]),
        "up": (xs[1], xs[2]),
        "platform": (xs[2], xs[3]),
        "down": (xs[3], xs[4]),
        "exit": (xs[4], xs[5]),
    }
    return Terrain(
        z=z,
        res=cfg.res,
        x0=0.0,
        y0=-cfg.width_m / 2,
        name=f"ramps{cfg.slope_deg:g}",
        spawn=(0.6, 0.0, 0.0),
        goal=(float(xs[-1] - 0.8), 0.0),
        info={"segments": segments, "slope_deg": cfg.slope_deg},
    )


# ---------------------------------------------------------------------------------------------- lunar


@dataclass(frozen=True)
class FractalRelief:
    """A self-affine broad relief by spectral synthesis: a Gaussian random surface whose deviogram (RMS height
    difference of points a baseline L apart) is v(L) = s·L0·(L/L0)^H, so its RMS slope at baseline L,
    v(L)/L = s·(L/L0)^(H−1), falls slowly with L while the relief v(L) grows with it. LOLA measures the
    Moon's topography this way (Rosenburg et al. 2011, JGR 116 E02001; NASA PGDA product 70: Hurst exponents
    from deviograms over 57 m–2.7 km baselines, H ≈ 0.95 on the maria and lower, ≈ 0.7–0.8, in the highlands;
    median slopes of a few degrees on the maria, more in the highlands). Stated here: H = 0.8 and a median
    |slope| of 3° at 25 m (3.6° at 10 m, the paper's 20 m field's 3.2° there; 2.6° at 50 m): a smooth
    intercrater plain, at the gentle end of the highlands, so that a scout can walk it. For a Gaussian height
    difference the median |slope| is 0.674 of the RMS one: s = tan 3° / 0.674 ≈ 0.078 (4.4° RMS at 25 m).
    Wavelengths shorter than `min_wavelength_m` are left out: at those scales the craters, rocks and fine
    noise of `make_lunar` stand for the surface, and the broad relief's local slope stays bounded."""

    hurst: float = 0.8
    median_slope_deg: float = 3.0  # median |bidirectional slope| at `baseline_m` [deg]
    baseline_m: float = 25.0
    min_wavelength_m: float = 12.0  # shortest wavelength synthesised [m]
    grid_m: float = 1.0  # synthesis grid (cubic-spline upsampled to the field's res) [m]
    pad: int = 4  # the synthesis domain is this many field sides (a periodic FFT: no wrap-around)
    # where routes run (within `grade_band_m`), hillsides steeper than `grade_above_deg` are graded (smoothed
    # at `grade_sigma_m`): a route is surveyed where the ground is walkable
    grade_above_deg: float = 12.0
    grade_band_m: float = 3.0
    grade_sigma_m: float = 4.0

    @property
    def rms_slope(self) -> float:
        """s: the RMS slope (tangent) at `baseline_m`."""
        return float(np.tan(np.radians(self.median_slope_deg)) / MEDIAN_OVER_RMS)

    def rms_slope_at(self, baseline_m: float) -> float:
        """The stated RMS slope (tangent) at `baseline_m`: s·(L/L0)^(H−1) (the self-affine law)."""
        return self.rms_slope * (baseline_m / self.baseline_m) ** (self.hurst - 1.0)


MEDIAN_OVER_RMS = 0.6745  # median |x| / RMS of a zero-mean Gaussian


def fractal_relief(
    cfg: FractalRelief, size_m: float, res: float, seed: int, routes: tuple | None = None
) -> np.ndarray:
    """The (n, n) self-affine relief [m] of a `size_m` field at `res` (n = size/res + 1), seeded. Random phases
    and Gaussian amplitudes under the power law |A(k)|² ∝ k^−2(H+1) (an isotropic self-affine surface) on a
    `pad`× larger periodic grid, band-limited to `min_wavelength_m`; scaled so that the *expected* deviogram
    at `baseline_m` (computed exactly from the discrete spectrum) is the stated one: each seed's own figure
    scatters about it as a real surface's would. With `routes` (polylines), the relief is graded where they
    run (`_grade_routes`)."""
    rng = np.random.default_rng([seed, 2])
    m = int(np.ceil(cfg.pad * size_m / cfg.grid_m))
    f = np.fft.fftfreq(m, d=cfg.grid_m)  # cycles per metre
    FX, FY = np.meshgrid(f, f)
    k = np.hypot(FX, FY)
    amp = np.where(
        (k > 0) & (k <= 1.0 / cfg.min_wavelength_m), np.maximum(k, 1e-12) ** -(cfg.hurst + 1.0), 0.0
    )
    xi = rng.normal(size=(m, m)) + 1j * rng.normal(size=(m, m))
    z = np.real(np.fft.ifft2(amp * xi))
    # E[(z(x+L) − z(x))²] along x (and y, the same) for this spectrum: Σ |A|² 2(1 − cos 2π f L) / m⁴
    L = cfg.baseline_m
    v2 = float(np.sum(amp**2 * (2.0 - np.cos(2 * np.pi * FX * L) - np.cos(2 * np.pi * FY * L))) / m**4)
    z *= cfg.rms_slope * L / np.sqrt(v2)
    nc = int(round(size_m / cfg.grid_m)) + 1
    zc = z[:nc, :nc]
    if routes is not None:
        zc = _grade_routes(zc, cfg, routes)
    n = int(round(size_m / res)) + 1
    return zoom(zc, (n - 1) / (nc - 1) + 1e-9, order=3, mode="nearest")[:n, :n]


def _grade_routes(zc: np.ndarray, cfg: FractalRelief, routes: tuple) -> np.ndarray:
    """Where a route crosses the relief's steeper spots (its slope above `grade_above_deg` within
    `grade_band_m` of the route), blend it toward its `grade_sigma_m`-smoothed self: a surveyed route is
    laid where the ground is walkable, and a slope that is steep over metres cannot be capped by the
    corridors' local smoothing (`_cap_corridor_slopes` handles crater walls and rocks, not hillsides)."""
    g = cfg.grid_m
    xs = np.arange(zc.shape[0]) * g
    X, Y = np.meshgrid(xs, xs)
    d = np.full(zc.shape, np.inf)
    for route in routes:
        d = np.minimum(d, _polyline_distance(X, Y, route))
    near = np.clip((cfg.grade_band_m + 4.0 - d) / 4.0, 0.0, 1.0)
    for _ in range(3):
        slope = np.degrees(np.arctan(np.hypot(*np.gradient(gaussian_filter(zc, 1.0), g))))
        steep = np.clip((slope - cfg.grade_above_deg) / 4.0, 0.0, 1.0)
        w = np.clip(gaussian_filter(steep, 3.0 / g) * 3.0, 0.0, 1.0) * near
        zc = zc * (1.0 - w) + gaussian_filter(zc, cfg.grade_sigma_m / g, mode="nearest") * w
    return zc


def deviogram_slope(z: np.ndarray, res: float, baseline_m: float) -> tuple[float, float]:
    """(RMS, median |·|) of the bidirectional slope (height difference / baseline, a tangent) of the grid `z`
    (spacing `res`) between points `baseline_m` apart along x and along y, pooled."""
    lag = int(round(baseline_m / res))
    d = np.concatenate([(z[:, lag:] - z[:, :-lag]).ravel(), (z[lag:, :] - z[:-lag, :]).ravel()]) / (lag * res)
    return float(np.sqrt(np.mean(d**2))), float(np.median(np.abs(d)))


@dataclass(frozen=True)
class LunarConfig:
    """Seeded lunar field (OmniLRS-like). Lengths in metres, slopes in degrees."""

    seed: int = 0
    size_m: float = PAPER_FIELD_M  # the field's side [m] (`--field`); routes scale with it
    res: float = 0.05
    relief_m: float = 3.0  # peak-to-peak of the coarse relief (±1.5 m), before the slope cap
    relief_spacing_m: float = 10.0  # coarse noise grid spacing (bicubic-upsampled): 3 × 3 on 20 m
    relief_max_slope_deg: float = 12.0  # the broad relief is scaled down until its steepest slope is this
    # the broad relief's model: "paper" (the above: coarse noise normalised over the whole field, which on a
    # larger field makes its relief ever smoother), "fractal" (self-affine, `FractalRelief`: relief that
    # grows with scale as the Moon's does), "auto": paper on fields up to the paper's 20 m, fractal beyond
    broad_relief: str = "auto"
    fractal: FractalRelief = field(default_factory=FractalRelief)
    fine_noise_m: float = 0.004  # smoothed fine noise std
    # crater classes: (min radius, max radius, density per m²), OmniLRS-like
    crater_classes: tuple[tuple[float, float, float], ...] = (
        (0.75, 1.25, 0.03),
        (0.4, 0.75, 0.05),
        (0.15, 0.4, 0.15),
    )
    crossable_depth_ratio: tuple[float, float] = (0.08, 0.15)  # depth/diameter near routes (walls ≤ 25°)
    # depth/diameter of large craters off routes: fresh simple craters, d/D ≈ 0.2 (Pike 1977: 0.196); no lunar
    # crater is deeper (the cosine bowl's steepest wall is π·d/D: 0.21 → 33°, the regolith's angle of repose)
    hazard_depth_ratio: tuple[float, float] = (0.17, 0.21)
    fresh_depth_ratio: tuple[float, float] = (0.12, 0.2)  # smaller craters off routes (fresh: ≈ 0.2)
    # craters larger than the paper's classes, drawn where the field holds them (radius ≤ `large_max_field_frac`
    # of its side: none on the 20 m field, up to 10 m radius on 100 m, 20 m on 200 m): the lunar equilibrium
    # population, cumulative N(≥D) = `equilibrium_k` · D⁻² per m² (D in m; Trask 1966, Gault 1970; Minton et al.
    # 2019: ∝ r⁻²), in octaves of radius from `large_min_radius_m`. At these sizes that population is
    # degraded by diffusion (Minton et al. 2019), d/D `degraded_depth_ratio` (Ivanov 2018's small craters' aging
    # review: d/D falls from ≈ 0.2 towards 0.05), walls ≤ 18°; they superpose, the smaller craters lie on them.
    equilibrium_k: float = 10**-1.1
    large_min_radius_m: float = 2.5
    large_max_field_frac: float = 0.1
    degraded_depth_ratio: tuple[float, float] = (0.04, 0.1)
    # where a large crater's bowl or rim reaches a corridor, it is made shallower (if need be) so that its
    # steepest wall (π·d/D for the cosine bowl) on the broad slope under it (the relief and earlier large
    # craters, smoothed at 1 m) stays within this: the corridor cap less room for the small craters on it
    crossable_large_max_slope_deg: float = 20.0
    rim_ratio: float = 0.15  # rim height / depth
    rock_clusters_per_m2: float = 0.03
    rocks_per_cluster: float = 6.0
    rock_cluster_sigma_m: float = 0.6
    rock_height_m: tuple[float, float] = (0.02, 0.08)  # rocks near routes
    hazard_rock_height_m: tuple[float, float] = (0.15, 0.3)  # some rocks off routes
    routes: tuple[tuple[tuple[float, float], ...], ...] | None = None  # default: `lunar_routes(size_m)`
    corridor_m: float = 1.2  # half-width of the surveyed corridors along routes
    spawn_radius_m: float = 0.9  # flattened patch around route ends
    corridor_max_slope_deg: float = 26.0  # slopes within corridors are smoothed down to this cap
    # a measured broad relief (n, n) at `res` (e.g. a DEM window, `scout_agent.dem_reader`) instead of the
    # seeded one; the seeded detail (fine noise, craters, rocks) is added on top
    base: np.ndarray | None = field(default=None, compare=False, repr=False)
    base_info: dict = field(default_factory=dict, compare=False, repr=False)


def _fractal(cfg: LunarConfig) -> bool:
    if cfg.broad_relief not in ("auto", "paper", "fractal"):
        raise ScoutConfigError(f"broad_relief {cfg.broad_relief!r}; valid: auto, paper, fractal")
    return cfg.broad_relief == "fractal" or (cfg.broad_relief == "auto" and cfg.size_m > PAPER_FIELD_M)


def make_lunar(cfg: LunarConfig = LunarConfig()) -> Terrain:
    """The seeded field. Densities are per m², so a larger field holds proportionally more craters and rocks;
    its broad relief is the paper's on the 20 m field and self-affine beyond (`broad_relief`), so the relief a
    longer walk crosses grows with its length as on the Moon."""
    fractal = _fractal(cfg)
    rng = np.random.default_rng(cfg.seed)
    named = lunar_routes(cfg.size_m)
    routes = cfg.routes if cfg.routes is not None else tuple(named.values())
    n = int(round(cfg.size_m / cfg.res)) + 1
    xs = np.arange(n) * cfg.res
    X, Y = np.meshgrid(xs, xs)
    # broad relief: uniform noise on a coarse grid, bicubic upsampling, then slope cap (or a DEM's)
    cells = max(3, int(round(cfg.size_m / cfg.relief_spacing_m)) + 1)
    coarse = rng.uniform(-0.5, 0.5, (cells, cells))  # drawn either way: same detail
    if cfg.base is not None:
        if cfg.base.shape != (n, n):
            raise ScoutConfigError(f"base relief {cfg.base.shape}: need ({n}, {n}) at res {cfg.res} m")
        z = np.array(cfg.base, dtype=np.float64)
    elif fractal:
        z = fractal_relief(cfg.fractal, cfg.size_m, cfg.res, cfg.seed, routes=tuple(routes))
    else:
        z = zoom(coarse, (n - 1) / (cells - 1) + 1e-9, order=3, mode="nearest")[:n, :n]
        z = (z - z.min()) / max(np.ptp(z), 1e-9) * cfg.relief_m - cfg.relief_m / 2
        g = np.hypot(*np.gradient(z, cfg.res))
        z *= min(1.0, np.tan(np.radians(cfg.relief_max_slope_deg)) / g.max())
    z += gaussian_filter(rng.normal(0.0, 1.0, z.shape), 2.0) * cfg.fine_noise_m * 2.0 / 0.14

    route_dist = np.full(z.shape, np.inf)
    for route in routes:
        route_dist = np.minimum(route_dist, _polyline_distance(X, Y, route))
    routes_arr = [np.asarray(r, dtype=float) for r in routes]

    def dist_to_routes(px: float, py: float) -> float:
        return float(min(_polyline_distance(np.array(px), np.array(py), r) for r in routes_arr))

    # craters: hard-core Poisson process per class, largest first
    area = cfg.size_m**2
    placed = _Buckets(cell_m=2.0 * cfg.crater_classes[0][1])  # placed craters, hashed by position
    craters = []
    for rmin, rmax, density in cfg.crater_classes:
        for _ in range(rng.poisson(density * area)):
            r = rng.uniform(rmin, rmax)
            cx, cy = rng.uniform(0, cfg.size_m, 2)
            near = dist_to_routes(cx, cy) < r * 1.3 + cfg.corridor_m
            gap = 1.3 if near else 0.9  # craters do not overlap where routes run
            if any(np.hypot(cx - px, cy - py) < gap * (r + pr) for px, py, pr in placed.near(cx, cy)):
                continue
            ends = min(np.hypot(cx - e[0], cy - e[1]) for rt in routes_arr for e in (rt[0], rt[-1]))
            if ends < r * 1.3 + cfg.spawn_radius_m + 0.5:
                continue
            hazard = (not near) and r >= cfg.crater_classes[0][0]
            ratio = rng.uniform(
                *(
                    cfg.hazard_depth_ratio
                    if hazard
                    else cfg.crossable_depth_ratio
                    if near
                    else cfg.fresh_depth_ratio
                )
            )
            depth = ratio * 2 * r
            ell = rng.uniform(0.85, 1.0)
            rot = rng.uniform(0, np.pi)
            placed.add(cx, cy, r)
            craters.append(
                {"x": float(cx), "y": float(cy), "r": float(r), "depth": float(depth), "hazard": bool(hazard)}
            )
            win = r * 2.0
            i0, i1 = int(max(0, (cy - win) / cfg.res)), int(min(n, (cy + win) / cfg.res + 2))
            j0, j1 = int(max(0, (cx - win) / cfg.res)), int(min(n, (cx + win) / cfg.res + 2))
            dx, dy = X[i0:i1, j0:j1] - cx, Y[i0:i1, j0:j1] - cy
            u = dx * np.cos(rot) + dy * np.sin(rot)
            v = (-dx * np.sin(rot) + dy * np.cos(rot)) / ell
            rho = np.hypot(u, v) / r
            bowl = np.where(rho < 1.0, -depth * 0.5 * (1.0 + np.cos(np.pi * np.minimum(rho, 1.0))), 0.0)
            rim = cfg.rim_ratio * depth * np.exp(-(((rho - 1.0) / 0.35) ** 2))
            z[i0:i1, j0:j1] += bowl + rim

    craters.extend(_large_craters(cfg, z, X, Y, routes_arr, route_dist))

    # rocks: Thomas cluster process of smooth bumps (σ ≥ 1.6·height keeps shoulders ≤ ~21°)
    rocks = []
    for _ in range(rng.poisson(cfg.rock_clusters_per_m2 * area)):
        px, py = rng.uniform(0, cfg.size_m, 2)
        for _ in range(rng.poisson(cfg.rocks_per_cluster)):
            cx, cy = rng.normal((px, py), cfg.rock_cluster_sigma_m)
            if not (0 <= cx <= cfg.size_m and 0 <= cy <= cfg.size_m):
                continue
            dr = dist_to_routes(cx, cy)
            hazard = dr > cfg.corridor_m + 0.6 and rng.uniform() < 0.3
            h = rng.uniform(*(cfg.hazard_rock_height_m if hazard else cfg.rock_height_m))
            sigma = max(1.6 * h, 0.1) if not hazard else rng.uniform(0.15, 0.25)
            rocks.append({"x": float(cx), "y": float(cy), "h": float(h), "hazard": bool(hazard)})
            win = 3 * sigma
            i0, i1 = int(max(0, (cy - win) / cfg.res)), int(min(n, (cy + win) / cfg.res + 2))
            j0, j1 = int(max(0, (cx - win) / cfg.res)), int(min(n, (cx + win) / cfg.res + 2))
            d2 = (X[i0:i1, j0:j1] - cx) ** 2 + (Y[i0:i1, j0:j1] - cy) ** 2
            z[i0:i1, j0:j1] += h * np.exp(-d2 / (2 * sigma**2))

    # flat spawn/goal patches: blend to the local mean height (on a window around each end); at mission scale
    # over a wider ring, as a patch levelled on a hillside would otherwise end in a step
    blend_m = 0.6 if not fractal else 2.5
    for rt in routes_arr:
        for ex, ey in (rt[0], rt[-1]):
            rad = cfg.spawn_radius_m + blend_m
            i0, i1 = int(max(0, (ey - rad) / cfg.res - 1)), int(min(n, (ey + rad) / cfg.res + 2))
            j0, j1 = int(max(0, (ex - rad) / cfg.res - 1)), int(min(n, (ex + rad) / cfg.res + 2))
            d = np.hypot(X[i0:i1, j0:j1] - ex, Y[i0:i1, j0:j1] - ey)
            inner = d <= cfg.spawn_radius_m
            w = np.clip((rad - d) / blend_m, 0.0, 1.0)
            w = w * w * (3 - 2 * w)
            zw = z[i0:i1, j0:j1]
            z[i0:i1, j0:j1] = zw * (1 - w) + float(zw[inner].mean()) * w

    cap = cfg.corridor_max_slope_deg
    z = _cap_corridor_slopes(z, route_dist <= cfg.corridor_m, cfg.res, cap, blend=fractal)

    direct = named["direct"]
    yaw = float(np.arctan2(direct[1][1] - direct[0][1], direct[1][0] - direct[0][0]))
    name = f"dem{cfg.seed}" if cfg.base is not None else f"lunar{cfg.seed}"
    terrain = Terrain(
        z=z,
        res=cfg.res,
        x0=0.0,
        y0=0.0,
        name=name,
        spawn=(direct[0][0], direct[0][1], yaw),
        goal=direct[-1],
        info={
            "seed": cfg.seed,
            "craters": craters,
            "rocks": rocks,
            **cfg.base_info,
            "routes": {k: [list(p) for p in v] for k, v in named.items()},
            "size_m": cfg.size_m,
        },
    )
    return terrain


def large_crater_classes(cfg: LunarConfig) -> list[tuple[float, float, float]]:
    """(min radius, max radius, density per m²) of the degraded craters larger than the paper's classes that
    a `cfg.size_m` field holds: octaves of radius from `large_min_radius_m` up to `large_max_field_frac` of the
    side, each with the equilibrium density N(≥2 r_min) − N(≥2 r_max)."""
    out = []
    top = cfg.large_max_field_frac * cfg.size_m
    r = cfg.large_min_radius_m
    while r < top:
        r1 = min(2.0 * r, top)
        out.append((r, r1, cfg.equilibrium_k * ((2.0 * r) ** -2 - (2.0 * r1) ** -2)))
        r = r1
    return out


def _large_craters(
    cfg: LunarConfig, z: np.ndarray, X: np.ndarray, Y: np.ndarray, routes_arr, route_dist: np.ndarray
) -> list[dict]:
    """Carve `large_crater_classes` into z (in place), with their own random stream (the paper's classes and
    rocks draw the same numbers at every field size); they keep clear of the route ends' flat patches, and
    where one reaches a corridor it is no steeper than `crossable_large_max_slope_deg` allows there."""
    rng = np.random.default_rng([cfg.seed, 1])
    n = z.shape[0]
    target = np.tan(np.radians(cfg.crossable_large_max_slope_deg))
    out = []
    for rmin, rmax, density in large_crater_classes(cfg):
        for _ in range(rng.poisson(density * cfg.size_m**2)):
            # sizes within the class follow the same r⁻² law (inverse-CDF of the cumulative r⁻²)
            u = rng.uniform()
            r = 1.0 / np.sqrt(rmin**-2 - u * (rmin**-2 - rmax**-2))
            cx, cy = rng.uniform(0, cfg.size_m, 2)
            ratio = rng.uniform(*cfg.degraded_depth_ratio)
            ends = min(np.hypot(cx - e[0], cy - e[1]) for rt in routes_arr for e in (rt[0], rt[-1]))
            if ends < r * 1.3 + cfg.spawn_radius_m + 0.5:
                continue
            win = r * 2.0
            i0, i1 = int(max(0, (cy - win) / cfg.res)), int(min(n, (cy + win) / cfg.res + 2))
            j0, j1 = int(max(0, (cx - win) / cfg.res)), int(min(n, (cx + win) / cfg.res + 2))
            rho = np.hypot(X[i0:i1, j0:j1] - cx, Y[i0:i1, j0:j1] - cy) / r
            crossed = (rho < 1.6) & (route_dist[i0:i1, j0:j1] <= cfg.corridor_m + 0.5)
            if crossed.any():
                broad = gaussian_filter(z[i0:i1, j0:j1], 1.0 / cfg.res, mode="nearest")
                under = float(np.hypot(*np.gradient(broad, cfg.res))[crossed].max())
                ratio = min(ratio, max(0.005, (target - under) / np.pi))
            depth = ratio * 2 * r
            out.append(
                {
                    "x": float(cx),
                    "y": float(cy),
                    "r": float(r),
                    "depth": float(depth),
                    "hazard": False,
                    "crossable": bool(crossed.any()),
                }
            )
            bowl = np.where(rho < 1.0, -depth * 0.5 * (1.0 + np.cos(np.pi * np.minimum(rho, 1.0))), 0.0)
            rim = cfg.rim_ratio * depth * np.exp(-(((rho - 1.0) / 0.35) ** 2))
            z[i0:i1, j0:j1] += bowl + rim
    return out


class _Buckets:
    """Points with a radius, hashed on a square grid, so a neighbour test on a 200 m field with ~9,000
    craters costs the few nearby ones, not all placed so far."""

    def __init__(self, cell_m: float) -> None:
        self.cell = cell_m
        self.grid: dict[tuple[int, int], list[tuple[float, float, float]]] = {}

    def add(self, x: float, y: float, r: float) -> None:
        self.grid.setdefault((int(x // self.cell), int(y // self.cell)), []).append((x, y, r))

    def near(self, x: float, y: float) -> list[tuple[float, float, float]]:
        """Every point within one cell (≥ the largest gap · (r + r')) of (x, y)."""
        i, j = int(x // self.cell), int(y // self.cell)
        out: list[tuple[float, float, float]] = []
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                out.extend(self.grid.get((i + di, j + dj), ()))
        return out


_CLUSTER_GAP = 40


def _steep_cells(z: np.ndarray, corridor_cells: np.ndarray, res: float, cap: float) -> np.ndarray:
    """Corridor cells whose steeper MuJoCo triangle (as Terrain.slope_grid_deg) exceeds `cap` (a tangent)."""
    g1 = np.hypot(z[:-1, 1:] - z[:-1, :-1], z[1:, 1:] - z[:-1, 1:])
    g2 = np.hypot(z[1:, 1:] - z[1:, :-1], z[1:, :-1] - z[:-1, :-1])
    return (np.maximum(g1, g2) / res > cap) & corridor_cells


def _cap_corridor_slopes(
    z: np.ndarray, corridor: np.ndarray, res: float, cap_deg: float, blend: bool = False
) -> np.ndarray:
    """Smooth, locally and repeatedly, wherever the slope inside `corridor` exceeds `cap_deg`. Each cluster of
    steep cells is smoothed in its own window: a pass changes heights within 5 cells of a steep cell and reads
    6 further (the filter), so clusters more than 24 cells apart do not interact and a 200 m field costs what
    its steep spots do, not 80 passes over 16 M heights. The paper's field replaces the heights there outright
    (its digest pins that); with `blend` (fields at mission scale) the smoothed heights are blended in with a
    weight that falls off over `_BLEND_SIGMA` cells and is 0 at the window's edges, so the accumulated change
    leaves no step (seam) at the rim of the smoothed region or window."""
    from scipy.ndimage import binary_dilation, find_objects, label

    z = z.copy()
    cap = np.tan(np.radians(cap_deg))
    corridor_cells = corridor[:-1, :-1] & corridor[1:, 1:]
    steep = _steep_cells(z, corridor_cells, res, cap)
    if not steep.any():
        return z
    gap = _CLUSTER_GAP + (3 * _BLEND_SIGMA if blend else 0)
    clusters, _ = label(binary_dilation(steep, iterations=gap))
    for sl in find_objects(clusters):
        # the cluster's window (cells) with a margin, as heights (one more row/column)
        r0, r1 = max(0, sl[0].start - gap), min(corridor_cells.shape[0], sl[0].stop + gap)
        c0, c1 = max(0, sl[1].start - gap), min(corridor_cells.shape[1], sl[1].stop + gap)
        sub = z[r0 : r1 + 1, c0 : c1 + 1]  # a view: smoothing writes into z
        cells = corridor_cells[r0:r1, c0:c1]
        inner = (r0 > 0, r1 < corridor_cells.shape[0], c0 > 0, c1 < corridor_cells.shape[1])
        taper = _edge_taper(sub.shape, _BLEND_SIGMA, inner) if blend else None
        for _ in range(80 if not blend else 160):
            bad_cells = _steep_cells(sub, cells, res, cap)
            if not bad_cells.any():
                break
            bad = np.zeros(sub.shape, bool)
            bad[:-1, :-1] |= bad_cells
            bad[1:, 1:] |= bad_cells
            region = binary_dilation(bad, iterations=4)
            if taper is None:
                sub[region] = gaussian_filter(sub, 1.5)[region]
            else:
                w = np.clip(2.0 * gaussian_filter(region.astype(float), _BLEND_SIGMA), 0.0, 1.0) * taper
                sub += (gaussian_filter(sub, 1.5, mode="nearest") - sub) * w
    return z


_BLEND_SIGMA = 10  # cells over which a blended cap pass's weight falls off


def _edge_taper(shape: tuple[int, int], width: int, sides: tuple[bool, bool, bool, bool]) -> np.ndarray:
    """A (rows, cols) weight 0 on the chosen borders (low row, high row, low column, high column: a window's
    sides inside the field; the field's own edge has no neighbour to make a seam with) rising smoothly
    (smoothstep) to 1 at `2·width` cells inside them."""
    out = np.ones(shape)
    for axis, m in enumerate(shape):
        lo, hi = sides[2 * axis], sides[2 * axis + 1]
        i = np.arange(m, dtype=float)
        dist = np.minimum(i if lo else np.inf, (m - 1 - i) if hi else np.inf)
        t = np.clip(dist / (2.0 * width), 0.0, 1.0)
        t = t * t * (3 - 2 * t)
        out *= t.reshape((-1, 1) if axis == 0 else (1, -1))
    return out


def route_slope_stats(terrain: Terrain, half_width: float = 0.5) -> dict[str, dict[str, float]]:
    """Slope statistics of the whole field and of the cells within `half_width` of each lunar route."""
    out = {"all": terrain.slope_stats()}
    for name, route in lunar_routes(float(terrain.info.get("size_m", PAPER_FIELD_M))).items():
        out[name] = terrain.slope_stats(terrain.corridor_mask(route, half_width))
    return out
