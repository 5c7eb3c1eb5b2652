"""The robot's drivers: what its software makes of a `LowState` before the state estimator sees it.

The hardware reports raw readings (`scout_agent.lowlevel.LowState`); the foot contact flags are the first thing
the software computes from them, so they are made here, on the robot's side, and not in the sensor models
(`scout_agent.sim.sensors`), which only say what a real device reads:
- **pressure** (default): each foot's 1-D force reading turns contact on above `on_n` and off below `off_n`
  (hysteresis keeps the sensor's noise from flickering the flag);
- **torques** (`source="torques"`, no foot sensor at all): the ground force on each stance foot is estimated as
  f = −J⁻ᵀ (τ − τ_g) (`robot.statics.leg_forces_from_torques`, with the nominal leg model), and its component
  along the base's −z axis is thresholded with the same hysteresis. It ignores the leg's own inertia (small
  legs, slow trot), so swing accelerations can leave a few newtons of phantom force.
A lost packet (`LowState.fresh` False) repeats the previous packet's values; the flags are then held, not
recomputed (nothing new arrived).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from scout_agent.errors import ScoutConfigError
from scout_agent.lowlevel import LowState
from scout_agent.robot import kinematics as K
from scout_agent.robot.statics import leg_forces_from_torques

CONTACT_SOURCES = ("pressure", "torques")
_ZERO12 = np.zeros(12)


@dataclass(frozen=True)
class ContactDetection:
    source: str = "pressure"  # one of CONTACT_SOURCES
    on_n: float = 5.0  # contact turns on above this reading [N]
    off_n: float = 2.5  # ... and off below this one [N]

    def __post_init__(self) -> None:
        if self.source not in CONTACT_SOURCES:
            raise ScoutConfigError(
                f"contact source {self.source!r} unknown; sources: {', '.join(CONTACT_SOURCES)}"
            )
        if not self.off_n < self.on_n:
            raise ScoutConfigError(f"contact thresholds need off_n < on_n (got {self.off_n}, {self.on_n})")


class SensorTick(NamedTuple):
    """One control tick's readings as the state estimator takes them: the `LowState` and the contact flags."""

    imu_acc: np.ndarray  # (3,) mean specific force over the tick, base frame [m/s²]
    imu_gyro: np.ndarray  # (3,) mean angular velocity over the tick, base frame [rad/s]
    q: np.ndarray  # (12,) encoder angles at the tick's end [rad]
    dq: np.ndarray  # (12,) driver joint velocities at the tick's end [rad/s]
    tau: np.ndarray  # (12,) torques from motor current at the tick's end [N·m]
    joint_energy_j: float  # Σ|τ·θ̇|dt over the tick's physics steps, from the measured values [J]
    foot_pressure: np.ndarray  # (4,) foot pressure readings [N]
    contact: np.ndarray  # (4,) bool contact flags (pressure or torque based, with hysteresis)
    stamp_s: float = math.nan  # the reading's time stamp on the robot's clock [s] (NaN: use the loop period)
    fresh: bool = True  # False: the packet was lost, these are the previous tick's values
    imu_temp_c: float = math.nan  # the IMU's on-chip thermometer [°C]


class ContactDetector:
    """`read(state)` → the tick's `SensorTick`: the readings with contact flags (module docstring)."""

    def __init__(self, config: ContactDetection = ContactDetection()) -> None:
        self.config = config
        self.contact = np.zeros(4, bool)

    def flags(self, force_n: np.ndarray) -> np.ndarray:
        """Contact flags from per-foot forces [N] (hysteresis on this detector's state)."""
        c = self.config
        _hysteresis(np.asarray(force_n, dtype=float), c.off_n, c.on_n, self.contact)
        return self.contact.copy()

    def read(self, state: LowState) -> SensorTick:
        if not state.fresh:
            contact = self.contact.copy()
        elif self.config.source == "torques":
            fb = leg_forces_from_torques(K.jacobians(state.q), state.tau_est, _ZERO12)
            contact = self.flags(fb[:, 2])  # the ground pushes a stance foot up the base z axis
        else:
            contact = self.flags(state.foot_force)
        return SensorTick(
            state.imu_acc,
            state.imu_gyro,
            state.q,
            state.dq,
            state.tau_est,
            state.joint_energy_j,
            state.foot_force,
            contact,
            state.stamp_s,
            state.fresh,
            state.imu_temp_c,
        )


@njit(cache=True, nogil=True)
def _hysteresis(force_n: np.ndarray, off_n: float, on_n: float, contact: np.ndarray) -> None:
    """Contact flags in place: stay on above `off_n`, turn on above `on_n`."""
    for i in range(contact.shape[0]):
        contact[i] = force_n[i] > off_n if contact[i] else force_n[i] > on_n


__all__ = ["CONTACT_SOURCES", "ContactDetection", "ContactDetector", "SensorTick"]
