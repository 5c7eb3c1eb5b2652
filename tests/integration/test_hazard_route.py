"""A scout's hazard reflex, published in its `hazard` layer, makes the planner route around that ground."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from consumer_planner.component import MapSource, PlanConfig, plan
from consumer_planner.costs import CostConfig
from scout_agent import component as scout
from scout_agent.component import ScoutConfig
from scout_agent.mapping import LinkConfig
from scout_agent.run import ScoutRunConfig
from scout_agent.sim.terrain import RampConfig


def test_one_scouts_hazard_makes_the_planner_route_around_the_cell(served_map, router):
    with served_map("hz", 0.4) as (service, _client):
        # μ 0.26 on a 20° down-ramp: ground no robot holds; the scout stops, backs off and reports it
        ramp = RampConfig(approach_m=1.0, up_m=1.5, platform_m=0.8, down_m=2.5, exit_m=1.5)
        run = ScoutRunConfig(scene="ramps", slope_deg=20.0, ramp=ramp, slippery_mu=0.26, sim_seconds=30.0,
                             scout_id="s1")  # fmt: skip
        s = scout.run(ScoutConfig(run=run, link=LinkConfig("hz", (router,), outbox="none"), progress=False))
        assert not s.fell and s.report["hazard_stops"] and s.all_acked
        assert s.report["map"]["hazard_reports"] == len(s.report["hazard_stops"])
        stop = s.report["hazard_stops"][0]
        hx, hy = (
            (np.floor(np.array([stop["x"], stop["y"]]) / 0.4) + 0.5) * 0.4
        ).tolist()  # its cell's centre

        src = MapSource(map_id="hz", connect=(router,), margin_m=4.0)
        a, b = (2.8, 0.0), (5.2, 0.0)  # across the hazard, along the scout's own track

        def min_dist(summary) -> float:
            path = np.asarray(summary.routes[0].path)
            return float(np.min(np.hypot(path[:, 0] - hx, path[:, 1] - hy)))

        # the slip layer alone also steers routes off slippery ground: leave it out to see the hazard's effect
        no_slip = CostConfig(weights=replace(CostConfig().weights, slip=0.0), slip_spread_m=0.0)
        blind = plan(PlanConfig(src, a, b, replace(no_slip, hazard="penalty", hazard_penalty=0.0)))
        assert min_dist(blind) <= 0.8  # ignoring the layer, the cheapest route crosses the hazard's zone
        seen = plan(PlanConfig(src, a, b, no_slip))  # default: cells within 0.8 m of a report are impassable
        assert min_dist(seen) > 0.8  # (cell centre to cell centre, as the cost rule measures)
        assert seen.routes[0].breakdown.length_m > blind.routes[0].breakdown.length_m
