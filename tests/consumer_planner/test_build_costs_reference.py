"""build_costs (optimised: shared fill weights, fills cropped to the cells that need them, no
nan_to_num copies, threads on large grids) against a straightforward reference kept here: the
implementation it replaced, one full-grid Gaussian fill per metric, written for clarity.

Random maps with unexplored blobs, scattered unknown cells, per-layer gaps inside known cells
(different masks per layer), layers with and without `n`, a slope layer; every unknown policy, several
fill sigmas, slip spreads and limits that trip. Values must agree to rtol 1e-12 and the masks exactly.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from consumer_planner import costs as costs_mod
from consumer_planner import infer
from consumer_planner.costs import (
    TERMS,
    UNKNOWN_POLICIES,
    CostConfig,
    CostMap,
    Limits,
    Weights,
    build_costs,
)
from psrmap_mapcore import LayerGrid

# --- the reference ------------------------------------------------------------------------------


def ref_smooth(a: np.ndarray, sigma: float) -> np.ndarray:
    from scipy import ndimage

    return ndimage.gaussian_filter(a, sigma=sigma, mode="constant", cval=0.0, truncate=3.0)


def ref_gaussian_fill(values: np.ndarray, sigma: float) -> np.ndarray:
    """Paper eq. 17 over the whole grid: non-finite cells get sum(w v) / sum(w) of the finite cells."""
    mask = np.isfinite(values)
    if mask.all() or not mask.any():
        return values.copy()
    num = ref_smooth(np.where(mask, values, 0.0), sigma)
    den = ref_smooth(mask.astype(np.float64), sigma)
    out = values.copy()
    reach = ~mask & (den > 1e-12)
    out[reach] = num[reach] / den[reach]
    return out


def ref_spread_max(values: np.ndarray, radius_m: float, res: float) -> np.ndarray:
    from scipy import ndimage

    r = int(math.floor(radius_m / res + 1e-9))
    if r < 1:
        return values.copy()
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disc = (xx**2 + yy**2) * res**2 <= radius_m**2 + 1e-9 * res**2
    lifted = np.where(np.isfinite(values), values, -np.inf)
    out = ndimage.maximum_filter(lifted, footprint=disc, mode="constant", cval=-np.inf)
    return np.where(np.isfinite(out), out, np.nan)


def ref_build_costs(grid: LayerGrid, config: CostConfig) -> CostMap:
    raw = {
        "cot": grid.value("cot"),
        "slip_rate": grid.slip_rate(),
        "giim": grid.value("giim"),
        "giam": grid.value("giam"),
        "slope_deg": grid.slope_deg(),
    }
    count = np.zeros(grid.shape)
    for layer in grid.layers:
        count = np.maximum(count, grid.count(layer))
    known = count > 0
    metrics = {}
    for name, m in raw.items():
        filled = ref_gaussian_fill(np.where(known, m, np.nan), config.infer_sigma_cells)
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
    if config.slip_spread_m > 0:
        measured = np.where(known, raw["slip_rate"], np.nan)
        metrics["slip_rate"] = np.fmax(
            metrics["slip_rate"], ref_spread_max(measured, config.slip_spread_m, grid.res)
        )
    slip_costed = costed | np.isfinite(metrics["slip_rate"])
    lim = config.limits
    with np.errstate(invalid="ignore"):
        over = (
            (metrics["slope_deg"] > lim.max_slope_deg)
            | (metrics["giim"] < lim.min_giim_rad)
            | (metrics["giam"] < lim.min_giam)
            | (metrics["slip_rate"] > lim.max_slip_rate)
        )
    c = config
    raw_terms = {
        "distance": np.ones(grid.shape),
        "cot": metrics["cot"],
        "slip": metrics["slip_rate"] * c.stances_per_m,
        "giim": np.maximum(0.0, (c.giim_ref_rad - metrics["giim"]) / c.giim_ref_rad),
        "giam": np.maximum(0.0, (c.giam_ref - metrics["giam"]) / c.giam_ref),
        "slope": metrics["slope_deg"] / c.slope_ref_deg,
        "confidence": c.confidence_n / (c.confidence_n + count),
    }
    terms = {}
    for name in TERMS:
        t = np.nan_to_num(raw_terms[name], nan=0.0)
        terms[name] = np.where(slip_costed if name == "slip" else costed, getattr(c.weights, name) * t, 0.0)
    penalized = ~costed if c.unknown == "penalty" else np.zeros(grid.shape, bool)
    terms["distance"] = np.where(penalized, c.weights.distance, terms["distance"])
    terms["unknown"] = np.where(penalized, c.unknown_penalty, 0.0)
    impassable = over | (~costed & ~penalized)
    cost = np.zeros(grid.shape)
    for t in terms.values():
        cost += t
    cost[impassable] = np.inf
    terms["hazard"] = np.zeros(grid.shape)  # these maps hold no hazard reports
    return CostMap(cost, terms, metrics, known, inferred, impassable, config)


# --- random maps --------------------------------------------------------------------------------


def random_grid(seed: int, shape=(48, 64), *, kind: str = "mixed", res: float = 0.4) -> LayerGrid:
    """kind: "mixed" (blobs + scattered unknown cells + per-layer gaps), "local" (all explored but
    one blob and a few gaps in one corner: the fills are cropped), "inf" (mixed, plus +-inf values
    and an infinite count)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    yy, xx = np.mgrid[:h, :w]
    known = np.ones(shape, bool)
    if kind == "local":
        known &= (yy - 0.8 * h) ** 2 + (xx - 0.75 * w) ** 2 > (0.12 * h) ** 2
    else:
        for _ in range(3):  # unexplored blobs, one large enough that its middle is out of reach
            cy, cx, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(3, 0.3 * h)
            known &= (yy - cy) ** 2 + (xx - cx) ** 2 > r * r
        known &= rng.random(shape) > 0.1
    n_shared = np.where(known, rng.integers(1, 30, shape).astype(float), 0.0)

    def layer(lo: float, hi: float, gap: float, own_n: bool) -> dict[str, np.ndarray]:
        v = lo + (hi - lo) * rng.random(shape)
        gaps = rng.random(shape) < gap
        if kind == "local":
            gaps &= (yy < 0.3 * h) & (xx < 0.3 * w)
        v = np.where(known & ~gaps, v, np.nan)
        n = np.where(known, rng.integers(1, 30, shape).astype(float), np.nan if own_n else 0.0)
        return {"value": v, "n": n if own_n else n_shared}

    layers = {
        "cot": layer(0.8, 1.6, 0.08, own_n=True),  # CoT undefined in some known cells
        "slip": layer(0.0, 0.12, 0.0, own_n=False),
        "giim": layer(0.05, 0.8, 0.03, own_n=False),
        "giam": layer(0.3, 1.2, 0.0, own_n=False),
        "elevation": {
            "slope_deg": np.where(known & (rng.random(shape) > 0.2), rng.uniform(0, 35, shape), np.nan)
        },
        "contacts": {"value": np.where(rng.random(shape) < 0.02, 1.0, np.nan)},  # no n: count = finite value
    }
    if kind == "inf":
        layers["cot"]["value"][rng.random(shape) < 0.01] = np.inf
        layers["giim"]["value"][rng.random(shape) < 0.01] = -np.inf
        layers["slip"]["value"][rng.random(shape) < 0.01] = np.inf
        layers["cot"]["n"][rng.random(shape) < 0.01] = np.inf
    return LayerGrid("rand", res, 0, 0, h, w, layers)


