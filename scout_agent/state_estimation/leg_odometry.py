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

from scout_agent.robot.vectors import cross


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
    normal; all in the base frame."""
    rc = feet_b - foot_radius * normal_b
    z = -cross(gyro, rc) - feet_vel_b + foot_radius * cross(foot_omega_b, normal_b)
    return z, rc
