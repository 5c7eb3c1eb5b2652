"""The loop that joins the simulated hardware and the robot's software, one control tick at a time.

    hardware = SimulatedAliengo(...)     # scout_agent.sim: physics, sensor models, ground truth
    robot = OnboardSoftware(...)         # scout_agent.onboard: drivers, state estimator, controller
    every tick:
        cmd = robot.command(v, w)        # LowCmd: per-joint q_des, dq_des, kp, kd, tau_ff
        hardware.write(cmd)              # one control tick of physics under it
        readings = hardware.read()       # LowState: IMU, joint q/dq/tau, foot force, stamp
        sample = robot.sense(readings)   # ProprioSample: the readings and the state estimate
        truth = hardware.truth(...)      # GroundTruth: evaluation only, never handed to the robot

On the real robot the same cycle reads `state = sdk.read(); cmd = robot.step(state); sdk.write(cmd)`. Here it is
written from the command on, with the robot's tick split at its record: between `sense` (readings → the tick's
`ProprioSample`) and the next `command`, the run (`run.py`) lets the localizer, the map estimators, evaluation and
the pilot see the record — the pilot's speed and turn rate are the `v, w` of the next command. This is the only
module (with `run.py`, which walks a path with it) that imports both sides; on a real Aliengo the same
`OnboardSoftware` would talk to `unitree_legged_sdk` instead of `SimulatedAliengo`.

Two things cross from the simulator to the robot here, both named and both for evaluation or set-up only:
- the launch: the lander's survey of where it put the robot (`state_estimation.launch.initial_pose`, given the
  true pose and adding the survey's error; the exact ground height only in the comparison mode
  `--launch exact`);
- `state_source="exact"` (`--state exact`, comparison runs only): the loop hands the truth channel's base state
  to the robot (`OnboardSoftware.take_exact_state`), which then runs its controller on it instead of its estimate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from scout_agent.control.controller import ControllerConfig, RobotState
from scout_agent.errors import ScoutConfigError
from scout_agent.onboard.drivers import ContactDetection
from scout_agent.onboard.software import ExactBase, OnboardConfig, OnboardSoftware
from scout_agent.signals import BaseState, GroundTruth, ProprioSample
from scout_agent.sim.aliengo import HardwareConfig, SimulatedAliengo
from scout_agent.sim.friction import FrictionMap
from scout_agent.sim.scene import PhysicsConfig
from scout_agent.sim.sensors import SensorConfig
from scout_agent.sim.terrain import Terrain
from scout_agent.sim.truth import quat_to_mat
from scout_agent.state_estimation import EstimatorConfig
from scout_agent.state_estimation.launch import HeightDatum, LaunchPose, LaunchSurvey, initial_pose

STATE_SOURCES = ("estimate", "exact")


@dataclass(frozen=True)
class SimConfig:
    """One simulated scout: its hardware (`hardware()`), its software (`onboard()`), and how they are joined."""

    physics: PhysicsConfig = field(default_factory=PhysicsConfig)  # hardware
    controller: ControllerConfig = field(default_factory=ControllerConfig)  # software
    sensors: SensorConfig = field(default_factory=SensorConfig)  # hardware
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)  # software
    contact: ContactDetection = field(default_factory=ContactDetection)  # software: contact flags
    state_source: str = "estimate"  # one of STATE_SOURCES; "exact" is an evaluation option
    launch: LaunchSurvey = field(default_factory=LaunchSurvey)  # the start the scout is given (launch.py)
    decimation: int = 5  # physics steps per control tick (100 Hz control; PD servos at 500 Hz)
    contact_threshold_n: float = 1.0  # [N] ground truth's contact flag
    fall_tilt_deg: float = 60.0  # trunk tilt from vertical that counts as a fall
    fall_min_height_m: float = 0.12  # trunk origin above the terrain below which it counts as a fall
    settle_s: float = 0.5  # stand still before walking [s]

    def __post_init__(self) -> None:
        if self.state_source not in STATE_SOURCES:
            raise ScoutConfigError(
                f"state source {self.state_source!r} unknown; sources: {', '.join(STATE_SOURCES)}"
            )

    def hardware(self) -> HardwareConfig:
        return HardwareConfig(
            self.physics,
            self.sensors,
            self.decimation,
            self.contact_threshold_n,
            self.fall_tilt_deg,
            self.fall_min_height_m,
        )

    def onboard(self) -> OnboardConfig:
        """The software's settings; the estimator takes the IMU's mounting offset from the robot's CAD (the
        sensor profile's `imu_offset_m`, where the simulated IMU sits)."""
        est = replace(self.estimator, imu_offset_m=self.sensors.imu_offset_m)
        return OnboardConfig(self.controller, est, self.contact, self.settle_s)


