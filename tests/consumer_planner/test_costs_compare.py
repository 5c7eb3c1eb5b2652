from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from cp_helpers import make_grid, path_cost, reference_dijkstra

from consumer_planner.compare import cell_weights, evaluate_route, plan_route
from consumer_planner.costs import CostConfig, Limits, Weights, build_costs, parse_weights
from consumer_planner.errors import PlannerError
from protocol.messages import MapRegion
from psrmap_mapcore import MapFileError, read_npz, stitch


def test_cost_is_weighted_sum_of_terms():
    g = make_grid((3, 3), cot=1.2, slip=0.05, giim=0.3, giam=0.45, n=10.0)
    cfg = CostConfig(weights=Weights(distance=1, cot=2, slip=3, giim=4, giam=5, slope=6, confidence=7))
    cm = build_costs(g, cfg)
    expect = 1 + 2 * 1.2 + 3 * 0.05 * cfg.stances_per_m + 4 * 0.5 + 5 * 0.5 + 0 + 7 * 10 / (10 + 10)
    np.testing.assert_allclose(cm.cost, expect)
    np.testing.assert_allclose(sum(cm.terms.values()), cm.cost)


def test_hard_limit_makes_cells_impassable_and_path_avoids_them():
    giim = np.full((5, 7), 0.6)
    giim[0:4, 3] = 0.01  # below min_giim_rad: a wall with a gap in the last row
    g = make_grid((5, 7), giim=giim)
    cm = build_costs(g)
    assert cm.impassable[0:4, 3].all() and not cm.impassable[4, 3]
    route = plan_route(g, cm, (0.1, 0.1), (3.4, 0.1))
    assert route is not None
    assert not cm.impassable[route.cells[:, 0], route.cells[:, 1]].any()
    assert (route.cells[:, 0] == 4).any()
    relaxed = build_costs(g, CostConfig(limits=Limits(min_giim_rad=0.0)))
    assert not relaxed.impassable.any()


def _half_known():
    known = np.ones((6, 8), bool)
    known[:, 3:5] = False  # an unexplored band between the two halves
    return make_grid((6, 8), known=known, cot=1.0)


def test_unknown_forbid_blocks_penalty_costs_infer_fills():
    g = _half_known()
    forbid = build_costs(g, CostConfig(unknown="forbid"))
    assert forbid.impassable[:, 3:5].all()
    assert plan_route(g, forbid, (0.1, 0.1), (3.9, 0.1)) is None

    cfg = CostConfig(unknown="penalty", unknown_penalty=2.5)
    pen = build_costs(g, cfg)
    np.testing.assert_allclose(pen.cost[:, 3:5], cfg.weights.distance + 2.5)
    r = plan_route(g, pen, (0.1, 0.1), (3.9, 0.1))
    assert r is not None and r.breakdown.unknown_fraction > 0 and r.breakdown.inferred_fraction == 0
    assert r.breakdown.terms["unknown"] > 0

    inf = build_costs(g, CostConfig(unknown="infer"))
    assert inf.inferred[:, 3:5].all() and not inf.inferred[:, :3].any()
    np.testing.assert_allclose(inf.metrics["cot"][:, 3:5], 1.0)  # fill of a uniform neighbourhood
    r = plan_route(g, inf, (0.1, 0.1), (3.9, 0.1))
    assert r is not None and r.breakdown.inferred_fraction > 0
    assert r.breakdown.inferred_fraction == r.breakdown.unknown_fraction


def test_infer_is_gaussian_weighted_and_leaves_far_cells_unknown():
    known = np.zeros((1, 30), bool)
    known[0, :2] = True
    cot = np.zeros((1, 30))
    cot[0, 0], cot[0, 1] = 1.0, 2.0
    g = make_grid((1, 30), known=known, cot=cot)
    cm = build_costs(g, CostConfig(unknown="infer", infer_sigma_cells=1.0))
    w0, w1 = math.exp(-(2**2) / 2), math.exp(-(1**2) / 2)  # distances 2 and 1 cells from cell 2
    assert cm.metrics["cot"][0, 2] == pytest.approx((w0 * 1 + w1 * 2) / (w0 + w1), rel=1e-3)
    assert cm.impassable[0, 10:].all() and not cm.inferred[0, 10:].any()


