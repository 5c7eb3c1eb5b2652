"""The planner reads the map's slope (`map_slope_deg`); a cell whose footholds' datums clash has an unknown slope
(filled from its neighbours), while a steep slope under one datum stays impassable; an impassable start says
why and where a valid one is."""

from __future__ import annotations

import re

import numpy as np
import pytest

from consumer_planner.compare import plan_route
from consumer_planner.costs import CostConfig, build_costs
from consumer_planner.errors import PlannerError
from protocol.layers import LAYERS
from psrmap_mapcore import LayerGrid
from scout_agent.holding import elevation_rows, height_rows
from tests.consumer_planner.cp_helpers import make_grid

RES = 0.4
SHAPE = (5, 5)


def footholds(ix: int, iy: int, along: str, z0: float, slope_deg: float, rng: np.random.Generator):
    """12 footholds on a track across cell (ix, iy) on the plane z = slope · x + z0 (5 mm foot noise)."""
    u = (np.linspace(0.03, 0.37, 12) + (ix if along == "x" else iy) * RES).astype(float)
    v = (
        np.clip((0.1 if along == "x" else 0.3) + rng.normal(0.0, 0.04, 12), 0.02, 0.38)
        + (iy if along == "x" else ix) * RES
    )
    x, y = (u, v) if along == "x" else (v, u)
    return x, y, np.tan(np.radians(slope_deg)) * x + z0 + rng.normal(0.0, 0.005, 12)


def terrain_grid(
    special: dict[tuple[int, int], list[tuple[str, float, float, float]]], height: bool = True
) -> LayerGrid:
    """A 5 × 5 map of flat ground walked by two crossing tracks per cell (σ 0.15 m), except `special` cells
    {(row, col): [(along, z0, slope_deg, σ), ...]}; uniform cot/slip/margins from `make_grid`."""
    rng = np.random.default_rng(8)
    xs, ys, zs, ss = [], [], [], []
    for row in range(SHAPE[0]):
        for col in range(SHAPE[1]):
            for along, z0, slope, sigma in special.get(
                (row, col), [("x", 0.0, 0.0, 0.15), ("y", 0.0, 0.0, 0.15)]
            ):
                x, y, z = footholds(col, row, along, z0, slope, rng)
                xs.append(x), ys.append(y), zs.append(z), ss.append(np.full(len(x), sigma))
    x, y, z, s = (np.concatenate(a) for a in (xs, ys, zs, ss))
    grid = make_grid(SHAPE, RES)
    layers = dict(grid.layers)
    todo = [("elevation", elevation_rows(x, y, z, RES))] + (
        [("height", height_rows(x, y, z, s, RES))] if height else []
    )
    for name, rows in todo:
        r, c = np.floor(rows[:, 1] / RES).astype(int), np.floor(rows[:, 0] / RES).astype(int)
        stats = {}
        for i, st in enumerate(LAYERS[name].stats):
            op = np.minimum if st in ("min", "min_sigma") else np.maximum if st == "max" else np.add
            a = np.full(SHAPE, np.inf if op is np.minimum else -np.inf if op is np.maximum else 0.0)
            op.at(a, (r, c), rows[:, 2 + i])
            stats[st] = a
        layers[name] = stats
    return LayerGrid("test", RES, 0, 0, SHAPE[0], SHAPE[1], layers)


CLASH = [
    ("x", 0.0, 0.0, 0.16),
    ("y", 1.2, 0.0, 0.24),
]  # two scouts 1.2 m apart in height, as at the 100 m start
STEEP = [("x", 0.0, 35.0, 0.1), ("y", 0.0, 35.0, 0.1)]  # one datum, a real 35° slope


def test_a_datum_clash_is_costed_as_unknown_slope_not_impassable() -> None:
    grid = terrain_grid({(2, 2): CLASH})
    assert grid.slope_deg()[2, 2] > 30.0  # the map's fit still bridges the datums...
    costs = build_costs(grid, CostConfig())
    assert costs.datum_clash is not None and costs.datum_clash[2, 2] and costs.datum_clash.sum() == 1
    assert not costs.impassable[2, 2]  # ...but the planner does not take it for terrain
    assert costs.metrics["slope_deg"][2, 2] == pytest.approx(0.0, abs=1.0)  # filled from the flat neighbours
    assert costs.cost[2, 2] == pytest.approx(costs.cost[2, 1], rel=0.05)
    route = plan_route(grid, costs, (1.0, 1.0), (1.9, 1.9))  # start on the clash cell plans
    assert route is not None


def test_without_the_height_layer_the_same_cell_is_impassable_as_before() -> None:
    costs = build_costs(terrain_grid({(2, 2): CLASH}, height=False), CostConfig())
    assert costs.impassable[2, 2] and not costs.datum_clash.any()  # type: ignore[union-attr]


def test_a_steep_slope_under_one_datum_stays_impassable_and_the_start_error_says_why() -> None:
    grid = terrain_grid({(2, 2): STEEP})
    costs = build_costs(grid, CostConfig())
    assert costs.impassable[2, 2] and not costs.datum_clash[2, 2]  # type: ignore[index]
    assert costs.metrics["slope_deg"][2, 2] == pytest.approx(35.0, abs=1.0)
    with pytest.raises(PlannerError) as err:
        plan_route(grid, costs, (1.0, 1.0), (1.9, 1.9))
    msg = str(err.value)
    assert re.search(
        r"start \(1, 1\) m, cell \(row 2, col 2\), is impassable: slope \(3[45]\.\d > limit 30\)", msg
    )
    assert "nearest passable cell: (1.00, 0.60) m, 0.40 m away" in msg
