"""The robot's low-level interface: joint commands in (`LowCmd`), sensor readings out (`LowState`).

This is the seam between the hardware and the robot's software, modelled on a real Aliengo's low-level
interface (Unitree `unitree_legged_sdk`: the robot's computer sends a `LowCmd` and receives a `LowState` over
UDP). The simulated Aliengo (`scout_agent.sim.aliengo.SimulatedAliengo`) takes a `LowCmd` and gives a
`LowState` every control tick; the robot's software (`scout_agent.onboard`) takes a `LowState` and gives a
`LowCmd`. Neither side imports the other: both import this module, `scout_agent.signals` and the robot's
description (`scout_agent.robot`). Ground truth is not here: the simulator offers it on a separate evaluation
channel (`SimulatedAliengo.truth`).

Per joint, `LowCmd` carries what the SDK's `MotorCmd` does (q, dq, Kp, Kd, tau): the motor driver applies
τ = τ_ff + Kp (q_des − q) + Kd (dq_des − dq) at its servo rate. `LowState` carries what `LowState` does — the
IMU (accelerometer, gyroscope, temperature), each motor's q, dq and estimated torque, the 1-D foot force
sensors, a time stamp (the SDK's `tick`) — with three differences a newcomer should know:
- the IMU's two vectors are the mean of the 500 Hz samples over the control tick (the IMU's output filter) and
  q, dq, τ are the tick's last driver samples: the software runs at the control rate (100 Hz);
- `joint_energy_j` is the joint work the motor drivers integrate at their servo rate from their own current
  and velocity measurements (a real driver's power telemetry; the SDK has no such field), because integrating
  it once per control tick misses ≈ 17 % of the work (`sim/sensors/joints.py`);
- `fresh` is False when the packet was lost (the values are the previous packet's; the software knows, as a
  real receiver does from the SDK's counter).
Legs in `signals.LEG_NAMES` order, joints in `signals.JOINT_NAMES` order.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np


class LowCmd(NamedTuple):
    """One control tick's command to the 12 joint drivers (each field (12,), `JOINT_NAMES` order)."""

    q_des: np.ndarray  # desired joint angle [rad]
    dq_des: np.ndarray  # desired joint velocity [rad/s]
    kp: np.ndarray  # position gain [N·m/rad]
    kd: np.ndarray  # velocity gain [N·m·s/rad]
    tau_ff: np.ndarray  # feed-forward torque [N·m]


class LowState(NamedTuple):
    """One control tick's readings, as the robot's computer receives them."""

    imu_acc: np.ndarray  # (3,) accelerometer specific force, IMU frame ≈ base frame, tick mean [m/s²]
    imu_gyro: np.ndarray  # (3,) gyroscope angular rate, tick mean [rad/s]
    q: np.ndarray  # (12,) joint encoder angles at the tick's end [rad]
    dq: np.ndarray  # (12,) driver joint velocities at the tick's end [rad/s]
    tau_est: np.ndarray  # (12,) joint torques from motor current at the tick's end [N·m]
    joint_energy_j: float  # Σ|τ·θ̇|dt over the tick's servo steps, from the drivers' measurements [J]
    foot_force: np.ndarray  # (4,) 1-D foot force sensor readings [N]
    stamp_s: float = math.nan  # the reading's time stamp on the robot's clock [s] (NaN: use the loop period)
    fresh: bool = True  # False: the packet was lost, these are the previous packet's values
    imu_temp_c: float = math.nan  # the IMU's on-chip thermometer [°C]


__all__ = ["LowCmd", "LowState"]
