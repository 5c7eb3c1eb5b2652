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
| slope | map slope (`protocol.layers.map_slope_deg`) | slope_deg / slope_ref_deg |
| confidence | counts `n` | n_ref / (n_ref + n), n = most samples of any layer in the cell |

The slope is the map's (`map_slope_deg`: the σ-weighted plane of the `height` layer where the cell has
one, else the `elevation` layer's). Where the cell's footholds clash (`protocol.layers.datum_clash`: they
scatter about their plane far beyond the vertical σ they state, two scouts' datums disagreeing) its plane is
a compromise between datums, not terrain: the slope there is *unknown* (NaN) — it never trips
`max_slope_deg` by itself, and is filled from the neighbours like any gap (below); `CostMap.datum_clash`
marks those cells. The cell's other layers (slip, CoT, margins) are measurements and stay.

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

Hazards (`hazard` layer: a scout's reflex stopped there, ground it could not hold): every cell whose centre
lies within `hazard_spread_m` of a cell with hazard reports is impassable (`hazard="forbid"`, the default)
or costs `hazard_penalty` more (`hazard="penalty"`, terms["hazard"]), whatever the other layers say there.

Speed (2000 x 2000 cells in well under a second; `benchmarks/plan.py`), with results bit for bit those
of the plain full-grid formulas (tests/consumer_planner/test_build_costs_reference.py keeps them): the
fill weight (the Gaussian of the finite-mask) is computed once per distinct mask; a fill filters only
the bounding box of the cells that need a value, widened by the kernel radius; the fills, the slip
spread and row blocks of the per-cell rules run on a few threads (scipy and numpy release the GIL);
the per-cell rules work on cache-sized row blocks written straight into the result arrays.
"""

from __future__ import annotations

import contextvars
import math
import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from consumer_planner.cost_config import (
    METRICS,
    TERMS,
    UNKNOWN_POLICIES,
    CostConfig,
    CostMap,
    Limits,
    Weights,
    parse_weights,
)
from consumer_planner.infer import FillBox, fill_box, fill_into, kernel_radius, smoothed_mask
from consumer_planner.spread import spread_cells, spread_finite, spread_max
from psrmap_mapcore import LayerGrid

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


def read_metrics(
    grid: LayerGrid, clash: np.ndarray | None = None
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """(metrics {name: (h, w), NaN = no estimate}, count (h, w) = most samples of any layer); the slope is NaN
    on `clash` cells (default `grid.datum_clash()`).

    The arrays may be the grid's own (never write to them)."""
    metrics = {
        "cot": grid.value("cot"),
        "slip_rate": grid.slip_rate(),
        "giim": grid.value("giim"),
        "giam": grid.value("giam"),
        "slope_deg": grid.slope_deg(),
    }
    clash = grid.datum_clash() if clash is None else clash
    if clash.any():  # a compromise between datums is not terrain: the slope there is unknown
        metrics["slope_deg"] = np.where(clash, np.nan, metrics["slope_deg"])
    # = max over layers of grid.count(layer) (nan_to_num'd n: NaN -> 0, +inf -> the largest float),
    # without a copy per layer: fmax skips NaN, the clip maps +inf; count >= 0 so -inf never wins.
    count = np.zeros(grid.shape)
    seen: set[int] = set()  # layers often share one `n` array
    for layer, stats in grid.layers.items():
        n = stats.get("n") if stats else None
        if n is None:
            np.maximum(count, grid.count(layer), out=count)
        elif id(n) not in seen:
            seen.add(id(n))
            np.fmax(count, n, out=count)
    np.minimum(count, np.finfo(np.float64).max, out=count)
    return metrics, count


def _copied(out: np.ndarray, values: np.ndarray | float) -> np.ndarray:
    np.copyto(out, values)
    return out


def _margin_term(x: np.ndarray, ref: float, out: np.ndarray) -> np.ndarray:
    np.subtract(ref, x, out=out)  # = np.maximum(0.0, (ref - x) / ref)
    np.divide(out, ref, out=out)
    return np.maximum(0.0, out, out=out)


# Each writes a term (unweighted; NaN where its metric is) into `out` (m: metrics, n: counts, c: config).
_TERM_FUNCS: dict[str, Callable[[dict[str, np.ndarray], np.ndarray, CostConfig, np.ndarray], np.ndarray]] = {
    "distance": lambda m, n, c, out: _copied(out, 1.0),
    "cot": lambda m, n, c, out: _copied(out, m["cot"]),
    "slip": lambda m, n, c, out: np.multiply(m["slip_rate"], c.stances_per_m, out=out),
    "giim": lambda m, n, c, out: _margin_term(m["giim"], c.giim_ref_rad, out),
    "giam": lambda m, n, c, out: _margin_term(m["giam"], c.giam_ref, out),
    "slope": lambda m, n, c, out: np.divide(m["slope_deg"], c.slope_ref_deg, out=out),
    "confidence": lambda m, n, c, out: np.divide(c.confidence_n, np.add(c.confidence_n, n, out=out), out=out),
}


def _weight_term(values: np.ndarray, weight: float, where: np.ndarray, outside: np.ndarray) -> None:
    """values[:] = where(where, weight * nan_to_num(values, nan=0.0), 0.0) (`outside` = ~where), in
    place and without nan_to_num's copies and +-inf scans when `values` hold no infinity (then it only
    maps NaN to 0)."""
    if not math.isfinite(weight) or np.isinf(values).any():  # inf * 0 = NaN; +-inf -> +-max float
        values[...] = np.where(where, weight * np.nan_to_num(values, nan=0.0), 0.0)
        return
    zero = np.isnan(values)
    zero |= outside
    np.multiply(values, weight, out=values)
    np.copyto(values, 0.0, where=zero)


# Grids of at least this many cells fill their metrics on a few threads (scipy's filters and numpy's
# loops release the GIL); smaller ones in the calling thread, where a pool costs more than it saves.
_PARALLEL_MIN_CELLS = 1 << 18


class _Inline:
    """The executor interface of `ThreadPoolExecutor` for running each job at once."""

    def submit(self, fn: Callable[..., object], /, *args: object) -> Future:
        f: Future = Future()
        f.set_result(fn(*args))
        return f

    def __enter__(self) -> _Inline:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


class _Pool:
    """A thread pool whose jobs run in a copy of the caller's context (so `np.errstate` reaches them)."""

    def __init__(self, workers: int) -> None:
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="build_costs")

    def submit(self, fn: Callable[..., object], /, *args: object) -> Future:
        return self._pool.submit(contextvars.copy_context().run, fn, *args)

    def __enter__(self) -> _Pool:
        return self

    def __exit__(self, *exc: object) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


def _executor(cells: int) -> _Pool | _Inline:
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if cells < _PARALLEL_MIN_CELLS or cpus < 2:
        return _Inline()
    return _Pool(min(cpus, 4))


# The result arrays' allocator (the tests hand out garbage instead, to prove every cell is written).
_empty = np.empty

# The per-cell part of the build (limits, terms, their sum) runs over blocks of this many cells, so the
# temporaries of one block stay in cache (and blocks spread over the pool's threads).
_BLOCK_CELLS = 1 << 16


def build_costs(grid: LayerGrid, config: CostConfig | None = None) -> CostMap:
    """The cost grid of `grid` under `config` (see the module docstring for every rule)."""
    config = config or CostConfig()
    clash = grid.datum_clash()
    raw, count = read_metrics(grid, clash)
    known = count > 0
    with _executor(grid.h * grid.w) as pool:
        spread: Future | None = None
        if config.slip_spread_m > 0:
            # the spread reads the measured rates: samples of known cells only, never a filled one
            slip, r_m = raw["slip_rate"], config.slip_spread_m
            if spread_cells(r_m, grid.res) >= 1:
                spread = pool.submit(spread_finite, slip, np.isfinite(slip) & known, r_m, grid.res)
            else:  # a disc of one cell: the measured rates themselves
                spread = pool.submit(np.where, known, slip, np.nan)
            del slip
        metrics = _fill_metrics(pool, raw, known, config)
        del raw  # (arrays read_metrics made, e.g. an all-NaN slope: their memory serves the results)
        if config.unknown == "infer":
            reach = np.zeros(grid.shape, bool)
            for m in metrics.values():
                reach |= np.isfinite(m)
            inferred = reach & ~known
        else:
            inferred = np.zeros(grid.shape, bool)
        costed = known | inferred
        if spread is not None:  # after `inferred`: the spread alone never makes a cell inferred
            np.fmax(metrics["slip_rate"], spread.result(), out=metrics["slip_rate"])
            del spread
        penalized = ~costed if config.unknown == "penalty" else np.zeros(grid.shape, bool)
        any_penalized = bool(penalized.any())
        out = _CostArrays(
            cost=_empty(grid.shape),
            # (np.zeros maps its pages lazily: a term that is 0 everywhere costs no memory traffic)
            terms={name: _empty(grid.shape) for name in TERMS}
            | {"unknown": _empty(grid.shape) if any_penalized else np.zeros(grid.shape)},
            impassable=_empty(grid.shape, bool),
            write_unknown=any_penalized,
        )
        step = max(1, _BLOCK_CELLS // max(1, grid.w))
        for f in [
            pool.submit(_cost_block, slice(r, r + step), metrics, count, costed, penalized, out, config)
            for r in range(0, grid.h, step)
        ]:
            f.result()
    terms = out.terms | {"hazard": _hazard_rule(grid, config, out.cost, out.impassable)}
    return CostMap(out.cost, terms, metrics, known, inferred, out.impassable, config, clash)


def _hazard_rule(grid: LayerGrid, config: CostConfig, cost: np.ndarray, impassable: np.ndarray) -> np.ndarray:
    """Apply the hazard policy in place to `cost` / `impassable`; returns the hazard term (zeros without)."""
    reports = grid.value("hazard") if "hazard" in grid.layers else None
    if reports is None or not np.any(reports > 0):
        return np.zeros(grid.shape)
    near = np.isfinite(reports) & (reports > 0)
    if spread_cells(config.hazard_spread_m, grid.res) >= 1:
        near = np.isfinite(spread_finite(np.where(near, 1.0, np.nan), near, config.hazard_spread_m, grid.res))
    if config.hazard == "forbid":
        impassable |= near
        cost[near] = np.inf
        return np.zeros(grid.shape)
    term = np.where(near & ~impassable, config.hazard_penalty, 0.0)
    cost += term
    return term


def _fill_metrics(
    pool: _Pool | _Inline, raw: dict[str, np.ndarray], known: np.ndarray, config: CostConfig
) -> dict[str, np.ndarray]:
    """The metrics of known cells, eq. 17-filled where the unknown policy needs it (see the module
    docstring); the jobs run on `pool`."""
    infer = config.unknown == "infer"
    sigma = config.infer_sigma_cells
    radius = kernel_radius(sigma)
    jobs: dict[str, Future] = {}
    dens: list[tuple[tuple[slice, slice], np.ndarray, Future]] = []  # one fill weight per mask
    for name, m in raw.items():
        finite = np.isfinite(m)
        finite &= known  # only samples of known cells feed the fill
        box = None
        if finite.any():  # else nothing to fill from
            target = ~finite  # the cells to fill: all but finite ones under infer, else gaps in known
            if not infer:
                target &= known  # (fills of unknown cells would be dropped)
            box = fill_box(target, radius)  # None: all finite where it counts
        if box is None:
            jobs[name] = pool.submit(np.where, known, m, np.nan)
            continue
        mask = finite[box.outer]
        den = next((d for o, mk, d in dens if o == box.outer and np.array_equal(mk, mask)), None)
        if den is None:
            den = pool.submit(smoothed_mask, mask, sigma)
            dens.append((box.outer, mask, den))
        jobs[name] = pool.submit(_filled_metric, m, known, mask, target, box, den, sigma)
    return {name: job.result() for name, job in jobs.items()}


def _filled_metric(
    m: np.ndarray,
    known: np.ndarray,
    mask: np.ndarray,
    target: np.ndarray,
    box: FillBox,
    den: Future,
    sigma: float,
) -> np.ndarray:
    filled = np.where(known, m, np.nan)
    fill_into(filled, mask, target, box, den, sigma)
    return filled


@dataclass(frozen=True)
class _CostArrays:
    """The result arrays `_cost_block` writes into (np.empty: every block writes all its cells)."""

    cost: np.ndarray
    terms: dict[str, np.ndarray]
    impassable: np.ndarray
    write_unknown: bool  # False: terms["unknown"] is np.zeros and stays so


def _cost_block(
    rows: slice,
    metrics: dict[str, np.ndarray],
    count: np.ndarray,
    costed: np.ndarray,
    penalized: np.ndarray,
    out: _CostArrays,
    config: CostConfig,
) -> None:
    """Rows `rows` of every per-cell rule after the fill and the slip spread: limits, terms and cost."""
    m = {name: a[rows] for name, a in metrics.items()}
    costed, penalized = costed[rows], penalized[rows]
    slip_costed = costed | np.isfinite(m["slip_rate"])  # + cells reached only by the spread
    lim = config.limits
    with np.errstate(invalid="ignore"):
        over = (
            (m["slope_deg"] > lim.max_slope_deg)
            | (m["giim"] < lim.min_giim_rad)
            | (m["giam"] < lim.min_giam)
            | (m["slip_rate"] > lim.max_slip_rate)
        )
    w = config.weights
    # its term is 1: the weight on costed (and, under penalty, on the unknown) cells
    out.terms["distance"][rows] = np.where(costed | penalized, w.distance * 1.0, 0.0)
    uncosted, slip_uncosted = ~costed, ~slip_costed
    n = count[rows]
    for name in TERMS:
        if name == "distance":
            continue
        term = _TERM_FUNCS[name](m, n, config, out.terms[name][rows])
        if name == "slip":
            _weight_term(term, w.slip, slip_costed, slip_uncosted)
        else:
            _weight_term(term, getattr(w, name), costed, uncosted)
    if out.write_unknown:
        out.terms["unknown"][rows] = np.where(penalized, config.unknown_penalty, 0.0)
    # metrics are NaN (never over a limit) on uncosted cells, except a spread slip rate there
    impassable = out.impassable[rows]
    np.logical_or(over, uncosted & ~penalized, out=impassable)
    cost = out.cost[rows]
    cost.fill(0.0)
    for t in out.terms.values():
        cost += t[rows]
    cost[impassable] = np.inf
