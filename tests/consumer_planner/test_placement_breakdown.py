"""The route breakdown shows how well a route's cells are placed (the placement layer, issue 23)."""

from __future__ import annotations

import numpy as np
import pytest
from cp_helpers import make_grid

from consumer_planner.compare import evaluate_route
from consumer_planner.costs import build_costs


def test_the_planners_breakdown_shows_how_well_a_route_is_placed() -> None:
    g = make_grid((4, 10), res=1.0)
    sig = np.where(np.arange(10)[None, :] < 5, 0.1, 0.7) * np.ones((4, 1))
    g.layers["placement"] = {"n": np.full((4, 10), 5.0), "var": 5 * sig**2, "max": sig}
    r = evaluate_route(g, build_costs(g), [(0.5, 0.5), (9.5, 0.5)])
    b = r.as_dict()["breakdown"]
    assert b["max_placement_sigma_m"] == pytest.approx(0.7)
    assert 0.1 < b["mean_placement_sigma_m"] < 0.7
    del g.layers["placement"]
    assert (
        evaluate_route(g, build_costs(g), [(0.5, 0.5), (9.5, 0.5)]).as_dict()["breakdown"][
            "max_placement_sigma_m"
        ]
        is None
    )  # a map without the layer: unknown, not zero


def test_the_planners_breakdown_shows_how_well_a_routes_heights_are_known() -> None:
    g = make_grid((4, 10), res=1.0)
    sig = np.where(np.arange(10)[None, :] < 5, 0.05, 0.4) * np.ones((4, 1))
    n = np.full((4, 10), 3.0)
    zero = np.zeros((4, 10))
    g.layers["height"] = {"n": n, "w": n / sig**2, "wz": zero, "wx": zero, "wy": zero, "wxx": zero,
                          "wyy": zero, "wxy": zero, "wxz": zero, "wyz": zero, "var": n * sig**2,
                          "min_sigma": sig}  # fmt: skip
    b = evaluate_route(g, build_costs(g), [(0.5, 0.5), (9.5, 0.5)]).as_dict()["breakdown"]
    assert b["max_height_sigma_m"] == pytest.approx(0.4)
    assert 0.05 < b["mean_height_sigma_m"] < 0.4
    del g.layers["height"]
    b = evaluate_route(g, build_costs(g), [(0.5, 0.5), (9.5, 0.5)]).as_dict()["breakdown"]
    assert b["max_height_sigma_m"] is None and b["mean_height_sigma_m"] is None  # unknown, not zero
