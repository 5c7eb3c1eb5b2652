"""An error-state EKF for a legged robot's base: IMU propagation, base-velocity updates.

Nominal state: world_R_base `R`, velocity `v` and position `p` of the base origin (world frame), gyro bias `bg`
and accelerometer bias `ba` (base frame). Error state (15,): δθ (rotation error in the base frame,
R_true = R·Exp(δθ)), δv, δp, δbg, δba.

Propagation with the IMU (ω_m, f_m, base frame; g world):
    ω = ω_m − bg,  f = f_m − ba,  a = R f + g
    p += v dt + a dt²/2,  v += a dt,  R ← R Exp(ω dt)
Error dynamics: δθ̇ = −[ω]× δθ − δbg − n_g,  δv̇ = −R[f]× δθ − R δba − R n_a,  δṗ = δv,  δḃ = n_b.

Measurement: a base velocity seen in the base frame plus a lever-arm bias term, z = Rᵀ v + [r]× bg + n
(leg odometry of one stance foot with contact point r, see leg_odometry.py), Jacobians
H_θ = [Rᵀ v]×, H_v = Rᵀ, H_bg = [r]×.

What is observable: roll and pitch (gravity, through the velocity updates: a tilt error makes the
accelerometer's gravity leak into v, which the legs contradict), velocity, and the gyro bias about axes not
parallel to gravity; yaw, the gyro bias about gravity and position are not,
and drift (the estimator's standstills observe the bias: standstill.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scout_agent.robot.vectors import cross, skew

from . import kernels
from .kernels import so3_exp

__all__ = ["ErrorStateEKF", "NoiseConfig", "so3_exp"]


@dataclass(frozen=True)
class NoiseConfig:
    """Continuous-time noise densities of the filter (its tuning, see estimator.py for why these values)."""

    gyro: float = 2.44e-4 * 3  # [rad/s/√Hz]
    acc: float = 1.72e-3 * 3  # [m/s²/√Hz]
    gyro_bias_walk: float = 1e-5  # [rad/s/√s]
    # the gyro offset about its z axis (heading's): 3× the sensor model's walk, not 10×. Roll and pitch
    # observe the x and y offsets all the time through gravity, so their margin costs nothing; heading's is
    # measured only standing (standstill.py), and a 1e-5 walk (σ 8e-5 rad/s a minute later) threw each
    # pause's measurement away before the next: the pauses' creep (1.6e-4 rad/s each) is averaged only if the
    # filter remembers them (docs/results.md, "Heading at 100 m"). Its temperature and g-sensitivity terms,
    # which do move it, are widened for separately (estimator.py, `_inflate`)
    gyro_bias_walk_z: float = 3e-6  # [rad/s/√s]
    acc_bias_walk: float = 1e-3  # [m/s²/√s]
    position: float = 1e-3  # [m/√s] (unmodelled; keeps P well conditioned)
    init_tilt: float = 0.02  # σ of the initial roll/pitch [rad]
    init_yaw: float = 0.002  # σ of the launch yaw [rad]
    init_vel: float = 0.05  # [m/s]
    init_pos: float = 0.005  # [m]
    init_gyro_bias: float = 5e-4  # [rad/s] ≈ 4.5× the power-on calibration's residual (estimator.py)
    init_acc_bias: float = 0.1  # [m/s²]


class ErrorStateEKF:
    def __init__(
        self,
        R: np.ndarray,
        v: np.ndarray,
        p: np.ndarray,
        gravity: np.ndarray,
        noise: NoiseConfig = NoiseConfig(),
    ) -> None:
        self.R = np.array(R, dtype=float)
        self.v = np.array(v, dtype=float)
        self.p = np.array(p, dtype=float)
        self.bg = np.zeros(3)
        self.ba = np.zeros(3)
        self.g = np.asarray(gravity, dtype=float)
        self.noise = n = noise
        # initial covariance: the launch yaw is known (mission frame), roll/pitch come from gravity
        sd = np.r_[
            n.init_tilt,
            n.init_tilt,
            n.init_yaw,
            [n.init_vel] * 3,
            [n.init_pos] * 3,
            [n.init_gyro_bias] * 3,
            [n.init_acc_bias] * 3,
        ]
        self.P = np.diag(sd**2)
        self._q = np.r_[
            [n.gyro**2] * 3,
            [n.acc**2] * 3,
            [n.position**2] * 3,
            [n.gyro_bias_walk**2] * 2,
            [n.gyro_bias_walk_z**2],
            [n.acc_bias_walk**2] * 3,
        ]  # process noise densities², per unit time

    @property
    def process_noise(self) -> np.ndarray:
        """(15,) the process noise densities², per unit time (the propagation's q)."""
        return self._q

    def _arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The nominal state and covariance the kernels update in place: R, v, p, bg, ba, P."""
        return self.R, self.v, self.p, self.bg, self.ba, self.P

    def propagate(self, gyro: np.ndarray, acc: np.ndarray, dt: float) -> np.ndarray:
        """One IMU step; returns the bias-corrected angular velocity ω (base frame) [rad/s]."""
        return kernels.propagate(
            *self._arrays(),
            self.g,
            self._q,
            np.asarray(gyro, dtype=float),
            np.asarray(acc, dtype=float),
            float(dt),
        )

    def velocity_rows(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted z = Rᵀv + [r]× bg (3,) and its Jacobian H (3, 15)."""
        vb = self.R.T @ self.v
        H = np.zeros((3, 15))
        H[:, 0:3] = skew(vb)
        H[:, 3:6] = self.R.T
        H[:, 9:12] = skew(r)
        return vb + cross(r, self.bg), H

    def velocity_rows_many(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`velocity_rows` for k lever arms r (k, 3) at once: predictions (k, 3), stacked Jacobian (3k, 15)."""
        return kernels.velocity_rows_many(self.R, self.v, self.bg, np.ascontiguousarray(r, dtype=float))

    def position_z_rows(self) -> np.ndarray:
        """Jacobian (1, 15) of a measurement of the base height p_z."""
        H = np.zeros((1, 15))
        H[0, 8] = 1.0
        return H

    def add_heading_variance(self, q: float) -> None:
        """Process noise of the heading alone, the rotation about world z [rad²]: in the base-frame error state
        that is u = Rᵀe_z (R's third row), so P_θθ grows by q·u uᵀ. Adding q to the base-z element instead
        would, on a slope of α, add sin α of it to the tilt, fully correlated with heading; an update that
        measures the tilt (gravity) would then turn the heading by cot α × its tilt residual."""
        kernels.add_heading_variance(self.R, self.P, q)

    def heading_variance(self) -> float:
        """Variance of the heading (rotation about world z) [rad²]: uᵀ P_θθ u, u = Rᵀe_z."""
        return kernels.heading_variance(self.R, self.P)

    def gravity_update(self, f_base: np.ndarray, std_mps2: float, gate_chi2: float) -> bool:
        """Standing still the accelerometer reads gravity: f = Rᵀ(−g) + ba, H_θ = [Rᵀ(−g)]×, H_ba = I; σ per
        axis `std_mps2`, χ²(3)-gated (the trunk accelerating). Gravity says nothing of heading (a rotation about
        it leaves Rᵀ(−g) unchanged), so this is a Schmidt update of heading, as the leg odometry's: no
        correlation the linearisation carries turns it. Returns whether it was fused."""
        u = self.R.T @ -self.g
        H = np.zeros((3, 15))
        H[:, 0:3] = skew(u)
        H[:, 12:15] = np.eye(3)
        residual = np.asarray(f_base, dtype=float) - (u + self.ba)
        keep = self.update(residual, H, np.full(3, std_mps2**2), gate_chi2=gate_chi2, hold_heading=True)
        return bool(keep[0])

    def update(
        self,
        residual: np.ndarray,
        H: np.ndarray,
        noise_var: np.ndarray,
        gate_chi2: float | None = None,
        hold_heading: bool = False,
    ) -> np.ndarray:
        """Kalman update with stacked 3-row measurements; the error is folded into the nominal state. With
        `gate_chi2`, each 3-row block whose Mahalanobis distance² exceeds it is dropped first (an outlier, e.g.
        a slipping foot). `hold_heading`: the update does not correct heading (a Schmidt update of the rotation
        about world z; kernels.update). Returns the kept blocks' mask. Joseph-form covariance update."""
        return kernels.update(
            *self._arrays(),
            np.ascontiguousarray(residual, dtype=float),
            np.ascontiguousarray(H, dtype=float),
            np.ascontiguousarray(noise_var, dtype=float),
            0.0 if gate_chi2 is None else float(gate_chi2),
            hold_heading,
        )
