"""The mission's numba kernels compiled ahead, with one line saying so: the first mission after an install
would otherwise sit at 0 % while every scout process compiles the state estimator's kernels at once.

`compile_ahead(say)` does nothing when numba's cache already holds every kernel; else it prints
`psrmap_common.jit.COMPILE_NOTICE` and runs the state estimator's and the planner's kernels once on small inputs in
this process (numba writes the machine code to its cache; the scouts and the planner load it)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from psrmap_common.jit import COMPILE_NOTICE, uncached
from psrmap_common.pathsearch import kernels as plan_kernels
from psrmap_common.pathsearch import plan_path
from scout_agent.state_estimation import kernels as ekf_kernels
from scout_agent.state_estimation.ekf import ErrorStateEKF

__all__ = ["compile_ahead"]


def compile_ahead(say: Callable[[str], None]) -> float:
    """Compile what is not cached yet (saying so first); returns the seconds it took (0.0 when cached)."""
    todo = uncached(
        [
            getattr(m, n)
            for m in (ekf_kernels, plan_kernels)
            for n in dir(m)
            if hasattr(getattr(m, n), "_cache")
        ]
    )
    if not todo:
        return 0.0
    say(f"[mission] {COMPILE_NOTICE}: {', '.join(sorted(todo))}")
    t0 = time.perf_counter()
    _run_ekf()
    _run_search()
    took = time.perf_counter() - t0
    say(f"[mission] kernels compiled in {took:.0f} s")
    return took


def _run_ekf() -> None:
    ekf = ErrorStateEKF(np.eye(3), np.zeros(3), np.zeros(3), np.array([0.0, 0.0, -1.62]))
    ekf.propagate(np.zeros(3), np.array([0.0, 0.0, 1.62]), 0.002)
    z, H = ekf.velocity_rows_many(np.zeros((4, 3)))
    ekf.update(-z.reshape(-1), H, np.ones(H.shape[0]), 9.0)


def _run_search() -> None:
    plan_path(np.ones((6, 6)), (0, 0), (5, 5), 0.4)  # Dial's buckets
    cost = np.ones((6, 6))
    cost[2, 1:] = 0.0  # zero-cost cells: the A* kernel
    plan_path(cost, (0, 0), (5, 5), 0.4)
