"""Per-cell travel cost [1/m] from map layers: named terms, weights from a frozen config, unknown policy.

    cost[cell] = sum_k weights.k * term_k[cell]        (impassable cells: +inf)

Terms (all dimensionless per metre, >= 0; a metric with no estimate at a cell contributes 0):

| term | from | value |
|---|---|---|
| distance | - | 1 (every metre costs at least this) |
| cot | `cot` value (work / dist) | CoT |
| slip | `slip` events / n | expected slip events per metre = rate * `stances_per_m` |
| giim | `giim` mean [rad] | max(0, (giim_ref - giim) / giim_ref): less margin, more cost |
| giam | `giam` mean [m/s^2] | max(0, (giam_ref - giam) / giam_ref) |
| slope | `elevation` plane fit | slope_deg / slope_ref_deg |
| confidence | counts `n` | n_ref / (n_ref + n), n = most samples of any layer in the cell |

A cell is *known* when any layer holds samples there. Gaps inside known cells (e.g. CoT undefined
below 5 cm of travel) are filled like inferred cells, below. Unknown cells by `unknown` policy:
`forbid` - impassable; `penalty` - cost = weights.distance + `unknown_penalty` (no other term);
`infer` - every metric filled by a Gaussian-weighted average of nearby known cells (paper eq. 17,
normalised by the weight of the known cells: sum_uv m_uv S_uv N(.) / sum_uv m_uv N(.), sigma
`infer_sigma_cells`, cut at 3 sigma); the cell is marked `inferred` and costed like a known one
(its confidence term is the full weight, n = 0); cells with no known cell within reach stay
impassable. Hard limits (`Limits`) make a known or inferred cell impassable.

Slip spreading (`slip_spread_m`, default 0.8 m; 0 = off): the slip-rate metric of every cell is the
largest measured slip rate (events / n of a known cell) within `slip_spread_m` of it, centre to centre
(a grey dilation over a disc; a cell's own rate counts, and a gap- or eq.-17-filled rate is kept where
it is larger). A scout's slip layer marks only the cells its feet slipped in, a strip narrower than the
slippery ground; read raw, a planner steps one cell aside and still crosses the patch (paper eq. 17
smooths the slip layer at read time for the same reason). A cell reached only by the spread (no
samples, not inferred) counts as known *for the slip term alone*: it keeps its unknown policy for
everything else — under `penalty` it costs distance + `unknown_penalty` + the slip term (spreading
never makes unmapped ground cheaper), under `forbid` (and `infer` beyond reach) it stays impassable,
it does not make a cell `inferred`, and it counts as unknown in a route's `unknown_fraction`.
`Limits.max_slip_rate` reads the spread rate too. The breakdown's `expected_slip_events` reads the
same spread rate the slip term charges (so terms["slip"] = weights.slip * expected_slip_events): an
upper estimate near slip cells; `slip_spread_m=0` gives the raw layer's count.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Literal

import numpy as np
from scipy import ndimage

from consumer_planner.errors import PlannerError
from consumer_planner.grid import LayerGrid

__all__ = [
    "METRICS",
    "TERMS",
    "UNKNOWN_POLICIES",
    "CostConfig",
    "CostMap",
    "Limits",
    "Weights",
    "build_costs",
    "parse_weights",
    "spread_max",
]

UNKNOWN_POLICIES = ("forbid", "penalty", "infer")
UnknownPolicy = Literal["forbid", "penalty", "infer"]
METRICS = ("cot", "slip_rate", "giim", "giam", "slope_deg")  # per-cell values the terms read


@dataclass(frozen=True)
class Weights:
    """Weight of each cost term (>= 0); names are the CLI's `--weights name=value` keys."""

    distance: float = 1.0
    cot: float = 1.0
    slip: float = 1.0
    giim: float = 1.0
    giam: float = 1.0
    slope: float = 1.0
    confidence: float = 0.5


TERMS = tuple(f.name for f in fields(Weights))


@dataclass(frozen=True)
class Limits:
    """Hard limits: a cell beyond any of them is impassable (NaN metrics never trip a limit)."""

    max_slope_deg: float = 30.0  # what a trot crosses (REFERENCE: 33 deg craters barely, 39 deg fall)
    min_giim_rad: float = 0.087  # 5 deg: four-foothold GIIM fell below this 0.5-1 s before falls
    min_giam: float = -math.inf  # [m/s^2]
    max_slip_rate: float = math.inf  # slip events per stance


