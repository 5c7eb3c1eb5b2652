"""Ground friction as a map in the map frame: a default coefficient plus rectangular patches.

The simulator applies it at no speed cost: the feet have a higher contact `priority` than the ground, so
MuJoCo uses the foot geom's friction, and each foot's friction is set from this map at the foot's position
every control tick. The map is ground truth (exported, logged, used in evaluation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from scout_agent.errors import ScoutConfigError
from scout_agent.sim.terrain import LUNAR_ROUTES, Terrain

DEFAULT_MU = 0.7  # regolith (internal friction angle 35–39°, Apollo 12)


@dataclass(frozen=True)
class RegolithFriction:
    """The friction of a loose-regolith patch, as a distribution of its friction angle φ [deg]; μ = tan φ.

    Source of the scale: the Lunar Sourcebook (Carrier, Olhoeft & Mendell 1991, ch. 9.1.6, Table 9.11)
    gives bulk regolith friction angles of ≈ 30–50° (best estimate 42° for the top 15 cm) and notes that
    the loose, low-density surface layer and the regolith on steep crater walls near its angle of repose
    shear at much lower stresses. A foot on such a layer (or on dust over rock) grips far less than the
    bulk angle: the patches model that, with a truncated normal φ ~ N(`mean_deg`, `std_deg`) cut to
    [`min_deg`, `max_deg`]. The numbers below are a modelling assumption chosen to span ground a quadruped
    holds and ground it does not on 10–25° slopes (μ 0.14–0.47, median 0.29), not a measurement.
    """

    mean_deg: float = 16.0
    std_deg: float = 4.0
    min_deg: float = 8.0
    max_deg: float = 25.0

    def draw(self, rng: np.random.Generator) -> float:
        """One patch μ = tan φ, φ from the truncated normal (by rejection)."""
        while True:
            phi = float(rng.normal(self.mean_deg, self.std_deg))
            if self.min_deg <= phi <= self.max_deg:
                return float(np.tan(np.radians(phi)))


PATCH_REGOLITH = RegolithFriction()


@dataclass(frozen=True)
class Patch:
    """Axis-aligned rectangle [x0, x1] × [y0, y1] (map frame, m) of friction `mu`."""

    x0: float
    y0: float
    x1: float
    y1: float
    mu: float

    def __post_init__(self) -> None:
        if not (self.x1 > self.x0 and self.y1 > self.y0):
            raise ScoutConfigError(f"patch needs x0 < x1 and y0 < y1, got {self}")
        if not 0.0 < self.mu <= 2.0:
            raise ScoutConfigError(f"patch friction {self.mu} out of range; valid: 0 < mu <= 2")

    @classmethod
    def parse(cls, text: str) -> Patch:
        """From 'x0,y0,x1,y1,MU'."""
        parts = [float(v) for v in text.split(",")]
        if len(parts) != 5:
            raise ScoutConfigError(f"patch {text!r}: expected x0,y0,x1,y1,MU (5 numbers)")
        return cls(*parts)


@dataclass(frozen=True)
class FrictionMap:
    """Friction coefficient at any (x, y); later patches override earlier ones."""

    default: float = DEFAULT_MU
    patches: tuple[Patch, ...] = ()

    def __post_init__(self) -> None:
        # the patches as one (n, 5) table x0, y0, x1, y1, μ for the compiled lookup (not a field)
        table = np.array([[p.x0, p.y0, p.x1, p.y1, p.mu] for p in self.patches], dtype=float).reshape(-1, 5)
        object.__setattr__(self, "_table", table)

    def at(self, x, y) -> np.ndarray:
        """Friction at (x, y) (arrays broadcast)."""
        xb, yb = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        return self.at_points(xb.ravel(), yb.ravel()).reshape(xb.shape)

    def at_points(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Friction at the points (x, y), two float arrays (n,): the simulator's per-tick lookup."""
        mu = np.empty(len(x))
        _friction_at(self.default, self._table, x, y, mu)  # type: ignore[attr-defined]
        return mu

    def under_bodies(self, xpos: np.ndarray, bodies: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Friction under bodies: at the (x, y) of rows `bodies` of `xpos` (MuJoCo's body positions, (nbody,
        3)), into `out` (the simulator's per-tick lookup under the feet, without the copies)."""
        _friction_under(self.default, self._table, xpos, bodies, out)  # type: ignore[attr-defined]
        return out

    def grid(self, terrain: Terrain, res: float = 0.1) -> tuple[np.ndarray, tuple[float, float, float]]:
        """(ny, nx) friction raster over the terrain and its (x0, y0, res) for export/logging."""
        xa, ya, xb, yb = terrain.extent
        xs = np.arange(xa + res / 2, xb, res)
        ys = np.arange(ya + res / 2, yb, res)
        X, Y = np.meshgrid(xs, ys)
        return self.at(X, Y), (xa, ya, res)

    def to_dict(self) -> dict:
        return {"default": self.default, "patches": [[p.x0, p.y0, p.x1, p.y1, p.mu] for p in self.patches]}


@njit(cache=True, nogil=True)
def _friction_at(default: float, table: np.ndarray, x: np.ndarray, y: np.ndarray, out: np.ndarray) -> None:
    """`FrictionMap.at` compiled: the last patch of `table` (n, 5) containing each point, else `default`."""
    for i in range(x.shape[0]):
        mu = default
        for k in range(table.shape[0]):
            if table[k, 0] <= x[i] <= table[k, 2] and table[k, 1] <= y[i] <= table[k, 3]:
                mu = table[k, 4]
        out[i] = mu


def ramp_slippery_patch(terrain: Terrain, mu: float) -> Patch:
    """A patch over the middle half of the down-ramp, across the testbed's width."""
    a, b = terrain.info["segments"]["down"]
    _, ya, _, yb = terrain.extent
    q = (b - a) / 4
    return Patch(a + q, ya, b - q, yb, mu)


def lunar_slippery_patches(
    terrain: Terrain,
    n: int,
    seed: int = 0,
    size_m: float = 1.6,
    mu_range: tuple[float, float] = (0.2, 0.35),
    margin: float = 0.02,
    holdable: bool = False,
    regolith: RegolithFriction = PATCH_REGOLITH,
) -> tuple[Patch, ...]:
    """`n` seeded patches spread over the lunar routes in turn, preferably where the route descends 10–20°
    (else anywhere on it).

    Default (honest worlds): each patch's μ is drawn from `regolith` (`RegolithFriction`), with no regard
    for the slope under it, so a patch may be ground no robot can stand on (μ < tan slope).
    `holdable=True` keeps the paper experiments' old world: μ drawn uniformly from `mu_range` but at least
    tan(steepest slope inside the patch) + `margin`; places where that exceeds the range's top are
    skipped."""
    rng = np.random.default_rng(seed + 1000)
    h = size_m / 2
    grid = np.linspace(-h, h, 17)
    gx_, gy_ = np.meshgrid(grid, grid)
    pools = []
    routes = terrain.info.get("routes") or LUNAR_ROUTES  # the field's own (scaled with --field)
    for route in routes.values():
        cands: list[tuple[float, float]] = []
        fallback: list[tuple[float, float]] = []
        pts = np.asarray(route, dtype=float)
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            length = float(np.hypot(*(b - a)))
            u = (b - a) / length
            for s in np.arange(2.5, length - 2.5, 0.25):
                x, y = a + s * u
                gx, gy = terrain.gradient(x, y)
                descent = -np.degrees(np.arctan(gx * u[0] + gy * u[1]))
                (cands if 10.0 <= descent <= 20.0 else fallback).append((x, y))
        pools.append(
            [cands[k] for k in rng.permutation(len(cands))]
            + [fallback[k] for k in rng.permutation(len(fallback))]
        )
    patches: list[Patch] = []
    cursor = [0] * len(pools)
    stuck = 0
    while len(patches) < n and stuck < len(pools):
        stuck = 0
        for r, pool in enumerate(pools):
            if len(patches) >= n:
                break
            placed = False
            while cursor[r] < len(pool) and not placed:
                x, y = pool[cursor[r]]
                cursor[r] += 1
                if any(
                    abs(x - (p.x0 + p.x1) / 2) < size_m * 1.5 and abs(y - (p.y0 + p.y1) / 2) < size_m * 1.5
                    for p in patches
                ):
                    continue
                if holdable:
                    steep = float(np.max(terrain.slope_deg(x + gx_, y + gy_)))
                    mu_min = max(mu_range[0], np.tan(np.radians(steep)) + margin)
                    if mu_min > mu_range[1]:
                        continue
                    mu = float(rng.uniform(mu_min, mu_range[1]))
                else:
                    mu = regolith.draw(rng)
                patches.append(Patch(x - h, y - h, x + h, y + h, mu))
                placed = True
            stuck += not placed
    return tuple(patches)


def unholdable(mu, slope_deg) -> np.ndarray:
    """Ground truth: True where a robot cannot stand still, μ < tan(slope) (ground inclined by α holds a
    static load only while its friction coefficient exceeds tan α)."""
    return np.asarray(mu, float) < np.tan(np.radians(np.asarray(slope_deg, float)))


@njit(cache=True, nogil=True)
def _friction_under(
    default: float, table: np.ndarray, xpos: np.ndarray, bodies: np.ndarray, out: np.ndarray
) -> None:
    """`_friction_at` at the (x, y) of rows `bodies` of `xpos` (n, 3)."""
    for i in range(bodies.shape[0]):
        x, y = xpos[bodies[i], 0], xpos[bodies[i], 1]
        mu = default
        for k in range(table.shape[0]):
            if table[k, 0] <= x <= table[k, 2] and table[k, 1] <= y <= table[k, 3]:
                mu = table[k, 4]
        out[i] = mu
