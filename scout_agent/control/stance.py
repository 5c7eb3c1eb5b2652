"""Stance forces by a small QP (quadprog): track a desired body wrench under friction-pyramid constraints.

    min_f  ‖A f − w‖²_S + α‖f‖² + β‖f − f_prev‖²
    s.t.   f_min ≤ n·f ≤ f_max,  |t_k·f| ≤ μ_i n·f  (k = 1, 2)   for each stance foot i

with A = [I …; [r_i]× …] (world frame, r_i foot relative to the CoM) and n the terrain normal. μ_i is the
configured constant unless the caller passes each foot's friction (the scout's own estimate,
`friction_estimate`), so the forces ask no more of the ground than it was felt to hold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import quadprog


@dataclass(frozen=True)
class StanceQPConfig:
    mu: float = 0.6  # friction the controller assumes (below the regolith's 0.7)
    f_min: float = 2.0  # [N]
    f_max: float = 150.0  # [N]
    force_weight: float = 1.0
    moment_weight: float = 20.0
    reg: float = 1e-3  # α
    smooth: float = 1e-3  # β


class StanceQP:
    def __init__(self, config: StanceQPConfig = StanceQPConfig()) -> None:
        self.config = config
        c = config
        self._S = np.array([c.force_weight] * 3 + [c.moment_weight] * 3)

    def solve(
        self,
        r: np.ndarray,
        normal: np.ndarray,
        wrench: np.ndarray,
        f_prev: np.ndarray | None = None,
        mu: np.ndarray | None = None,
    ) -> np.ndarray:
        """Forces (k, 3) on the k stance feet (world frame) from their positions `r` (k, 3) relative to the
        CoM, the ground normal (3,), the desired wrench (6,) = (force, moment about the CoM) and optionally
        each foot's friction coefficient `mu` (k,) (default: the configured constant)."""
        c = self.config
        k = r.shape[0]
        n = 3 * k
        A = np.zeros((6, n))
        for i in range(k):
            x, y, z = r[i]
            j = 3 * i
            A[0, j] = A[1, j + 1] = A[2, j + 2] = 1.0
            A[3, j + 1], A[3, j + 2] = -z, y
            A[4, j], A[4, j + 2] = z, -x
            A[5, j], A[5, j + 1] = -y, x
        AS = A.T * self._S
        G = AS @ A
        G[np.diag_indices(n)] += c.reg + c.smooth
        a = AS @ wrench
        if f_prev is not None:
            a += c.smooth * f_prev.ravel()
        nx, ny, nz = normal
        t1 = np.array([-nz, 0.0, nx]) if abs(nx) < 0.9 else np.array([ny, -nx, 0.0])  # ⊥ normal
        t1 /= np.sqrt(t1 @ t1)
        t2 = np.array([ny * t1[2] - nz * t1[1], nz * t1[0] - nx * t1[2], nx * t1[1] - ny * t1[0]])
        lo = np.array([c.f_min, -c.f_max, 0.0, 0.0, 0.0, 0.0])
        Cm = np.zeros((n, 6 * k))
        b = np.tile(lo, k)
        for i in range(k):
            m = c.mu if mu is None else float(mu[i])
            rows = np.array(
                [normal, -normal, m * normal - t1, m * normal + t1, m * normal - t2, m * normal + t2]
            )
            Cm[3 * i : 3 * i + 3, 6 * i : 6 * i + 6] = rows.T
        try:
            f = quadprog.solve_qp(G, a, Cm, b, 0)[0]
        except ValueError:  # infeasible (should not happen with these box/cone constraints)
            f = np.zeros(n)
            f[2::3] = wrench[2] / k
        return f.reshape(k, 3)