@dataclass(frozen=True)
class CostConfig:
    weights: Weights = field(default_factory=Weights)
    limits: Limits = field(default_factory=Limits)
    unknown: UnknownPolicy = "penalty"
    unknown_penalty: float = 4.0  # [1/m] added to the distance term on unknown cells (policy penalty)
    infer_sigma_cells: float = 2.0  # Gaussian sigma of the fill (eq. 17) [cells]
    stances_per_m: float = 28.0  # stance phases per metre: 4 feet x 1.4 Hz trot / 0.2 m/s
    giim_ref_rad: float = 0.6  # GIIM at or above this costs nothing (flat static Aliengo ~0.6 rad)
    giam_ref: float = 0.9  # [m/s^2], ditto (flat static ~0.9 m/s^2)
    slope_ref_deg: float = 30.0  # slope term = 1 at this slope
    confidence_n: float = 10.0  # samples at which the confidence term halves
    # [m] the slip term of a cell reads the largest slip rate within this radius (0 = the raw layer);
    # 0.8 m = half a slippery patch: in the map-utility experiment this made planned routes avoid patches
    slip_spread_m: float = 0.8

    def __post_init__(self) -> None:
        if self.unknown not in UNKNOWN_POLICIES:
            raise PlannerError(f"no unknown policy {self.unknown!r}; policies: {', '.join(UNKNOWN_POLICIES)}")
        if not (self.slip_spread_m >= 0 and math.isfinite(self.slip_spread_m)):
            raise PlannerError(f"slip_spread_m={self.slip_spread_m} must be a finite radius >= 0 m (0 = off)")
        bad = [f"{t}={getattr(self.weights, t)}" for t in TERMS if not getattr(self.weights, t) >= 0]
        if bad:
            raise PlannerError(f"weights must be finite and >= 0: {', '.join(bad)}")


def parse_weights(text: str, base: Weights | None = None) -> Weights:
    """`cot=1,slip=2` -> Weights (unnamed terms keep `base`); PlannerError naming the valid terms."""
    values: dict[str, float] = {}
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        name, sep, num = part.partition("=")
        name = name.strip()
        if not sep or name not in TERMS:
            raise PlannerError(f"bad weight {part!r}; give name=value with name in: {', '.join(TERMS)}")
        try:
            values[name] = float(num)
        except ValueError:
            raise PlannerError(f"weight {name}={num!r} is not a number") from None
        if not (values[name] >= 0 and math.isfinite(values[name])):
            raise PlannerError(f"weight {name}={num} must be finite and >= 0")
    return Weights(**{**(base or Weights()).__dict__, **values})


@dataclass(frozen=True, eq=False)
class CostMap:
    """Everything a route breakdown needs, all (h, w): `cost` [1/m] (+inf impassable), the weighted
    `terms` (summing to `cost` on passable cells; `unknown` = the penalty), the `metrics` the terms read
    (filled where inferred), and the masks `known`, `inferred`, `impassable`."""

    cost: np.ndarray
    terms: dict[str, np.ndarray]
    metrics: dict[str, np.ndarray]
    known: np.ndarray
    inferred: np.ndarray
    impassable: np.ndarray
    config: CostConfig


def gaussian_fill(values: np.ndarray, sigma_cells: float, weight: np.ndarray | None = None) -> np.ndarray:
    """Paper eq. 17 normalised over known cells: NaN cells get sum(w * v) / sum(w) of the finite cells
    within 3 sigma (Gaussian weights w); NaN where none is in reach. Finite cells are kept.
    `weight`: the filtered finite-mask, when the caller already has it for this exact mask."""
    mask = np.isfinite(values)
    if mask.all() or not mask.any():
        return values.copy()
    num = _smooth(np.where(mask, values, 0.0), sigma_cells)
    den = _smooth(mask.astype(np.float64), sigma_cells) if weight is None else weight
    out = values.copy()
    reach = ~mask & (den > 1e-12)
    out[reach] = num[reach] / den[reach]
    return out


def _smooth(a: np.ndarray, sigma_cells: float) -> np.ndarray:
    return ndimage.gaussian_filter(a, sigma=sigma_cells, mode="constant", cval=0.0, truncate=3.0)


def read_metrics(grid: LayerGrid) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """(metrics {name: (h, w), NaN = no estimate}, count (h, w) = most samples of any layer)."""
    metrics = {
        "cot": grid.value("cot"),
        "slip_rate": grid.slip_rate(),
        "giim": grid.value("giim"),
        "giam": grid.value("giam"),
        "slope_deg": grid.slope_deg(),
    }
    count = np.zeros(grid.shape)
    for layer in grid.layers:
        count = np.maximum(count, grid.count(layer))
    return metrics, count