def poisoned_empty(shape, dtype=float) -> np.ndarray:
    """np.empty that hands out NaN (floats) or True (masks) instead of whatever memory held."""
    return np.full(shape, np.nan if np.dtype(dtype).kind == "f" else True, dtype)


def assert_same(got: CostMap, ref: CostMap) -> None:
    for mask in ("known", "inferred", "impassable"):
        np.testing.assert_array_equal(getattr(got, mask), getattr(ref, mask), err_msg=mask)
    np.testing.assert_allclose(got.cost, ref.cost, rtol=1e-12, atol=0, err_msg="cost")
    assert list(got.terms) == list(ref.terms) and list(got.metrics) == list(ref.metrics)
    for name in ref.terms:
        np.testing.assert_allclose(
            got.terms[name], ref.terms[name], rtol=1e-12, atol=0, err_msg=f"term {name}"
        )
    for name in ref.metrics:
        np.testing.assert_allclose(
            got.metrics[name], ref.metrics[name], rtol=1e-12, atol=0, err_msg=f"metric {name}"
        )


CONFIGS = [
    {},
    {"infer_sigma_cells": 1.0, "slip_spread_m": 0.0},
    {"infer_sigma_cells": 3.0, "slip_spread_m": 1.3},
    {"infer_sigma_cells": 0.4, "slip_spread_m": 0.3},  # kernel radius 1; a spread disc of one cell
    {"infer_sigma_cells": 0.0},  # no fill at all
    {
        "limits": Limits(max_slope_deg=20.0, min_giim_rad=0.2, min_giam=0.5, max_slip_rate=0.1),
        "weights": Weights(distance=0.5, cot=2.0, slip=0.0, giim=3.0, giam=1.5, slope=2.5, confidence=0.0),
        "unknown_penalty": 7.0,
    },
]


