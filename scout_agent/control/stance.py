"""Stance forces by a small QP (quadprog): track a desired body wrench under friction-pyramid constraints.

    min_f  ‖A f − w‖²_S + α‖f‖² + β‖f − f_prev‖²
    s.t.   f_min ≤ n·f ≤ f_max,  |t_k·f| ≤ μ_i n·f  (k = 1, 2)   for each stance foot i

with A = [I …; [r_i]× …] (world frame, r_i foot relative to the CoM) and n the terrain normal. μ_i is the
configured constant unless the caller passes each foot's friction (the scout's own estimate,
`friction_estimate`), so the forces ask no more of the ground than it was felt to hold. The problem's
matrices are built compiled (`qp_problem`, numba); quadprog solves it. The controller's tick (`solve_feet`)
builds the problem and calls quadprog's solver routine `qpgen2_` in one compiled call (`scout_agent.ccall`),
on the same inputs `quadprog.solve_qp` hands it (G and C in Fortran order), into buffers kept on the instance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import quadprog
from numba import njit

from scout_agent.ccall import c_function, ccall_int

# quadprog's Goldfarb-Idnani solver, the C routine its `solve_qp` wraps (this signature since quadprog 0.1.10):
# int qpgen2_(double *G, double *a, int n, double *sol, double *lagr, double *crval, double *C, double *b,
#             int q, int meq, int *iact, int *nact, int *iter, double *work, int factorized)
_QPGEN2 = c_function(quadprog.__file__, "qpgen2_")
_N_MAX, _M_MAX = 12, 24  # variables and constraints with four stance feet
# the float workspace: G (n, n) and C (n, m) in Fortran order, a, b, sol, lagr, crval, work
_WS_G, _WS_C = 0, _N_MAX * _N_MAX
_WS_A = _WS_C + _N_MAX * _M_MAX
_WS_B = _WS_A + _N_MAX
_WS_SOL = _WS_B + _M_MAX
_WS_LAGR = _WS_SOL + _N_MAX
_WS_CRVAL = _WS_LAGR + _M_MAX
_WS_WORK = _WS_CRVAL + 1
_WS_LEN = _WS_WORK + 2 * _N_MAX + 2 * _M_MAX + _N_MAX * (_N_MAX + 5) // 2


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
        self._limits = np.array([c.f_min, c.f_max, c.reg, c.smooth])
        self._ws = np.zeros(_WS_LEN)  # `_stance_forces`' buffers
        self._iws = np.zeros(_M_MAX + 3, dtype=np.int32)  # iact, nact, iter

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
        forces = np.zeros((4, 3))
        mu4 = self._mu4 if mu is None else np.asarray(mu, dtype=float)
        _stance_forces(
            stance,
            feet_w,
            com,
            f_prev,
            mu4,
            normal,
            wrench,
            self._S,
            self._limits,
            _QPGEN2,
            self._ws,
            self._iws,
            forces,
        )
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
def _stance_forces(
    stance: np.ndarray,
    feet_w: np.ndarray,
    com: np.ndarray,
    f_prev: np.ndarray,
    mu: np.ndarray,
    normal: np.ndarray,
    wrench: np.ndarray,
    S: np.ndarray,
    limits: np.ndarray,
    qpgen2: int,
    ws: np.ndarray,
    iws: np.ndarray,
    forces: np.ndarray,
) -> None:
    """`StanceQP.solve_feet` compiled: the problem for the feet in `stance` of all four (positions relative to
    the CoM, their last forces `f_prev` (4, 3) and friction `mu` (4,) selected here; `limits` f_min, f_max,
    reg, smooth) built into the workspace `ws`/`iws` as `quadprog.solve_qp` lays it out, solved by `qpgen2`,
    the forces written into the stance rows of `forces` (4, 3) (zero elsewhere). An infeasible problem (which
    these box and cone constraints should never give) spreads the wrench's z force over the stance feet."""
    k = 0
    for i in range(4):
        k += stance[i]
    if k == 0:
        return
    n, m = 3 * k, 6 * k
    r, fp, mk = np.empty((k, 3)), np.empty(n), np.empty(k)
    row = 0
    for i in range(4):
        if stance[i]:
            for j in range(3):
                r[row, j] = feet_w[i, j] - com[j]
                fp[3 * row + j] = f_prev[i, j]
            mk[row] = mu[i]
            row += 1
    G = ws[_WS_G : _WS_G + n * n].reshape((n, n)).T  # Fortran order: G[i, j] at i + j·n
    Cm = ws[_WS_C : _WS_C + n * m].reshape((m, n)).T
    a, b = ws[_WS_A : _WS_A + n], ws[_WS_B : _WS_B + m]
    _fill_problem(r, normal, wrench, fp, S, mk, limits, G, a, Cm, b)
    sol = ws[_WS_SOL : _WS_SOL + n]
    ierr = ccall_int(
        qpgen2,
        (
            ws[_WS_G:],
            a,
            np.int32(n),
            sol,
            ws[_WS_LAGR:],
            ws[_WS_CRVAL:],
            ws[_WS_C:],
            b,
            np.int32(m),
            np.int32(0),  # meq: no equality constraints
            iws,
            iws[_M_MAX:],
            iws[_M_MAX + 1 :],
            ws[_WS_WORK:],
            np.int32(0),  # G not factorized
        ),
    )
    row = 0
    for i in range(4):
        if stance[i]:
            for j in range(3):
                if ierr == 0:
                    forces[i, j] = sol[3 * row + j]
                else:
                    forces[i, j] = wrench[2] / k if j == 2 else 0.0
            row += 1


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
    """quadprog's (G, a, C, b) for the problem above: min ½fᵀGf − aᵀf s.t. Cᵀf ≥ b (compiled)."""
    k = r.shape[0]
    n = 3 * k
    G, a, Cm, b = np.empty((n, n)), np.empty(n), np.empty((n, 6 * k)), np.empty(6 * k)
    limits = np.array([f_min, f_max, reg, smooth])
    _fill_problem(r, normal, wrench, f_prev, S, mu, limits, G, a, Cm, b)
    return G, a, Cm, b


@njit(cache=True, nogil=True)
def _fill_problem(
    r: np.ndarray, normal: np.ndarray, wrench: np.ndarray, f_prev: np.ndarray, S: np.ndarray, mu: np.ndarray,
    limits: np.ndarray, G: np.ndarray, a: np.ndarray, Cm: np.ndarray, b: np.ndarray,
) -> None:  # fmt: skip
    """`qp_problem`'s arithmetic into G (n, n), a (n,), C (n, 6k), b (6k,) (C-order arrays or Fortran-order
    views); `limits`: f_min, f_max, reg, smooth."""
    f_min, f_max, reg, smooth = limits[0], limits[1], limits[2], limits[3]
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
    Cm[:, :] = 0.0
    b[:] = 0.0
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