def test_breakdown_equals_independent_sums_along_path():
    rng = np.random.default_rng(3)
    shape = (9, 11)
    g = make_grid(shape, cot=rng.uniform(0.8, 2, shape), slip=rng.uniform(0, 0.1, shape),
                  giim=rng.uniform(0.2, 0.8, shape), giam=rng.uniform(0.3, 1.2, shape))  # fmt: skip
    cm = build_costs(g, CostConfig(slip_spread_m=0.0))  # the raw slip layer (spread: test_slip_spread.py)
    r = plan_route(g, cm, (0.2, 0.2), (5.3, 4.3))
    assert r is not None
    res, cells = g.res, [tuple(c) for c in r.cells]
    ref, _ = reference_dijkstra(cm.cost, cells[0], cells[-1], res)
    b = r.breakdown
    assert b.cost == pytest.approx(ref, rel=1e-9)
    assert b.cost == pytest.approx(path_cost(cm.cost, r.cells, res), rel=1e-9)
    assert sum(b.terms.values()) == pytest.approx(b.cost, rel=1e-9)
    # one cell at a time: weight = half of each adjacent step
    steps = [res * math.hypot(a[0] - c[0], a[1] - c[1]) for a, c in zip(cells[:-1], cells[1:], strict=True)]
    w = [0.0] * len(cells)
    for i, s in enumerate(steps):
        w[i] += s / 2
        w[i + 1] += s / 2
    assert b.length_m == pytest.approx(sum(steps))
    cot = [g.layers["cot"]["value"][c] for c in cells]
    slip = [g.layers["slip"]["value"][c] for c in cells]
    giim = [g.layers["giim"]["value"][c] for c in cells]
    assert b.mean_cot == pytest.approx(sum(wi * x for wi, x in zip(w, cot, strict=True)) / sum(w))
    assert b.expected_slip_events == pytest.approx(
        cm.config.stances_per_m * sum(wi * x for wi, x in zip(w, slip, strict=True))
    )
    assert b.min_giim == pytest.approx(min(giim))
    assert b.mean_giim == pytest.approx(sum(wi * x for wi, x in zip(w, giim, strict=True)) / sum(w))
    assert b.unknown_fraction == 0 and b.impassable_cells == 0
    np.testing.assert_allclose(cell_weights(r.cells, res), w)


def test_evaluate_route_through_waypoints_and_errors():
    g = make_grid((10, 10), res=1.0)
    cm = build_costs(g)
    r = evaluate_route(g, cm, [(0.5, 0.5), (5.5, 0.5), (5.5, 5.5)])
    assert r.breakdown.length_m == pytest.approx(10.0)
    assert r.path[0].tolist() == [0.5, 0.5] and r.path[-1].tolist() == [5.5, 5.5]
    assert r.breakdown.cost == pytest.approx(path_cost(cm.cost, r.cells, 1.0))
    with pytest.raises(PlannerError, match=r"outside the map box x 0..10, y 0..10 m"):
        evaluate_route(g, cm, [(0.5, 0.5), (50, 0.5)])
    blocked = build_costs(g, replace(cm.config, unknown="forbid"))
    assert blocked.cost[0, 0] == cm.cost[0, 0]
    d = r.as_dict()
    assert set(d) >= {"path", "length_m", "cost", "breakdown"}


def test_parse_weights_names_valid_terms():
    assert parse_weights("cot=2, slip=0.5").cot == 2.0
    with pytest.raises(PlannerError, match="distance, cot, slip, giim, giam, slope, confidence"):
        parse_weights("cots=1")
    with pytest.raises(PlannerError, match="policies: forbid, penalty, infer"):
        CostConfig(unknown="guess")  # type: ignore[arg-type]


