"""psrmap_common.pathsearch: optimal path search on 8-connected cost grids, shared by the scout (its detours around
hazards) and the planner (routes for rovers). Services never import each other; both import this.

- `search.plan_path`, `nearest_passable`, `step_lengths`, `GridPath`: the search and its path definition.
- `kernels`: the compiled (numba) Dijkstra / A* kernels.
- `errors.PathSearchError`: bad input, named.

It imports numpy, numba (and scikit-image for the reference method), nothing of the services.
"""

from __future__ import annotations

from psrmap_common.pathsearch.errors import PathSearchError
from psrmap_common.pathsearch.search import (
    METHODS,
    GridPath,
    Method,
    nearest_passable,
    plan_path,
    step_lengths,
)

__all__ = [
    "METHODS",
    "GridPath",
    "Method",
    "PathSearchError",
    "nearest_passable",
    "plan_path",
    "step_lengths",
]
