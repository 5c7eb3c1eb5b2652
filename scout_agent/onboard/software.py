"""`OnboardSoftware`: the robot's software on one Aliengo — readings in, joint commands out.

Per control tick the loop (`scout_agent.loop`) hands it the hardware's `lowlevel.LowState` and takes back a
`lowlevel.LowCmd`; it never sees the simulator (it imports nothing of `scout_agent.sim`;
tests/scout_agent/test_structure.py checks it), so the same object could run on a real Aliengo's computer
behind `unitree_legged_sdk`. Inside, one tick:

1. `sense(state)`: the drivers make contact flags of the readings (`drivers.ContactDetector`), the state
   estimator (`scout_agent.state_estimation`) updates the base state from them, and the tick's record
   (`signals.ProprioSample`) is what the rest of the software — localizer, map estimators, path follower —
   reads;
2. `command(forward_speed, yaw_rate)`: the trot controller (`scout_agent.control`) turns the path follower's
   speed and turn rate and the current state into the joint drivers' targets and torques (`LowCmd`).

`take_exact_state` is the evaluation option `state_source="exact"` (`psrmap evaluate --state exact`): the loop
hands the simulator's exact base state in place of the estimate, for comparison runs only; a real robot has
no such input.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from scout_agent.control.controller import ControllerConfig, ControlOutput, RobotState, TrotController
from scout_agent.lowlevel import LowCmd, LowState
from scout_agent.onboard.drivers import ContactDetection, ContactDetector
from scout_agent.robot import constants as C
from scout_agent.signals import BaseState, ProprioSample
from scout_agent.state_estimation import EstimatorConfig, StateEstimator
from scout_agent.state_estimation.launch import LaunchPose

_ZERO12 = np.zeros(12)


@dataclass(frozen=True)
class OnboardConfig:
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    contact: ContactDetection = field(default_factory=ContactDetection)
    settle_s: float = 0.5  # stand still before walking [s]


class ExactBase(NamedTuple):
    """The simulator's exact base state, handed in by the loop for `state_source="exact"` (evaluation only)."""

    pos: np.ndarray  # (3,) world [m]
    quat: np.ndarray  # (4,) wxyz, world_R_base
    R: np.ndarray  # (3, 3) world_R_base
    vel: np.ndarray  # (3,) world [m/s]
    omega: np.ndarray  # (3,) base frame [rad/s]


class OnboardSoftware:
    """Drivers, state estimator and trot controller of one scout, started from its `launch` pose."""

    def __init__(
        self, launch: LaunchPose, control_dt: float, config: OnboardConfig = OnboardConfig()
    ) -> None:
        self.config = config
        self.control_dt = control_dt
        self.launch = launch
        self.t = 0.0  # the robot's clock [s]
        self.drivers = ContactDetector(config.contact)
        self.estimator = StateEstimator(launch, C.HOME_Q, config.estimator)
        self.controller = TrotController(config.controller)
        self.controller.set_command(0.0, 0.0)
        self.last_output: ControlOutput | None = None
        self.on_exact_state = False  # True once the loop hands it the simulator's state (evaluation only)
        self.state = RobotState(  # at power-on: the launch pose, the home posture, no reading yet
            0.0,
            self.estimator.estimate.pos,
            self.estimator.estimate.R,
            np.zeros(3),
            np.zeros(3),
            C.HOME_Q.copy(),
            np.zeros(12),
            np.zeros(4, bool),
        )

    # ------------------------------------------------------------------------------------------ control
    def command(self, forward_speed: float | None = None, yaw_rate: float = 0.0) -> LowCmd:
        """The joint command for the next control tick, walking at `forward_speed` [m/s] and turning at
        `yaw_rate` [rad/s] (None: keep the last command); it stands still for `settle_s` after power-on."""
        if forward_speed is not None:
            walk = self.t >= self.config.settle_s
            self.controller.set_command(forward_speed if walk else 0.0, yaw_rate if walk else 0.0)
        out = self.controller.step(self.state, self.control_dt)
        self.last_output = out
        return LowCmd(out.q_des, _ZERO12, out.kp, out.kd, out.tau_ff)  # tau_ff already holds kd·dq_des

    # -------------------------------------------------------------------------------------------- sense
    def sense(self, low_state: LowState, exact: ExactBase | None = None) -> ProprioSample:
        """One control tick's readings → the state the controller runs on next, and the tick's record.
        `exact` (evaluation only, `take_exact_state`) replaces the estimate by the simulator's base state."""
        out = self.last_output
        if out is None:
            raise RuntimeError("sense() before command(): the robot has not commanded a control tick")
        self.t += self.control_dt
        tick = self.drivers.read(low_state)
        if exact is not None:
            self.state = RobotState(
                self.t, exact.pos, exact.R, exact.vel, exact.omega, tick.q, tick.dq, tick.contact
            )
            base = BaseState(exact.pos.copy(), exact.quat.copy(), exact.vel.copy(), exact.omega.copy())
        else:
            est = self.estimator.update(
                self.t, tick, self.control_dt, self._mid_stance(out), standing=self.controller.standing
            )
            self.state = RobotState(self.t, est.pos, est.R, est.vel, est.omega, tick.q, tick.dq, tick.contact)
            base = BaseState(est.pos, est.quat, est.vel, est.omega)
        return ProprioSample(
            t=self.t,
            q=tick.q,
            dq=tick.dq,
            tau=tick.tau,
            contact=tick.contact,
            foot_pressure=tick.foot_pressure,
            joint_energy_j=tick.joint_energy_j,
            # at the base origin, as the estimator moved it (the IMU's lever arm removed: the estimators' GIA and
            # non-foot force compare it with the feet's forces); the raw reading when the estimate is not run
            imu_acc=tick.imu_acc if exact is not None else self.estimator.specific_force_base.copy(),
            imu_gyro=tick.imu_gyro,
            base=base,
            foot_pos_des_base=out.foot_pos_des_base,
            foot_vel_des_base=out.foot_vel_des_base,
            stance_planned=out.stance_planned,
            phase=out.phase,
            fresh=tick.fresh,
        )

    def take_exact_state(self, state: RobotState) -> None:
        """Evaluation only (`state_source="exact"`): run the controller on this state, not the estimate."""
        self.on_exact_state = True
        self.state = state

    def _mid_stance(self, out: ControlOutput) -> np.ndarray:
        """Legs the gait schedule has in the middle of their stance (`estimator.odometry_stance`)."""
        lo, hi = self.config.estimator.odometry_stance
        return self.controller.gait.mid_stance(out.phase, out.stance_planned, lo, hi)

    def position_sigma_m(self) -> float | None:
        """The horizontal position σ [m] the estimator gives itself (the larger axis of its x, y covariance);
        None when it runs on the exact state."""
        if self.on_exact_state:
            return None
        P = self.estimator.position_covariance()[:2, :2]
        return float(np.sqrt(max(float(np.linalg.eigvalsh(P)[-1]), 0.0)))


__all__ = ["ExactBase", "OnboardConfig", "OnboardSoftware"]
