"""Slip spreading (`CostConfig.slip_spread_m`): known answers on constructed maps.

A scout's slip layer marks only the cells its feet slipped in. Read raw, the cheapest path passes one
cell beside such a strip; with the slip rate spread over >= 2 cells it goes around the whole dilated
region. The dilated rate array is checked against a brute-force loop, and the unknown policies and the
breakdown against independent sums.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from cp_helpers import make_grid, path_cost, reference_dijkstra

from consumer_planner.compare import cell_weights, evaluate_route, plan_route
from consumer_planner.costs import CostConfig, Limits, build_costs, spread_max
from consumer_planner.errors import PlannerError

RATE = 0.1  # slip events per stance on the strip: 2.8 expected slips per metre


def brute_spread(values: np.ndarray, radius_m: float, res: float) -> np.ndarray:
    """Largest finite value whose cell centre is within radius_m of each cell centre; NaN if none."""
    h, w = values.shape
    out = np.full((h, w), np.nan)
    for r in range(h):
        for c in range(w):
            best = -math.inf
            for rr in range(h):
                for cc in range(w):
                    v = values[rr, cc]
                    if math.isfinite(v) and math.hypot(rr - r, cc - c) * res <= radius_m + 1e-9:
                        best = max(best, v)
            if best > -math.inf:
                out[r, c] = best
    return out


@pytest.mark.parametrize(("radius_m", "res"), [(0.8, 0.4), (0.8, 0.5), (1.0, 0.5), (1.3, 0.4), (0.3, 0.4)])
def test_spread_max_equals_brute_force_loop(radius_m: float, res: float) -> None:
    rng = np.random.default_rng(7)
    values = rng.uniform(0, 1, (9, 12))
    values[rng.uniform(size=values.shape) < 0.6] = np.nan  # sparse, with whole empty neighbourhoods
    values[:, 9:] = np.nan
    got = spread_max(values, radius_m, res)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(brute_spread(values, radius_m, res)))
    np.testing.assert_allclose(got, brute_spread(values, radius_m, res))


def _strip_grid() -> tuple[object, tuple[int, int], tuple[int, int], np.ndarray]:
    """21 x 25 cells of 1 m, all mapped; slips in one row-10 strip (cols 6..18) on the start-goal line."""
    slip = np.zeros((21, 25))
    slip[10, 6:19] = RATE
    return make_grid((21, 25), res=1.0, slip=slip), (10, 1), (10, 23), slip > 0


def _dist_to(mask: np.ndarray, cells: np.ndarray) -> np.ndarray:
    pts = np.argwhere(mask)
    return np.array([np.min(np.hypot(*(pts - c).T)) for c in cells])


def test_without_spread_the_path_passes_one_cell_beside_the_strip() -> None:
    g, s, t, strip = _strip_grid()
    cm = build_costs(g, CostConfig(slip_spread_m=0.0))
    route = plan_route(g, cm, (s[1] + 0.5, s[0] + 0.5), (t[1] + 0.5, t[0] + 0.5))
    assert route is not None
    ref, _ = reference_dijkstra(cm.cost, s, t, 1.0)
    assert route.breakdown.cost == pytest.approx(ref, rel=1e-9)
    d = _dist_to(strip, route.cells)
    assert d.min() == 1.0  # never on a slip cell, but right beside it
    assert route.breakdown.expected_slip_events == 0.0
    # the same path on the spread map crosses the dilated region: the raw layer hid the patch
    spread = build_costs(g, CostConfig(slip_spread_m=2.0))
    assert evaluate_route(g, spread, route.path).breakdown.expected_slip_events > 5


@pytest.mark.parametrize("radius_m", [2.0, 2.5, 3.0])
def test_with_spread_the_path_goes_around_the_whole_dilated_region(radius_m: float) -> None:
    g, s, t, strip = _strip_grid()
    cm = build_costs(g, CostConfig(slip_spread_m=radius_m))
    dilated = cm.metrics["slip_rate"] > 0
    np.testing.assert_array_equal(dilated, brute_spread(np.where(strip, RATE, 0.0), radius_m, 1.0) > 0)
    assert dilated.sum() > strip.sum()
    route = plan_route(g, cm, (s[1] + 0.5, s[0] + 0.5), (t[1] + 0.5, t[0] + 0.5))
    assert route is not None
    ref, _ = reference_dijkstra(cm.cost, s, t, 1.0)
    assert route.breakdown.cost == pytest.approx(ref, rel=1e-9)
    assert route.breakdown.cost == pytest.approx(path_cost(cm.cost, route.cells, 1.0), rel=1e-9)
    assert not dilated[route.cells[:, 0], route.cells[:, 1]].any()
    assert (_dist_to(strip, route.cells) > radius_m).all()
    assert route.breakdown.expected_slip_events == 0.0


def test_spread_only_cells_keep_the_unknown_policy_for_everything_but_slip() -> None:
    known = np.ones((5, 9), bool)
    known[:, 5:] = False  # unmapped to the east of column 4
    slip = np.zeros((5, 9))
    slip[2, 4] = RATE  # a slip cell on the edge of the mapped ground
    g = make_grid((5, 9), res=0.4, known=known, slip=slip)
    cfg = CostConfig(unknown="penalty", unknown_penalty=2.5, slip_spread_m=0.8)  # 2 cells
    cm = build_costs(g, cfg)
    reach = brute_spread(np.where(known, slip, np.nan), 0.8, 0.4)
    np.testing.assert_allclose(cm.metrics["slip_rate"], reach)  # NaN beyond 2 cells of mapped ground
    only_spread = ~known & np.isfinite(reach)
    assert only_spread[:, 5:7].all() and not only_spread[:, 7:].any()
    # unknown for every other purpose: penalty kept, no other term, not inferred
    assert not cm.known[only_spread].any() and not cm.inferred.any()
    expect = 1.0 + 2.5 + cfg.weights.slip * cfg.stances_per_m * np.nan_to_num(reach)
    np.testing.assert_allclose(cm.cost[:, 5:], expect[:, 5:])
    assert cm.cost[2, 5] == pytest.approx(
        1 + 2.5 + cfg.weights.slip * cfg.stances_per_m * RATE
    )  # dearer than unknown
    for name in ("cot", "giim", "giam", "slope", "confidence"):
        assert not cm.terms[name][~known].any(), name
    np.testing.assert_allclose(sum(cm.terms.values()), cm.cost)

    forbid = build_costs(g, CostConfig(unknown="forbid", slip_spread_m=0.8))
    assert forbid.impassable[:, 5:].all() and not forbid.impassable[:, :5].any()

    inf = build_costs(g, CostConfig(unknown="infer", slip_spread_m=0.8))
    plain = build_costs(g, CostConfig(unknown="infer", slip_spread_m=0.0))
    np.testing.assert_array_equal(inf.inferred, plain.inferred)  # the spread infers nothing
    np.testing.assert_allclose(
        inf.metrics["slip_rate"], np.fmax(plain.metrics["slip_rate"], reach), equal_nan=True
    )

    # a slip-rate limit reads the spread rate, on mapped and spread-only cells alike
    lim = build_costs(g, CostConfig(unknown="penalty", slip_spread_m=0.8, limits=Limits(max_slip_rate=0.05)))
    np.testing.assert_array_equal(lim.impassable, np.nan_to_num(reach) > 0.05)


def test_breakdown_reads_the_spread_rate_the_cost_charges() -> None:
    rng = np.random.default_rng(11)
    shape = (9, 11)
    known = rng.uniform(size=shape) > 0.2
    slip = np.where(rng.uniform(size=shape) > 0.8, rng.uniform(0, 0.1, shape), 0.0)
    g = make_grid(shape, res=0.4, known=known, slip=slip, cot=rng.uniform(0.8, 2, shape))
    cm = build_costs(g, CostConfig(slip_spread_m=0.8))
    route = plan_route(g, cm, (0.2, 0.2), (4.1, 3.3))
    assert route is not None
    cells = [tuple(c) for c in route.cells]
    w = cell_weights(route.cells, 0.4)
    rate = np.nan_to_num(brute_spread(np.where(known, slip, np.nan), 0.8, 0.4))
    expect = cm.config.stances_per_m * sum(wi * rate[c] for wi, c in zip(w, cells, strict=True))
    b = route.breakdown
    assert b.expected_slip_events == pytest.approx(expect, rel=1e-12)
    assert b.terms["slip"] == pytest.approx(cm.config.weights.slip * b.expected_slip_events, rel=1e-12)
    assert sum(b.terms.values()) == pytest.approx(b.cost, rel=1e-12)
    unknown = sum(wi for wi, c in zip(w, cells, strict=True) if not known[c]) / b.length_m
    assert b.unknown_fraction == pytest.approx(unknown)


@pytest.mark.parametrize("bad", [-0.1, math.inf, math.nan])
def test_config_rejects_bad_spread(bad: float) -> None:
    with pytest.raises(PlannerError, match=r"finite radius >= 0 m \(0 = off\)"):
        CostConfig(slip_spread_m=bad)


def test_zero_spread_is_the_raw_layer() -> None:
    g, *_ = _strip_grid()
    cm = build_costs(g, CostConfig(slip_spread_m=0.0))
    np.testing.assert_array_equal(cm.metrics["slip_rate"], g.slip_rate())