class SimulatedScout:
    """A `SimulatedAliengo` and the `OnboardSoftware` on it, stepped together: `step(v, w)` runs one control
    tick (module docstring) and returns the tick's `(ProprioSample, GroundTruth)`."""

    def __init__(
        self,
        terrain: Terrain,
        friction: FrictionMap | None = None,
        config: SimConfig = SimConfig(),
        start: tuple[float, float, float] | None = None,
        datum_sources: Sequence[tuple[str, HeightDatum]] = (),
    ) -> None:
        """`datum_sources`: where the scout may take its launch ground height (launch.py), tried in order."""
        self.config = config
        self.hardware = SimulatedAliengo(terrain, friction, config.hardware(), start)
        self.control_dt = self.hardware.control_dt
        self.launch = self._survey_launch(datum_sources)
        self.robot = OnboardSoftware(self.launch, self.control_dt, config.onboard())
        self.exact = config.state_source == "exact"
        if self.exact:
            self.robot.take_exact_state(self._exact_state())

    def _survey_launch(self, datum_sources: Sequence[tuple[str, HeightDatum]]) -> LaunchPose:
        """The lander's survey of where it put the robot, with its error (a start that is never the
        simulator's, unless the comparison mode "exact" asks for it: state_estimation/launch.py)."""
        hw, cfg = self.hardware, self.config
        ground_z = hw.start_ground_z
        return initial_pose(
            hw.start,
            cfg.launch,
            np.random.default_rng([cfg.sensors.seed, 0x1A7C]),
            datum_sources,
            exact_ground_z=lambda: ground_z,
        )

    @property
    def t(self) -> float:
        """Simulated time [s]."""
        return self.hardware.t

    @property
    def fell(self) -> bool:
        return self.hardware.fell

    def step(
        self, forward_speed: float | None = None, yaw_rate: float = 0.0
    ) -> tuple[ProprioSample, GroundTruth]:
        """One control tick: command → physics → readings → estimate, and the tick's ground truth beside it."""
        hardware, robot = self.hardware, self.robot
        hardware.write(robot.command(forward_speed, yaw_rate))
        readings = hardware.read()
        stance_planned = (
            robot.last_output.stance_planned if robot.last_output is not None else np.zeros(4, bool)
        )
        truth = hardware.truth(stance_planned)
        if self.exact:  # evaluation only: the robot runs on the simulator's state
            sample = robot.sense(readings, _exact_base(truth.base))
        else:
            sample = robot.sense(readings)
        return sample, truth

    # --------------------------------------------------------- state_source "exact": evaluation only
    def _exact_state(self) -> RobotState:
        """The simulator's exact state at power-on, before the first tick's truth (joints too: no reading yet)."""
        d = self.hardware.data
        b = _exact_base(
            BaseState(d.qpos[0:3].copy(), d.qpos[3:7].copy(), d.qvel[0:3].copy(), d.qvel[3:6].copy())
        )
        return RobotState(
            self.t, b.pos, b.R, b.vel, b.omega, d.qpos[7:].copy(), d.qvel[6:].copy(), np.zeros(4, bool)
        )


def _exact_base(base: BaseState) -> ExactBase:
    """The truth channel's base state as the robot takes it for `state_source="exact"` (evaluation only)."""
    return ExactBase(base.pos, base.quat, _rotation(base.quat), base.vel, base.omega)


def _rotation(quat: np.ndarray) -> np.ndarray:
    R = np.empty((3, 3))
    quat_to_mat(np.ascontiguousarray(quat, dtype=float), R)
    return R


__all__ = ["STATE_SOURCES", "SimConfig", "SimulatedScout"]