def test_stitch_two_shards_and_npz_roundtrip(tmp_path):
    def region(ix0, n, val):
        layers = {"cot": {"n": np.array([[n, n]], float), "value": np.array([[val, val]])}}
        return MapRegion("m", 0.5, ix0, 0, 2, 1, 3, layers)

    g = stitch([region(0, 5, 1.0), region(4, 7, 2.0), region(1, 0, np.nan)])
    assert (g.ix0, g.w, g.h) == (0, 6, 1)
    np.testing.assert_array_equal(g.layers["cot"]["n"], [[5, 5, 0, 0, 7, 7]])
    np.testing.assert_array_equal(g.layers["cot"]["value"], [[1, 1, np.nan, np.nan, 2, 2]])
    np.savez(
        tmp_path / "m.npz",
        res=0.5,
        ix0=0,
        iy0=0,
        **{"cot/n": g.layers["cot"]["n"], "cot/value": g.layers["cot"]["value"]},
    )
    back = read_npz(tmp_path / "m.npz")
    np.testing.assert_array_equal(back.layers["cot"]["n"], g.layers["cot"]["n"])
    assert back.cell_of(2.9, 0.1) == (0, 5) and back.cell_of(3.1, 0.1) is None
    with pytest.raises(MapFileError, match="no map file"):
        read_npz(tmp_path / "nope.npz")


def test_slope_term_and_limit_from_elevation_plane_fit():
    import consumer_planner

    # footholds on a plane tilted 20 deg along x in every cell, x, y relative to the cell centre
    h, w = 3, 4
    xs = np.array([-0.1, 0.1, -0.1, 0.1, 0.0])
    ys = np.array([-0.1, -0.1, 0.1, 0.1, 0.0])
    zs = np.tan(np.radians(20.0)) * xs + 0.3
    sums = {"n": len(xs), "sum": zs.sum(), "sumsq": (zs**2).sum(), "sx": xs.sum(), "sy": ys.sum(),
            "sxx": (xs**2).sum(), "syy": (ys**2).sum(), "sxy": (xs * ys).sum(), "sxz": (xs * zs).sum(),
            "syz": (ys * zs).sum(), "min": zs.min(), "max": zs.max()}  # fmt: skip
    g = make_grid((h, w))
    g.layers["elevation"] = {k: np.full((h, w), float(v)) for k, v in sums.items()}
    cm = build_costs(g, CostConfig(weights=Weights(cot=0, slip=0, giim=0, giam=0, confidence=0, slope=3)))
    np.testing.assert_allclose(cm.metrics["slope_deg"], 20.0)
    np.testing.assert_allclose(cm.cost, 1 + 3 * 20 / 30)
    steep = build_costs(g, CostConfig(limits=Limits(max_slope_deg=15.0)))
    assert steep.impassable.all()
    assert sorted(consumer_planner.__all__) == consumer_planner.__all__
    assert all(hasattr(consumer_planner, name) for name in consumer_planner.__all__)


def _with_hazard(g, cells):
    """The grid `g` with one hazard report in each (row, col) of `cells` (raw stats, as a server replies)."""
    n = np.zeros(g.shape)
    for r, c in cells:
        n[r, c] = 1.0
    stats = {"n": n, "slip": n.copy(), "margin": np.zeros(g.shape), "contact": np.zeros(g.shape),
             "attitude": np.zeros(g.shape)}  # fmt: skip
    return replace(g, layers={**g.layers, "hazard": stats})


def test_a_hazard_report_forbids_its_neighbourhood_or_costs_a_penalty():
    g = _with_hazard(make_grid((9, 9), res=0.4), [(4, 4)])
    straight = plan_route(
        make_grid((9, 9), res=0.4), build_costs(make_grid((9, 9), res=0.4)), (0.2, 1.8), (3.4, 1.8)
    )
    assert straight is not None and (straight.cells[:, 0] == 4).all()  # without the report: straight through
    cm = build_costs(g)  # default: forbid, within 0.8 m
    rr, cc = np.mgrid[0:9, 0:9]
    near = (rr - 4) ** 2 + (cc - 4) ** 2 <= 4
    assert cm.impassable[near].all() and not cm.impassable[~near].any()
    route = plan_route(g, cm, (0.2, 1.8), (3.4, 1.8))
    assert route is not None and not near[route.cells[:, 0], route.cells[:, 1]].any()
    pen = build_costs(g, CostConfig(hazard="penalty", hazard_penalty=7.0, hazard_spread_m=0.0))
    assert not pen.impassable.any() and pen.terms["hazard"][4, 4] == 7.0 and pen.terms["hazard"].sum() == 7.0
    np.testing.assert_allclose(sum(pen.terms.values()), pen.cost)
    with pytest.raises(PlannerError, match="policies: forbid, penalty"):
        CostConfig(hazard="avoid")  # type: ignore[arg-type]