@pytest.mark.parametrize("unknown", UNKNOWN_POLICIES)
@pytest.mark.parametrize("cfg", range(len(CONFIGS)))
@pytest.mark.parametrize("kind", ["mixed", "local", "inf"])
def test_build_costs_equals_reference(
    unknown: str, cfg: int, kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(costs_mod, "_empty", poisoned_empty)
    config = CostConfig(unknown=unknown, **CONFIGS[cfg])  # type: ignore[arg-type]
    for seed in range(3):
        grid = random_grid(100 * cfg + seed, kind=kind)
        with np.errstate(over="ignore"):  # "inf" maps: the largest float (nan_to_num of inf) summed
            assert_same(build_costs(grid, config), ref_build_costs(grid, config))


@pytest.mark.parametrize("threads", [False, True])
@pytest.mark.parametrize("unknown", UNKNOWN_POLICIES)
def test_blocked_and_threaded_build_equals_reference(
    unknown: str, threads: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The per-cell rules in row blocks of 7 rows (and a last short one), in the calling thread and
    on the thread pool that grids of >= _PARALLEL_MIN_CELLS cells use (forced here on small maps)."""
    monkeypatch.setattr(costs_mod, "_BLOCK_CELLS", 7 * 70)
    monkeypatch.setattr(costs_mod, "_empty", poisoned_empty)  # every cell of every result must be written
    if threads:
        monkeypatch.setattr(costs_mod, "_PARALLEL_MIN_CELLS", 0)
        monkeypatch.setattr(costs_mod.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    config = CostConfig(unknown=unknown)  # type: ignore[arg-type]
    for seed, kind in enumerate(["mixed", "local", "inf"]):
        grid = random_grid(seed, (90, 70), kind=kind, res=0.3)
        assert isinstance(costs_mod._executor(grid.h * grid.w), costs_mod._Pool) == threads
        with np.errstate(over="ignore"):
            assert_same(build_costs(grid, config), ref_build_costs(grid, config))


def test_build_costs_leaves_the_grid_unchanged() -> None:
    grid = random_grid(5, kind="inf")
    before = {k: {s: a.copy() for s, a in st.items()} for k, st in grid.layers.items()}
    with np.errstate(over="ignore"):
        build_costs(grid, CostConfig(unknown="infer"))
    for k, st in before.items():
        for s, a in st.items():
            np.testing.assert_array_equal(grid.layers[k][s], a)


def test_crop_is_exercised() -> None:
    """On a "local" map the fill box is a corner of the grid, widened by the kernel radius."""
    grid = random_grid(1, kind="local")
    known = grid.count("cot") > 0
    target = known & ~np.isfinite(grid.value("cot"))
    box = infer.fill_box(target, infer.kernel_radius(2.0))
    assert box is not None
    (r, c), (orow, ocol) = box.inner, box.outer
    assert r.stop <= 0.3 * grid.h + 1 and c.stop <= 0.3 * grid.w + 1
    assert orow.stop == r.stop + 6 and ocol.stop == c.stop + 6
