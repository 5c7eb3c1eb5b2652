"""Leg odometry: the base velocity each stance foot implies, from encoders and the gyro (base frame).

A stance foot's contact point is at rest (no slip). With the foot sphere centre r (base frame, forward
kinematics), its velocity u = J q̇ relative to the base, the foot's angular velocity ω_rel relative to the base,
the gyro ω_m and the contact point r' = r − ρ n (ρ the foot radius, n the ground normal in the base frame),
rolling without slip gives

    v_base = −ω × r' − u + ρ ω_rel × n,   ω = ω_m − bg,

so the measurement z = −ω_m × r' − u + ρ ω_rel × n equals Rᵀ v + r' × bg (ekf.py). The rolling term matters:
a ball foot's centre moves ≈ 7 mm per stance as the calf turns, ≈ 9 % of the base's travel per stance if ignored.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels import velocity_rows_many


@njit(cache=True, nogil=True)
def stance_velocity_measurements(
    feet_b: np.ndarray,
    feet_vel_b: np.ndarray,
    foot_omega_b: np.ndarray,
    gyro: np.ndarray,
    normal_b: np.ndarray,
    foot_radius: float,
) -> tuple[np.ndarray, np.ndarray]:
    """For all four feet: (z (4, 3) base velocity measurements [m/s], r' (4, 3) contact points [m]).
    feet_b: foot sphere centres; feet_vel_b: their velocities relative to the base; foot_omega_b: feet's
    angular velocities relative to the base; gyro: (3,) measured angular velocity; normal_b: (3,) unit ground
    normal; all in the base frame. Compiled (numba): the estimator calls it every tick."""
    k = feet_b.shape[0]
    rc = np.empty((k, 3))
    z = np.empty((k, 3))
    g0, g1, g2 = gyro[0], gyro[1], gyro[2]
    n0, n1, n2 = normal_b[0], normal_b[1], normal_b[2]
    for i in range(k):
        r0 = feet_b[i, 0] - foot_radius * n0
        r1 = feet_b[i, 1] - foot_radius * n1
        r2 = feet_b[i, 2] - foot_radius * n2
        rc[i, 0], rc[i, 1], rc[i, 2] = r0, r1, r2
        w0, w1, w2 = foot_omega_b[i, 0], foot_omega_b[i, 1], foot_omega_b[i, 2]
        z[i, 0] = -(g1 * r2 - g2 * r1) - feet_vel_b[i, 0] + foot_radius * (w1 * n2 - w2 * n1)
        z[i, 1] = -(g2 * r0 - g0 * r2) - feet_vel_b[i, 1] + foot_radius * (w2 * n0 - w0 * n2)
        z[i, 2] = -(g0 * r1 - g1 * r0) - feet_vel_b[i, 2] + foot_radius * (w0 * n1 - w1 * n0)
    return z, rc


@njit(cache=True, nogil=True)
def odometry_rows(
    use: np.ndarray,
    R: np.ndarray,
    v: np.ndarray,
    bg: np.ndarray,
    feet: tuple[np.ndarray, np.ndarray, np.ndarray],
    gyro: np.ndarray,
    normal_b: np.ndarray,
    foot_radius: float,
    climb_bias: float = 0.0,
    excess: float = 0.0,
    crab_rad: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The filter's velocity update from the feet in `use` (4,) bool: stacked residuals z − h (3k,) and the
    Jacobian H (3k, 15): `stance_velocity_measurements` of `feet` (positions, velocities, angular velocities,
    base frame) with the ground normal `normal_b` (3,), base frame, less the EKF's predicted measurement at the
    estimate R, v, bg (`kernels.velocity_rows_many`). `climb_bias` [rad ≈ m/m]: the legs' calibrated climb
    (climb_calibration.py), turned back about the base y axis (z_z − c·z_x for small c). `excess` (share) and
    `crab_rad`: the legs' along-track excess and crab angle, calibrated on a surveyed course
    (`EstimatorConfig.odometry_calibration`): the horizontal part is scaled by 1 − excess and turned by the crab
    about the base z axis."""
    z, rc = stance_velocity_measurements(feet[0], feet[1], feet[2], gyro, normal_b, foot_radius)
    k = 0
    for i in range(4):
        k += use[i]
    rows = np.empty((k, 3))
    zu = np.empty((k, 3))
    cb, sb = np.cos(climb_bias), np.sin(climb_bias)
    gc, gs = (1.0 - excess) * np.cos(crab_rad), (1.0 - excess) * np.sin(crab_rad)
    m = 0
    for i in range(4):
        if use[i]:
            rows[m] = rc[i]
            zx = cb * z[i, 0] + sb * z[i, 2]
            zu[m, 0] = gc * zx - gs * z[i, 1]
            zu[m, 1] = gs * zx + gc * z[i, 1]
            zu[m, 2] = cb * z[i, 2] - sb * z[i, 0]
            m += 1
    h, H = velocity_rows_many(R, v, bg, rows)
    return (zu - h).reshape(3 * k), H