def spread_max(values: np.ndarray, radius_m: float, res: float) -> np.ndarray:
    """Per cell, the largest finite value among the cells whose centres lie within `radius_m` of its
    centre (itself included; a grey dilation over a disc of cells); NaN where none is finite."""
    r = int(math.floor(radius_m / res + 1e-9))
    if r < 1:
        return values.copy()
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disc = (xx**2 + yy**2) * res**2 <= radius_m**2 + 1e-9 * res**2
    lifted = np.where(np.isfinite(values), values, -np.inf)
    out = ndimage.maximum_filter(lifted, footprint=disc, mode="constant", cval=-np.inf)
    return np.where(np.isfinite(out), out, np.nan)


def _margin_term(x: np.ndarray, ref: float) -> np.ndarray:
    return np.maximum(0.0, (ref - x) / ref)


_TERM_FUNCS: dict[str, Callable[[dict[str, np.ndarray], np.ndarray, CostConfig], np.ndarray]] = {
    "distance": lambda m, n, c: np.ones_like(n),
    "cot": lambda m, n, c: m["cot"],
    "slip": lambda m, n, c: m["slip_rate"] * c.stances_per_m,
    "giim": lambda m, n, c: _margin_term(m["giim"], c.giim_ref_rad),
    "giam": lambda m, n, c: _margin_term(m["giam"], c.giam_ref),
    "slope": lambda m, n, c: m["slope_deg"] / c.slope_ref_deg,
    "confidence": lambda m, n, c: c.confidence_n / (c.confidence_n + n),
}


def build_costs(grid: LayerGrid, config: CostConfig | None = None) -> CostMap:
    """The cost grid of `grid` under `config` (see the module docstring for every rule)."""
    config = config or CostConfig()
    raw, count = read_metrics(grid)
    known = count > 0
    metrics: dict[str, np.ndarray] = {}
    known_weight: np.ndarray | None = None  # the fill's denominator, shared by metrics known on `known`
    measured_slip = np.where(known, raw["slip_rate"], np.nan)
    for name, m in raw.items():
        keep = np.where(known, m, np.nan)  # only samples of known cells feed the fill
        weight = None
        if np.array_equal(np.isfinite(keep), known):
            if known_weight is None:
                known_weight = _smooth(known.astype(np.float64), config.infer_sigma_cells)
            weight = known_weight
        filled = gaussian_fill(keep, config.infer_sigma_cells, weight)
        if config.unknown != "infer":
            filled = np.where(known, filled, np.nan)
        metrics[name] = filled
    if config.unknown == "infer":
        reach = np.zeros(grid.shape, bool)
        for m in metrics.values():
            reach |= np.isfinite(m)
        inferred = ~known & reach
    else:
        inferred = np.zeros(grid.shape, bool)
    costed = known | inferred
    if config.slip_spread_m > 0:  # after `inferred`: the spread alone never makes a cell inferred
        metrics["slip_rate"] = np.fmax(
            metrics["slip_rate"], spread_max(measured_slip, config.slip_spread_m, grid.res)
        )
    slip_costed = costed | np.isfinite(metrics["slip_rate"])  # + cells reached only by the spread

    lim = config.limits
    with np.errstate(invalid="ignore"):
        over = (
            (metrics["slope_deg"] > lim.max_slope_deg)
            | (metrics["giim"] < lim.min_giim_rad)
            | (metrics["giam"] < lim.min_giam)
            | (metrics["slip_rate"] > lim.max_slip_rate)
        )
    terms: dict[str, np.ndarray] = {}
    for name in TERMS:
        t = np.nan_to_num(_TERM_FUNCS[name](metrics, count, config), nan=0.0)
        terms[name] = np.where(
            slip_costed if name == "slip" else costed, getattr(config.weights, name) * t, 0.0
        )
    penalized = ~costed if config.unknown == "penalty" else np.zeros(grid.shape, bool)
    terms["distance"] = np.where(penalized, config.weights.distance, terms["distance"])
    terms["unknown"] = np.where(penalized, config.unknown_penalty, 0.0)
    # metrics are NaN (never over a limit) on uncosted cells, except a spread slip rate there
    impassable = over | (~costed & ~penalized)
    cost = np.zeros(grid.shape)
    for t in terms.values():
        cost += t
    cost[impassable] = np.inf
    return CostMap(cost, terms, metrics, known, inferred, impassable, config)
