"""Is the state estimate's covariance honest? Error against ground truth over a whole run (evaluation only).

`ConsistencyTracker.add(truth_pos, truth_quat, estimate_pos, estimate_quat, pos_cov)` once per control tick;
`summary()` gives, over every tick of the run:
- `pos_error_max_m`, `pos_error_final_m`: horizontal distance between the true and estimated base position
  (the maximum, not only the end: end-point error flatters loops);
- `yaw_error_max_deg`: the largest heading error;
- `nees_pos_mean`: mean normalised estimation error squared of the horizontal position, eᵀ P⁻¹ e with P the
  filter's 2×2 horizontal position covariance; a consistent filter averages 2 (two degrees of freedom);
- `inside_3sigma_frac`: share of ticks whose true horizontal position lies inside the estimate's 3σ ellipse
  (eᵀ P⁻¹ e ≤ 9; a consistent Gaussian filter: 98.9 %);
- `nees_yaw_mean`, `yaw_inside_3sigma_frac`: the same for the heading (one degree of freedom: a consistent filter
  averages 1, and 99.7 % of its ticks have |error| ≤ 3σ), when the heading variance is given.
Only evaluation code calls this; it reads the simulator's truth.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ConsistencyTracker", "yaw_of_quat"]


def yaw_of_quat(quat: np.ndarray) -> float:
    """Heading [rad] of a (w, x, y, z) quaternion."""
    w, x, y, z = quat.tolist()
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


class ConsistencyTracker:
    def __init__(self) -> None:
        self.n = 0
        self.err_max = 0.0
        self.err_final = math.nan
        self.yaw_max = 0.0
        self.nees_sum = 0.0
        self.nees_n = 0
        self.inside = 0
        self.nees_yaw_sum = 0.0
        self.nees_yaw_n = 0
        self.yaw_inside = 0

    def add(
        self,
        truth_pos: np.ndarray,
        truth_quat: np.ndarray,
        est_pos: np.ndarray,
        est_quat: np.ndarray,
        pos_cov: np.ndarray | None,
        yaw_var: float | None = None,
    ) -> None:
        (tx, ty, _), (px, py, _) = truth_pos.tolist(), est_pos.tolist()
        ex, ey = tx - px, ty - py
        err = math.hypot(ex, ey)
        self.n += 1
        self.err_final = err
        self.err_max = max(self.err_max, err)
        dyaw = (yaw_of_quat(est_quat) - yaw_of_quat(truth_quat) + math.pi) % (2 * math.pi) - math.pi
        self.yaw_max = max(self.yaw_max, abs(dyaw))
        if yaw_var is not None and yaw_var > 0:
            nees_yaw = dyaw * dyaw / yaw_var
            self.nees_yaw_sum += nees_yaw
            self.nees_yaw_n += 1
            self.yaw_inside += nees_yaw <= 9.0
        if pos_cov is None:
            return
        (a, b), (_, d) = pos_cov[:2, :2].tolist()
        det = a * d - b * b
        if not det > 0:
            return
        nees = (d * ex * ex - 2 * b * ex * ey + a * ey * ey) / det
        self.nees_sum += nees
        self.nees_n += 1
        self.inside += nees <= 9.0

    def summary(self) -> dict[str, float | None]:
        def r(v: float, nd: int = 4) -> float | None:
            return round(v, nd) if math.isfinite(v) else None

        return {
            "pos_error_max_m": r(self.err_max) if self.n else None,
            "pos_error_final_m": r(self.err_final) if self.n else None,
            "yaw_error_max_deg": r(math.degrees(self.yaw_max), 3) if self.n else None,
            "nees_pos_mean": r(self.nees_sum / self.nees_n, 3) if self.nees_n else None,
            "inside_3sigma_frac": r(self.inside / self.nees_n) if self.nees_n else None,
            "nees_yaw_mean": r(self.nees_yaw_sum / self.nees_yaw_n, 3) if self.nees_yaw_n else None,
            "yaw_inside_3sigma_frac": r(self.yaw_inside / self.nees_yaw_n) if self.nees_yaw_n else None,
        }
