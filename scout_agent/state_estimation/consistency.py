"""Is the state estimate's covariance honest? Error against ground truth over a whole run (evaluation only).

`ConsistencyTracker.add(truth_pos, truth_quat, estimate_pos, estimate_quat, pos_cov)` once per control tick;
`summary()` gives, over every tick of the run:
- `pos_error_max_m`, `pos_error_final_m`: horizontal distance between the true and estimated base position
  (the maximum, not only the end: end-point error flatters loops);
- `pos_error_start_m`: the horizontal error at the first tick (the launch survey's), and
  `pos_error_growth_max_m`, `pos_error_growth_final_m`: how far the error vector moved from it, the largest over
  the run and at the end, |e(t) − e(0)| (what the walk added to the start's error: the start and the drift apart);
- `yaw_error_max_deg`: the largest heading error; `yaw_error_start_deg`, the heading error at the first tick (the
  launch survey's draw), and `yaw_error_growth_max_deg`, the largest |ε(t) − ε(0)| (what the walk added to it:
  nothing proprioceptive observes the survey's heading, so the two are apart);
- `nees_pos_mean`: mean normalised estimation error squared of the horizontal position, eᵀ P⁻¹ e with P the
  filter's 2×2 horizontal position covariance; a consistent filter averages 2 (two degrees of freedom);
- `inside_3sigma_frac`: share of ticks whose true horizontal position lies inside the estimate's 3σ ellipse
  (eᵀ P⁻¹ e ≤ 9; a consistent Gaussian filter: 98.9 %);
- `nees_yaw_mean`, `yaw_inside_3sigma_frac`: the same for the heading (one degree of freedom: a consistent filter
  averages 1, and 99.7 % of its ticks have |error| ≤ 3σ), when the heading variance is given;
- `height_error_max_m`, `nees_height_mean`, `height_inside_3sigma_frac`: the same for the base height (one
  degree of freedom), when the position covariance is 3×3 (the filter's: always).
Only evaluation code calls this; it reads the simulator's truth.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["ConsistencyTracker", "yaw_of_quat"]


def yaw_of_quat(quat: np.ndarray) -> float:
    """Heading [rad] of a (w, x, y, z) quaternion."""
    w, x, y, z = quat.tolist()
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


# the tracker's running figures, one float each, updated in place by the compiled tick
(
    _N,
    _ERR_MAX,
    _ERR_FINAL,
    _YAW_MAX,
    _NEES_SUM,
    _NEES_N,
    _INSIDE,
    _NEES_YAW_SUM,
    _NEES_YAW_N,
    _YAW_INSIDE,
    _EX0,
    _EY0,
    _GROWTH_MAX,
    _GROWTH_FINAL,
    _Z_MAX,
    _NEES_Z_SUM,
    _NEES_Z_N,
    _Z_INSIDE,
    _YAW0,
    _YAW_GROWTH_MAX,
) = range(20)


@njit(cache=True, nogil=True)
def _yaw(q: np.ndarray) -> float:
    return math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] * q[2] + q[3] * q[3]))


@njit(cache=True, nogil=True)
def _add(
    acc: np.ndarray,
    truth_pos: np.ndarray,
    truth_quat: np.ndarray,
    est_pos: np.ndarray,
    est_quat: np.ndarray,
    cov_xx: float,
    cov_xy: float,
    cov_yy: float,
    yaw_var: float,
    var_z: float,
) -> None:
    """One tick into `acc`; a NaN `cov_xx` (no covariance), `yaw_var` (no heading variance) or `var_z` (no
    height variance) leaves out the position, heading or height NEES."""
    ex, ey = truth_pos[0] - est_pos[0], truth_pos[1] - est_pos[1]
    err = math.hypot(ex, ey)
    acc[_N] += 1.0
    if acc[_N] == 1.0:
        acc[_EX0], acc[_EY0] = ex, ey
    growth = math.hypot(ex - acc[_EX0], ey - acc[_EY0])
    acc[_GROWTH_FINAL] = growth
    acc[_GROWTH_MAX] = max(acc[_GROWTH_MAX], growth)
    acc[_ERR_FINAL] = err
    acc[_ERR_MAX] = max(acc[_ERR_MAX], err)
    dyaw = (_yaw(est_quat) - _yaw(truth_quat) + math.pi) % (2 * math.pi) - math.pi
    acc[_YAW_MAX] = max(acc[_YAW_MAX], abs(dyaw))
    if acc[_N] == 1.0:
        acc[_YAW0] = dyaw
    dgrow = (dyaw - acc[_YAW0] + math.pi) % (2 * math.pi) - math.pi
    acc[_YAW_GROWTH_MAX] = max(acc[_YAW_GROWTH_MAX], abs(dgrow))
    ez = truth_pos[2] - est_pos[2]
    acc[_Z_MAX] = max(acc[_Z_MAX], abs(ez))
    if var_z > 0:  # False for NaN
        nees_z = ez * ez / var_z
        acc[_NEES_Z_SUM] += nees_z
        acc[_NEES_Z_N] += 1.0
        acc[_Z_INSIDE] += nees_z <= 9.0
    if yaw_var > 0:  # False for NaN
        nees_yaw = dyaw * dyaw / yaw_var
        acc[_NEES_YAW_SUM] += nees_yaw
        acc[_NEES_YAW_N] += 1.0
        acc[_YAW_INSIDE] += nees_yaw <= 9.0
    det = cov_xx * cov_yy - cov_xy * cov_xy
    if not det > 0:  # also NaN: no covariance
        return
    nees = (cov_yy * ex * ex - 2 * cov_xy * ex * ey + cov_xx * ey * ey) / det
    acc[_NEES_SUM] += nees
    acc[_NEES_N] += 1.0
    acc[_INSIDE] += nees <= 9.0


@njit(cache=True, nogil=True)
def _add_filter(
    acc: np.ndarray,
    truth_pos: np.ndarray,
    truth_quat: np.ndarray,
    est_pos: np.ndarray,
    est_quat: np.ndarray,
    P: np.ndarray,
    R: np.ndarray,
) -> None:
    """`_add` with the filter's own figures: the horizontal position block P[6:8, 6:8] and the heading variance
    uᵀ P_θθ u, u = Rᵀe_z (`ErrorStateEKF.heading_variance`)."""
    yaw_var = 0.0
    for i in range(3):
        for j in range(3):
            yaw_var += R[2, i] * P[i, j] * R[2, j]
    _add(acc, truth_pos, truth_quat, est_pos, est_quat, P[6, 6], P[6, 7], P[7, 7], yaw_var, P[8, 8])


class ConsistencyTracker:
    def __init__(self) -> None:
        self._acc = np.zeros(20)
        self._acc[_ERR_FINAL] = math.nan

    def add(
        self,
        truth_pos: np.ndarray,
        truth_quat: np.ndarray,
        est_pos: np.ndarray,
        est_quat: np.ndarray,
        pos_cov: np.ndarray | None,
        yaw_var: float | None = None,
    ) -> None:
        """One tick: the true and estimated pose, the estimate's horizontal position covariance (2×2 or larger;
        None: not judged) and heading variance [rad²] (None: not judged)."""
        (a, b), (_, d) = pos_cov[:2, :2].tolist() if pos_cov is not None else ((math.nan, 0.0), (0.0, 0.0))
        _add(
            self._acc,
            _f3(truth_pos),
            _f4(truth_quat),
            _f3(est_pos),
            _f4(est_quat),
            a,
            b,
            d,
            math.nan if yaw_var is None else float(yaw_var),
            float(pos_cov[2, 2]) if pos_cov is not None and len(pos_cov) > 2 else math.nan,
        )

    def add_filter(
        self,
        truth_pos: np.ndarray,
        truth_quat: np.ndarray,
        est_pos: np.ndarray,
        est_quat: np.ndarray,
        P: np.ndarray,
        R: np.ndarray,
    ) -> None:
        """`add` judged by the error-state filter's covariance `P` (15, 15) and attitude `R` (3, 3)
        (`ErrorStateEKF`: rotation error first, position at 6:9) in one compiled call: the run loop's form."""
        _add_filter(self._acc, truth_pos, truth_quat, est_pos, est_quat, P, R)

    def summary(self) -> dict[str, float | None]:
        def r(v: float, nd: int = 4) -> float | None:
            return round(v, nd) if math.isfinite(v) else None

        acc = self._acc.tolist()
        n, nees_n, nees_yaw_n = acc[_N], acc[_NEES_N], acc[_NEES_YAW_N]
        return {
            "pos_error_max_m": r(acc[_ERR_MAX]) if n else None,
            "pos_error_final_m": r(acc[_ERR_FINAL]) if n else None,
            "pos_error_start_m": r(math.hypot(acc[_EX0], acc[_EY0])) if n else None,
            "pos_error_growth_max_m": r(acc[_GROWTH_MAX]) if n else None,
            "pos_error_growth_final_m": r(acc[_GROWTH_FINAL]) if n else None,
            "yaw_error_max_deg": r(math.degrees(acc[_YAW_MAX]), 3) if n else None,
            "yaw_error_start_deg": r(math.degrees(acc[_YAW0]), 3) if n else None,
            "yaw_error_growth_max_deg": r(math.degrees(acc[_YAW_GROWTH_MAX]), 3) if n else None,
            "nees_pos_mean": r(acc[_NEES_SUM] / nees_n, 3) if nees_n else None,
            "inside_3sigma_frac": r(acc[_INSIDE] / nees_n) if nees_n else None,
            "nees_yaw_mean": r(acc[_NEES_YAW_SUM] / nees_yaw_n, 3) if nees_yaw_n else None,
            "yaw_inside_3sigma_frac": r(acc[_YAW_INSIDE] / nees_yaw_n) if nees_yaw_n else None,
            "height_error_max_m": r(acc[_Z_MAX]) if n else None,
            "nees_height_mean": r(acc[_NEES_Z_SUM] / acc[_NEES_Z_N], 3) if acc[_NEES_Z_N] else None,
            "height_inside_3sigma_frac": r(acc[_Z_INSIDE] / acc[_NEES_Z_N]) if acc[_NEES_Z_N] else None,
        }


def _f3(v: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(v, dtype=float).reshape(3)


def _f4(v: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(v, dtype=float).reshape(4)
