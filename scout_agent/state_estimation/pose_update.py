"""A pose measurement update of the error-state EKF: map-frame x, y, z and heading with a full covariance,
e.g. from matching footholds against a map (`scout_agent.localization`).

Measurement: z = (x, y, z, ψ) of the base, ψ = atan2(R[1,0], R[0,0]). Jacobians in the error state
(δθ base frame, R_true = R·Exp(δθ); δp world): the position rows pick δp; the heading row is ∂ψ/∂δθ, taken
numerically (it is R's third row, (R[2,:]), only while the base is level). Rows whose variance is infinite are
left out (a match that did not search yaw). Gated: the whole measurement is refused when its Mahalanobis
distance² against the innovation covariance H P Hᵀ + R exceeds `gate_chi2` — a match that disagrees with
what the filter is sure of is a wrong place, not a correction. Joseph-form covariance update; the error
folded into the nominal state as `kernels.update` does.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .ekf import ErrorStateEKF
from .kernels import so3_exp

__all__ = ["PoseUpdate", "heading", "heading_row", "update_pose"]


class PoseUpdate(NamedTuple):
    accepted: bool
    d2: float  # Mahalanobis distance² of the innovation
    dof: int  # rows used
    correction: np.ndarray  # (4,) applied change of x, y, z [m] and heading [rad] (zeros when refused)


def heading(R: np.ndarray) -> float:
    return float(np.arctan2(R[1, 0], R[0, 0]))


def heading_row(R: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """∂ψ/∂δθ: the heading's row of the error state's rotation (numerical)."""
    row = np.zeros(3)
    psi = heading(R)
    for i in range(3):
        e = np.zeros(3)
        e[i] = eps
        d = heading(R @ so3_exp(e)) - psi
        row[i] = ((d + np.pi) % (2 * np.pi) - np.pi) / eps
    return row


def update_pose(ekf: ErrorStateEKF, measured: np.ndarray, cov: np.ndarray, gate_chi2: float) -> PoseUpdate:
    """Fuse a measured (x, y, z, ψ) with covariance `cov` (4, 4); rows with infinite or NaN variance are
    skipped. Returns whether it passed the gate, its d², and the correction applied."""
    measured = np.asarray(measured, dtype=float)
    cov = np.asarray(cov, dtype=float)
    use = np.isfinite(np.diag(cov)) & np.isfinite(measured)
    k = int(use.sum())
    if k == 0:
        return PoseUpdate(False, float("nan"), 0, np.zeros(4))
    H = np.zeros((4, 15))
    H[0, 6] = H[1, 7] = H[2, 8] = 1.0
    H[3, 0:3] = heading_row(ekf.R)
    pred = np.r_[ekf.p, heading(ekf.R)]
    res = measured - pred
    res[3] = (res[3] + np.pi) % (2 * np.pi) - np.pi
    H, res, Rm = H[use], res[use], cov[np.ix_(use, use)]
    P = ekf.P
    S = H @ P @ H.T + Rm
    d2 = float(res @ np.linalg.solve(S, res))
    if not np.isfinite(d2) or d2 > gate_chi2:
        return PoseUpdate(False, d2, k, np.zeros(4))
    K = np.linalg.solve(S, H @ P).T  # (15, k)
    dx = K @ res
    IKH = np.eye(15) - K @ H
    P[:, :] = IKH @ P @ IKH.T + K @ Rm @ K.T
    before = np.r_[ekf.p, heading(ekf.R)]
    ekf.R[:, :] = ekf.R @ so3_exp(np.ascontiguousarray(dx[0:3]))
    ekf.v += dx[3:6]
    ekf.p += dx[6:9]
    ekf.bg += dx[9:12]
    ekf.ba += dx[12:15]
    after = np.r_[ekf.p, heading(ekf.R)]
    corr = after - before
    corr[3] = (corr[3] + np.pi) % (2 * np.pi) - np.pi
    return PoseUpdate(True, d2, k, corr)
