"""consumer_planner: rover-side queries of the shared map, costed paths and route comparison."""

from __future__ import annotations

from consumer_planner.compare import Breakdown, Route, breakdown, evaluate_route, plan_route
from consumer_planner.costs import CostConfig, CostMap, Limits, Weights, build_costs, parse_weights
from consumer_planner.errors import PlannerError
from psrmap_common.pathsearch import GridPath, plan_path

__all__ = [
    "Breakdown",
    "CostConfig",
    "CostMap",
    "GridPath",
    "Limits",
    "PlannerError",
    "Route",
    "Weights",
    "breakdown",
    "build_costs",
    "evaluate_route",
    "parse_weights",
    "plan_path",
    "plan_route",
]
