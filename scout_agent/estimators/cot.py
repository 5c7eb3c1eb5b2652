"""Cost of Transport (paper eq. 5–6): CoT = E / (m·g·d), E = ∫ Σ_i |τ_i·θ̇_i| dt over the 12 joints.

Per tick we produce the two additive pieces a cell needs (ratio of sums, DESIGN "cot" layer):
`work` = E_tick / (m·g) [m] and `dist` = horizontal distance the base travelled during the tick [m].
E_tick is the joint energy the motor drivers integrated over the tick at every physics step from measured
current (torque) and velocity (`ProprioSample.joint_energy_j`, `scout_agent.sim.sensors.joints`). The distance is
‖v_xy‖·dt of the state estimator's velocity (IMU + leg odometry), which is smooth and near zero standing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["CotConfig", "CotMeter", "cot_from_sums", "joint_power"]


@dataclass(frozen=True)
class CotConfig:
    mass_kg: float = 24.64  # robot mass m [kg]; the pipeline sets it from the model actually simulated
    gravity_mps2: float = 1.62  # g [m/s²] (lunar)
    min_dist_m: float = 0.05  # a cell's CoT is undefined below this travel [m]


def joint_power(tau: np.ndarray, dq: np.ndarray) -> float:
    """Σ_i |τ_i·θ̇_i| [W] (absolute mechanical power, eq. 6 integrand)."""
    return float(np.abs(tau * dq).sum())


def cot_from_sums(work_m: np.ndarray | float, dist_m: np.ndarray | float, min_dist_m: float = 0.05):
    """CoT from summed work (E/(m·g) [m]) and distance [m]; NaN where dist < min_dist_m."""
    work = np.asarray(work_m, dtype=float)
    dist = np.asarray(dist_m, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(dist >= min_dist_m, work / np.where(dist > 0, dist, 1.0), np.nan)
    return out if out.ndim else float(out)


class CotMeter:
    """Integrates energy and distance; `update` returns this tick's (work [m], dist [m])."""

    def __init__(self, config: CotConfig | None = None) -> None:
        self.config = config or CotConfig()
        self._mg = self.config.mass_kg * self.config.gravity_mps2
        self._t_prev: float | None = None
        self.energy_j = 0.0  # E since start [J]
        self.dist_m = 0.0  # d since start [m]

    def update(self, t: float, energy_j: float, base_vel_world: np.ndarray) -> tuple[float, float]:
        """One tick: the joint energy since the last tick [J] and the base velocity (world) [m/s]."""
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        e = energy_j if dt > 0 else 0.0
        vx, vy, _ = base_vel_world.tolist()  # Python floats: numpy scalars' arithmetic costs ~10× more
        d = math.sqrt(vx * vx + vy * vy) * dt
        self.energy_j += e
        self.dist_m += d
        return e / self._mg, d

    @property
    def cot(self) -> float:
        """Whole-run CoT = E/(m·g·d); NaN below `min_dist_m`."""
        return cot_from_sums(self.energy_j / self._mg, self.dist_m, self.config.min_dist_m)
