"""What a scout knows each control tick (proprioception) and what only the simulator knows (ground truth).

`ProprioSample` is the robot's software's own record of a tick (`scout_agent.onboard.OnboardSoftware.sense`):
every field is a reading of the hardware's `lowlevel.LowState`, a flag the drivers made of one, the state
estimate (`scout_agent.state_estimation`) or the controller's plan; the localizer, the map estimators
(`scout_agent.estimators`) and the pilot read it. `GroundTruth` comes from the simulator's evaluation channel
(`scout_agent.sim.aliengo.SimulatedAliengo.truth`); evaluation reads it beside the sample, never mixed in. Both
sides import this module (it imports neither).

Conventions: legs in `LEG_NAMES` order, joints in `JOINT_NAMES` order (hip ab/ad, thigh, calf per leg);
quaternions are (w, x, y, z) and rotate base-frame vectors into the world (map) frame; the world frame is the
mission's map frame, z up, gravity along -z.

The three records are NamedTuples (immutable, like the frozen dataclasses they were): the loop builds them every
control tick, and a NamedTuple costs a third of a frozen dataclass to build (`benchmarks/loop_profile.py`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

LEG_NAMES: tuple[str, ...] = ("FL", "FR", "RL", "RR")
JOINT_NAMES: tuple[str, ...] = tuple(
    f"{leg}_{part}_joint" for leg in LEG_NAMES for part in ("hip", "thigh", "calf")
)


class BaseState(NamedTuple):
    """Pose and twist of the robot's base (trunk frame)."""

    pos: np.ndarray  # (3,) base origin in the world frame [m]
    quat: np.ndarray  # (4,) wxyz, world_R_base
    vel: np.ndarray  # (3,) linear velocity of the base origin, world frame [m/s]
    omega: np.ndarray  # (3,) angular velocity, base frame [rad/s]


class ProprioSample(NamedTuple):
    """What a real Aliengo knows at one control tick: its sensors' readings and its state estimate."""

    t: float  # scout clock [s]
    q: np.ndarray  # (12,) joint encoder angles [rad], JOINT_NAMES order
    dq: np.ndarray  # (12,) joint velocities as the motor drivers report them [rad/s]
    tau: np.ndarray  # (12,) joint torques from motor current [N·m]
    contact: np.ndarray  # (4,) bool, foot contact flags (foot pressure sensors with hysteresis, or torques)
    foot_pressure: np.ndarray  # (4,) 1-D foot pressure sensor readings [N]
    joint_energy_j: float  # Σ|τ·q̇|dt over this tick, integrated by the drivers at every physics step [J]
    imu_acc: np.ndarray  # (3,) accelerometer specific force at the base origin (lever arm removed), base frame, tick mean [m/s²]
    imu_gyro: np.ndarray  # (3,) gyroscope angular velocity, base frame, tick mean [rad/s]
    base: BaseState  # base state as the robot knows it: the state estimate (exact only with state "exact")
    foot_pos_des_base: np.ndarray  # (4, 3) controller's desired foot positions, base frame [m]
    foot_vel_des_base: np.ndarray  # (4, 3) controller's desired foot velocities, base frame [m/s]
    stance_planned: np.ndarray  # (4,) bool, the gait schedule puts the leg in stance
    phase: np.ndarray  # (4,) gait phase of each leg in [0, 1)
    fresh: bool = True  # False: the hardware's packet was lost and the readings repeat the last ones


class GroundTruth(NamedTuple):
    """What only the simulator knows, for evaluation. Never fed to the estimators."""

    t: float  # sim time [s]
    base: BaseState  # exact base state
    foot_pos_world: np.ndarray  # (4, 3) foot sphere centres, world frame [m]
    contact_point_world: np.ndarray  # (4, 3) foot contact points, world frame [m]; NaN rows in swing
    stance_disp: (
        np.ndarray
    )  # (4,) distance the contact point moved since the stance's first contact [m]; NaN in swing
    terrain_height_at_feet: np.ndarray  # (4,) exact terrain height under each foot [m]
    friction_at_feet: np.ndarray  # (4,) friction coefficient of the ground under each foot
    nonfoot_contacts: int  # number of robot geoms other than feet touching the ground
    contact: np.ndarray  # (4,) bool, foot normal force above the simulator's contact threshold
    foot_force_world: np.ndarray  # (4, 3) exact ground reaction force on each foot, world frame [N]
    joint_energy_j: float  # exact Σ|τ·q̇|dt over this tick at every physics step [J]
    q: np.ndarray  # (12,) exact joint angles [rad]
    dq: np.ndarray  # (12,) exact joint velocities [rad/s]
