"""`SensorSuite`: one robot's sensors, sampled every physics step, delivered once per control tick.

The simulator hands the suite the exact readings of the k physics steps of one control tick (`TrueBlock`);
the suite returns what the robot's drivers and IMU report (`SensorTick`). This is the only place where the
simulator's exact state enters the robot's side.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from scout_agent.robot import kinematics as K

from .foot_pressure import ContactConfig, FootContactSensors, leg_forces_from_torques
from .imu import ImuConfig, ImuModel
from .joints import JointSensorConfig, JointSensors

_ZERO12 = np.zeros(12)


@dataclass(frozen=True)
class SensorConfig:
    imu: ImuConfig = field(default_factory=ImuConfig)
    joints: JointSensorConfig = field(default_factory=JointSensorConfig)
    contact: ContactConfig = field(default_factory=ContactConfig)
    seed: int = 0


class TrueBlock(NamedTuple):
    """Exact values over the k physics steps of one tick (what the physical sensors sense)."""

    dt: float  # physics step [s]
    acc: np.ndarray  # (k, 3) specific force at the IMU site, base frame [m/s²]
    gyro: np.ndarray  # (k, 3) angular velocity, base frame [rad/s]
    q: np.ndarray  # (k, 12) joint angles [rad]
    tau: np.ndarray  # (k, 12) actuator joint torques [N·m]
    foot_normal_n: np.ndarray  # (4,) normal ground force on each foot at the tick's end [N]


class SensorTick(NamedTuple):
    """What the robot's sensors report for one control tick."""

    imu_acc: np.ndarray  # (3,) mean specific force over the tick, base frame [m/s²]
    imu_gyro: np.ndarray  # (3,) mean angular velocity over the tick, base frame [rad/s]
    q: np.ndarray  # (12,) encoder angles at the tick's end [rad]
    dq: np.ndarray  # (12,) driver joint velocities at the tick's end [rad/s]
    tau: np.ndarray  # (12,) torques from motor current at the tick's end [N·m]
    joint_energy_j: float  # Σ|τ·θ̇|dt over the tick's physics steps, from the measured values [J]
    foot_pressure: np.ndarray  # (4,) foot pressure readings [N]
    contact: np.ndarray  # (4,) bool contact flags (pressure or torque based, with hysteresis)


class SensorSuite:
    def __init__(self, config: SensorConfig, q0: np.ndarray) -> None:
        self.config = config
        rng = np.random.default_rng([config.seed, 0x5E45])
        self.imu = ImuModel(config.imu, rng)
        self.joints = JointSensors(config.joints, rng, q0)
        self.feet = FootContactSensors(config.contact, rng)

    def read(self, block: TrueBlock) -> SensorTick:
        acc, gyro = self.imu.sample(block.acc, block.gyro, block.dt)
        q, dq, tau, energy = self.joints.sample(block.q, block.tau, block.dt)
        pressure = self.feet.reading(block.foot_normal_n)
        if self.config.contact.source == "torques":
            fb = leg_forces_from_torques(K.jacobians(q[-1]), tau[-1], _ZERO12)
            contact = self.feet.flags(fb[:, 2])  # the ground pushes a stance foot up the base z axis
        else:
            contact = self.feet.flags(pressure)
        return SensorTick(
            acc.mean(axis=0), gyro.mean(axis=0), q[-1], dq[-1], tau[-1], energy, pressure, contact
        )
