"""Stance forces by a small QP (quadprog): track a desired body wrench under friction-pyramid constraints.

    min_f  ‖A f − w‖²_S + α‖f‖² + β‖f − f_prev‖²
    s.t.   f_min ≤ n·f ≤ f_max,  |t_k·f| ≤ μ_i n·f  (k = 1, 2)   for each stance foot i

with A = [I …; [r_i]× …] (world frame, r_i foot relative to the CoM) and n the terrain normal. μ_i is the
configured constant unless the caller passes each foot's friction (the scout's own estimate,
`friction_estimate`), so the forces ask no more of the ground than it was felt to hold. The problem's
matrices are built compiled (`qp_problem`, numba); quadprog solves it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import quadprog
from numba import njit


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
        self._mu4 = np.full(4, c.mu)

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
        G, a, Cm, b = qp_problem(
            np.ascontiguousarray(r, dtype=float),
            np.asarray(normal, dtype=float),
            np.asarray(wrench, dtype=float),
            np.zeros(3 * k) if f_prev is None else np.ascontiguousarray(f_prev, dtype=float).reshape(3 * k),
            self._S,
            np.full(k, c.mu) if mu is None else np.asarray(mu, dtype=float),
            c.f_min,
            c.f_max,
            c.reg,
            c.smooth,
        )
        return _solve((G, a, Cm, b), wrench, k)

    def solve_feet(
        self,
        stance: np.ndarray,
        feet_w: np.ndarray,
        com: np.ndarray,
        normal: np.ndarray,
        wrench: np.ndarray,
        f_prev: np.ndarray,
        mu: np.ndarray | None = None,
    ) -> np.ndarray:
        """`solve` for the feet in `stance` (4,) bool of all four: their world positions `feet_w` (4, 3) and
        the CoM `com` (3,), last tick's forces `f_prev` (4, 3), each foot's friction `mu` (4,) or None;
        forces (4, 3), zero on the other feet (the controller's tick: the selection is compiled)."""
        c = self.config
        forces = np.zeros((4, 3))
        k = int(np.count_nonzero(stance))
        if k == 0:
            return forces
        mu4 = self._mu4 if mu is None else np.asarray(mu, dtype=float)
        problem = (normal, wrench, self._S, c.f_min, c.f_max, c.reg, c.smooth)
        forces[stance] = _solve(stance_problem(stance, feet_w, com, f_prev, mu4, problem), wrench, k)
        return forces


def _solve(
    qp: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], wrench: np.ndarray, k: int
) -> np.ndarray:
    """quadprog on (G, a, C, b); forces (k, 3)."""
    try:
        f = quadprog.solve_qp(*qp, 0)[0]
    except ValueError:  # infeasible (should not happen with these box/cone constraints)
        f = np.zeros(3 * k)
        f[2::3] = wrench[2] / k
    return f.reshape(k, 3)


@njit(cache=True, nogil=True)
def stance_problem(
    stance: np.ndarray,
    feet_w: np.ndarray,
    com: np.ndarray,
    f_prev: np.ndarray,
    mu: np.ndarray,
    problem: tuple[np.ndarray, np.ndarray, np.ndarray, float, float, float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`qp_problem` for the feet in `stance` of all four (positions relative to the CoM, their last forces
    `f_prev` (4, 3) and friction `mu` (4,) selected here); `problem`: normal, wrench, S, f_min, f_max, reg,
    smooth as `qp_problem` takes them."""
    normal, wrench, S, f_min, f_max, reg, smooth = problem
    k = 0
    for i in range(4):
        k += stance[i]
    r, fp, m = np.empty((k, 3)), np.empty(3 * k), np.empty(k)
    row = 0
    for i in range(4):
        if stance[i]:
            for j in range(3):
                r[row, j] = feet_w[i, j] - com[j]
                fp[3 * row + j] = f_prev[i, j]
            m[row] = mu[i]
            row += 1
    return qp_problem(r, normal, wrench, fp, S, m, f_min, f_max, reg, smooth)


@njit(cache=True, nogil=True)
def qp_problem(
    r: np.ndarray,
    normal: np.ndarray,
    wrench: np.ndarray,
    f_prev: np.ndarray,
    S: np.ndarray,
    mu: np.ndarray,
    f_min: float,
    f_max: float,
    reg: float,
    smooth: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """quadprog's (G, a, C, b) for the problem above: min ½fᵀGf − aᵀf s.t. Cᵀf ≥ b (compiled; every tick)."""
    k = r.shape[0]
    n = 3 * k
    A = np.zeros((6, n))
    for i in range(k):
        x, y, z = r[i, 0], r[i, 1], r[i, 2]
        j = 3 * i
        A[0, j] = A[1, j + 1] = A[2, j + 2] = 1.0
        A[3, j + 1], A[3, j + 2] = -z, y
        A[4, j], A[4, j + 2] = z, -x
        A[5, j], A[5, j + 1] = -y, x
    G = np.empty((n, n))
    a = np.empty(n)
    for i in range(n):
        for j in range(n):
            g = 0.0
            for row in range(6):
                g += (A[row, i] * S[row]) * A[row, j]
            G[i, j] = g
        G[i, i] += reg + smooth
        s = 0.0
        for row in range(6):
            s += (A[row, i] * S[row]) * wrench[row]
        a[i] = s + smooth * f_prev[i]
    nx, ny, nz = normal[0], normal[1], normal[2]
    t1 = np.array([-nz, 0.0, nx]) if abs(nx) < 0.9 else np.array([ny, -nx, 0.0])  # ⊥ normal
    t1 /= np.sqrt(t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2])
    t2 = np.array([ny * t1[2] - nz * t1[1], nz * t1[0] - nx * t1[2], nx * t1[1] - ny * t1[0]])
    Cm = np.zeros((n, 6 * k))
    b = np.zeros(6 * k)
    for i in range(k):
        b[6 * i] = f_min
        b[6 * i + 1] = -f_max
        m = mu[i]
        for j in range(3):
            col = 3 * i + j
            Cm[col, 6 * i] = normal[j]
            Cm[col, 6 * i + 1] = -normal[j]
            Cm[col, 6 * i + 2] = m * normal[j] - t1[j]
            Cm[col, 6 * i + 3] = m * normal[j] + t1[j]
            Cm[col, 6 * i + 4] = m * normal[j] - t2[j]
            Cm[col, 6 * i + 5] = m * normal[j] + t2[j]
    return G, a, Cm, b
