from __future__ import annotations

import numpy as np
import pytest
from cp_helpers import path_cost, reference_dijkstra
from hypothesis import given, settings
from hypothesis import strategies as st

from psrmap_common.pathsearch import PathSearchError
from psrmap_common.pathsearch.search import plan_path


def _random_costs(seed, h, w, blocked, low=0.5):
    rng = np.random.default_rng(seed)
    cost = rng.uniform(low, 5.0, (h, w))
    cost[rng.random((h, w)) < blocked] = np.inf
    return cost


@pytest.mark.parametrize("method", ["compiled", "skimage"])
@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    h=st.integers(1, 12),
    w=st.integers(1, 12),
    blocked=st.sampled_from([0, 0.2, 0.4]),
)
def test_optimal_against_reference_dijkstra(method, seed, h, w, blocked):
    cost = _random_costs(seed, h, w, blocked)
    start, goal = (0, 0), (h - 1, w - 1)
    cost[start] = cost[goal] = 1.0
    res = 0.4
    ref, _ = reference_dijkstra(cost, start, goal, res)
    got = plan_path(cost, start, goal, res, method)
    if ref is None:
        assert got is None
        return
    assert got is not None
    assert got.cost == pytest.approx(ref, rel=1e-9)
    cells = [tuple(c) for c in got.cells]
    assert cells[0] == start and cells[-1] == goal
    assert path_cost(cost, got.cells, res) == pytest.approx(ref, rel=1e-9)
    assert all(np.isfinite(cost[c]) for c in cells), "path crosses an impassable cell"


def test_goes_around_a_wall():
    cost = np.ones((7, 7))
    cost[:6, 3] = np.inf  # wall with a gap at the bottom row
    got = plan_path(cost, (0, 0), (0, 6), 1.0)
    assert got is not None
    assert (got.cells[:, 0] == 6).any()
    assert all(np.isfinite(cost[tuple(c)]) for c in got.cells)


def test_unreachable_goal_is_none_and_bad_endpoints_raise():
    cost = np.ones((5, 5))
    cost[:, 2] = np.inf
    assert plan_path(cost, (0, 0), (4, 4), 1.0) is None
    with pytest.raises(PathSearchError, match="impassable"):
        plan_path(cost, (0, 2), (4, 4), 1.0)
    with pytest.raises(PathSearchError, match="outside the grid of 5 x 5"):
        plan_path(cost, (0, 0), (9, 4), 1.0)
    with pytest.raises(PathSearchError, match="methods: auto, compiled, skimage"):
        plan_path(cost, (0, 0), (0, 1), 1.0, "dijkstra")  # type: ignore[arg-type]


def test_start_equals_goal():
    got = plan_path(np.ones((3, 3)), (1, 1), (1, 1), 1.0)
    assert got is not None and got.cost == 0.0 and got.cells.tolist() == [[1, 1]]


def test_uniform_grid_known_answer():
    # 3 diagonal steps then 2 straight steps on unit cost: 3*sqrt(2) + 2 [m]
    got = plan_path(np.ones((4, 6)), (0, 0), (3, 5), 1.0)
    assert got is not None and got.cost == pytest.approx(3 * np.sqrt(2) + 2)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 12))
def test_free_cells_use_the_heap_search_and_stay_optimal(seed, n):
    # cells of cost 0 make the bucket queue impossible (zero-width buckets): the A* heap path runs
    cost = _random_costs(seed, n, n, 0.2, low=0.0)
    cost[np.random.default_rng(seed).random((n, n)) < 0.3] = 0.0
    start, goal = (0, 0), (n - 1, n - 1)
    cost[start] = cost[goal] = 0.0
    ref, _ = reference_dijkstra(cost, start, goal, 1.0)
    got = plan_path(cost, start, goal, 1.0, "compiled")
    assert (got is None) == (ref is None)
    if got is not None:
        assert got.cost == pytest.approx(ref, rel=1e-9, abs=1e-12)
        assert path_cost(cost, got.cells, 1.0) == pytest.approx(ref, rel=1e-9, abs=1e-12)


def test_wide_cost_range_matches_reference():
    rng = np.random.default_rng(7)
    cost = np.exp(rng.uniform(0, 8, (15, 15)))  # ratio ~3000: many buckets, still exact
    ref, _ = reference_dijkstra(cost, (0, 0), (14, 14), 0.3)
    got = plan_path(cost, (0, 0), (14, 14), 0.3)
    assert got is not None and got.cost == pytest.approx(ref, rel=1e-9)


def test_a_goal_on_an_impassable_cell_moves_to_the_nearest_passable_one_within_tolerance():
    from psrmap_common.pathsearch.search import nearest_passable

    cost = np.ones((9, 9))
    cost[3:6, 3:6] = np.inf  # a robot fell here: the map forbids these cells
    assert nearest_passable(cost, (4, 4), 1.0) is None  # nothing passable within one cell
    r, c = nearest_passable(cost, (4, 4), 2.0)
    assert np.isfinite(cost[r, c]) and (r - 4) ** 2 + (c - 4) ** 2 == 4
    assert nearest_passable(cost, (0, 0), 3.0) == (0, 0)  # a passable goal stays put


@pytest.mark.parametrize(
    ("res", "why"),
    [(0.0, "> 0"), (-1.0, "> 0"), (float("nan"), "finite"), (float("inf"), "finite"), ("a", "number")],
)
def test_bad_cell_size_is_a_planner_error_not_a_crash(res, why):
    with pytest.raises(PathSearchError, match=why):
        plan_path(np.ones((4, 4)), (0, 0), (3, 3), res)


def test_compiled_kernel_needs_no_compiler(monkeypatch):
    # no C compiler on PATH and no CC: the compiled search still runs (numba ships its own LLVM)
    monkeypatch.setenv("PATH", "/nonexistent")
    monkeypatch.delenv("CC", raising=False)
    got = plan_path(np.ones((6, 6)), (0, 0), (5, 5), 1.0, "compiled")
    assert got is not None and got.method == "compiled" and got.cost == pytest.approx(5 * np.sqrt(2))
