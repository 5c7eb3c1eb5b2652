"""Stance forces by a small QP (quadprog): track a desired body wrench under friction-pyramid constraints.

    min_f  ‖A f − w‖²_S + α‖f‖² + β‖f − f_prev‖²
    s.t.   f_min ≤ n·f ≤ f_max,  |t_k·f| ≤ μ n·f  (k = 1, 2)   for each stance foot

with A = [I …; [r_i]× …] (world frame, r_i foot relative to the CoM) and n the terrain normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import quadprog


@dataclass(frozen=True)
class StanceQPConfig:
    mu: float = 0.5  # friction the controller assumes (below the regolith's 0.7)
    f_min: float = 2.0  # [N]
    f_max: float = 150.0  # [N]
    force_weight: float = 1.0
    moment_weight: float = 20.0
    reg: float = 1e-3  # α
    smooth: float = 1e-3  # β


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class StanceQP:
    def __init__(self, config: StanceQPConfig = StanceQPConfig()) -> None:
        self.config = config
        c = config
        self._S = np.array([c.force_weight] * 3 + [c.moment_weight] * 3)

    def solve(self, r: np.ndarray, normal: np.ndarray, wrench: np.ndarray,
              f_prev: np.ndarray | None = None) -> np.ndarray:
        """Forces (k, 3) on the k stance feet (world frame) from their positions `r` (k, 3) relative to the
        CoM, the ground normal (3,) and the desired wrench (6,) = (force, moment about the CoM)."""
        c = self.config
        k = r.shape[0]
        n = 3 * k
        A = np.zeros((6, n))
        for i in range(k):
            A[0:3, 3 * i : 3 * i + 3] = np.eye(3)
            A[3:6, 3 * i : 3 * i + 3] = _skew(r[i])
        AS = A.T * self._S
        G = AS @ A + (c.reg + c.smooth) * np.eye(n)
        a = AS @ wrench
        if f_prev is not None:
            a += c.smooth * f_prev.ravel()
        t1 = np.cross(normal, [0.0, 1.0, 0.0] if abs(normal[0]) < 0.9 else [1.0, 0.0, 0.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(normal, t1)
        rows = np.array([normal, -normal, c.mu * normal - t1, c.mu * normal + t1,
                         c.mu * normal - t2, c.mu * normal + t2])  # (6, 3)
        lo = np.array([c.f_min, -c.f_max, 0.0, 0.0, 0.0, 0.0])
        Cm = np.zeros((n, 6 * k))
        b = np.tile(lo, k)
        for i in range(k):
            Cm[3 * i : 3 * i + 3, 6 * i : 6 * i + 6] = rows.T
        try:
            f = quadprog.solve_qp(G, a, Cm, b, 0)[0]
        except ValueError:  # infeasible (should not happen with these box/cone constraints)
            f = np.zeros(n)
            f[2::3] = wrench[2] / k
        return f.reshape(k, 3)
