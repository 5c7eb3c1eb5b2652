"""`ScoutSim`: MuJoCo physics, the robot's sensors and its onboard software (state estimator + trot controller),
one `(ProprioSample, GroundTruth)` per control tick.

Timing: physics at `dt` = 0.002 s; the controller every `decimation` physics steps (default 5 → 100 Hz),
while the joint PD servos act at every physics step inside MuJoCo. The sensor models
(`scout_agent.sensors`) sample the IMU, encoders and motor currents at every physics step (driver rate: the
joint energy is integrated there) and report once per tick; the state estimator
(`scout_agent.state_estimation`) runs once per tick on those readings only.

The robot's side reads nothing of the simulator's state: the controller balances on the state estimate, and
every field of `ProprioSample` is a sensor reading or the estimate (`state_source="estimate"`, the default).
`state_source="exact"` is an evaluation option: the controller and `ProprioSample.base` use the simulator's
exact base state instead (sensor readings stay modelled). `GroundTruth` is for evaluation only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import mujoco
import numpy as np

from scout_agent.control.controller import ControllerConfig, ControlOutput, RobotState, TrotController
from scout_agent.errors import ScoutConfigError
from scout_agent.robot import constants as C
from scout_agent.robot import kinematics as K
from scout_agent.sensors import SensorConfig, SensorSuite
from scout_agent.sensors.suite import TrueBlock, link_length_errors
from scout_agent.signals import LEG_NAMES, BaseState, GroundTruth, ProprioSample
from scout_agent.sim.friction import FrictionMap
from scout_agent.sim.scene import TERRAIN_GEOM, PhysicsConfig, build_scene
from scout_agent.sim.terrain import Terrain
from scout_agent.sim.truth import quat_to_mat, tick_truth
from scout_agent.state_estimation import EstimatorConfig, StateEstimator
from scout_agent.state_estimation.launch import HeightDatum, LaunchSurvey, initial_pose

STATE_SOURCES = ("estimate", "exact")


@dataclass(frozen=True)
class SimConfig:
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    state_source: str = "estimate"  # one of STATE_SOURCES; "exact" is an evaluation option
    launch: LaunchSurvey = field(default_factory=LaunchSurvey)  # the start the scout is given (launch.py)
    decimation: int = 5  # physics steps per control tick (100 Hz control; PD servos at 500 Hz)
    contact_threshold_n: float = 1.0  # [N]
    fall_tilt_deg: float = 60.0  # trunk tilt from vertical that counts as a fall
    fall_min_height_m: float = 0.12  # trunk origin above the terrain below which it counts as a fall
    settle_s: float = 0.5  # stand still before walking [s]

    def __post_init__(self) -> None:
        if self.state_source not in STATE_SOURCES:
            raise ScoutConfigError(
                f"state source {self.state_source!r} unknown; sources: {', '.join(STATE_SOURCES)}"
            )


def _ids_slice(ids: np.ndarray) -> slice:
    """The slice of consecutive ids (the model's actuators are declared in blocks of 12)."""
    lo = int(ids[0])
    if not np.array_equal(ids, np.arange(lo, lo + len(ids))):
        raise ValueError(f"actuator ids {ids.tolist()} are not consecutive")
    return slice(lo, lo + len(ids))


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    R = np.empty((3, 3))
    quat_to_mat(np.ascontiguousarray(q, dtype=float), R)
    return R


class ScoutSim:
    """One Aliengo on one terrain. `step()` advances one control tick and returns its records."""

    def __init__(
        self,
        terrain: Terrain,
        friction: FrictionMap | None = None,
        config: SimConfig = SimConfig(),
        start: tuple[float, float, float] | None = None,
        datum_sources: Sequence[tuple[str, HeightDatum]] = (),
    ) -> None:
        """`datum_sources`: where the scout may take its launch ground height (launch.py), tried in order."""
        self.terrain = terrain
        self.datum_sources = tuple(datum_sources)
        self.friction = friction or FrictionMap()
        self.config = config
        self.model = build_scene(terrain, config.physics)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.dt = m.opt.timestep
        self.control_dt = self.dt * config.decimation
        self._tau_ids = np.array([m.actuator(n).id for n in C.TAU_ACTUATORS])
        self._pd_ids = np.array([m.actuator(n).id for n in C.PD_ACTUATORS])
        self._foot_geoms = np.array([m.geom(n).id for n in C.FOOT_GEOMS])
        self._foot_bodies = m.geom_bodyid[self._foot_geoms]
        self._terrain_geom = m.geom(TERRAIN_GEOM).id
        self._trunk_geom = m.geom("trunk").id
        self._leg_of_geom = np.full(m.ngeom, -1)
        self._leg_of_geom[self._foot_geoms] = np.arange(4)
        # the simulated robot as built, not as designed (sensors/suite.py): IMU where it is mounted, and
        # thigh/calf lengths off the nominal ones the robot's software uses
        m.site_pos[m.site(C.IMU_SITE).id] = config.sensors.imu_offset_m
        dl = link_length_errors(config.sensors)
        for i, leg in enumerate(LEG_NAMES):
            m.body_pos[m.body(f"{leg}_calf").id, 2] -= dl[i, 0]
            m.body_pos[m.body(f"{leg}_foot").id, 2] -= dl[i, 1]
        acc_adr = m.sensor_adr[m.sensor("imu_acc").id]
        gyro_adr = m.sensor_adr[m.sensor("imu_gyro").id]
        self._touching = np.zeros(m.ngeom, bool)  # non-foot geoms on the ground (truth.foot_contacts)
        # per control tick: the physics steps' readings land in these blocks (one row per step), copied from
        # views of MjData/MjModel taken once (MuJoCo keeps their memory for the model's/data's lifetime)
        k = config.decimation
        self._blk_sensors = np.zeros((k, m.nsensordata))
        self._blk_acc = self._blk_sensors[:, acc_adr : acc_adr + 3]
        self._blk_gyro = self._blk_sensors[:, gyro_adr : gyro_adr + 3]
        self._blk_q = np.zeros((k, 12))
        self._blk_tau = np.zeros((k, 12))
        self._blk_dq = np.zeros((k, 12))
        d = self.data
        self._v_sensors, self._v_q, self._v_dq, self._v_tau = (
            d.sensordata,
            d.qpos[7:],
            d.qvel[6:],
            d.qfrc_actuator[6:],
        )
        self._v_ctrl_tau, self._v_ctrl_pd = (
            d.ctrl[_ids_slice(self._tau_ids)],
            d.ctrl[_ids_slice(self._pd_ids)],
        )
        pd = _ids_slice(self._pd_ids)
        self._v_kp, self._v_bias_p, self._v_bias_d = (
            m.actuator_gainprm[pd, 0],
            m.actuator_biasprm[pd, 1],
            m.actuator_biasprm[pd, 2],
        )
        self.controller = TrotController(config.controller)
        self.reset(start if start is not None else terrain.spawn)

    # ------------------------------------------------------------------------------------------ setup
    def reset(self, start: tuple[float, float, float]) -> None:
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        x, y, yaw = start
        feet = K.fk(C.HOME_Q)
        c, s = np.cos(yaw), np.sin(yaw)
        fx = x + c * feet[:, 0] - s * feet[:, 1]
        fy = y + s * feet[:, 0] + c * feet[:, 1]
        ground = float(np.max(self.terrain.height(fx, fy)))
        d.qpos[0:3] = (x, y, ground - feet[0, 2] + C.FOOT_RADIUS + 0.01)
        d.qpos[3:7] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
        d.qpos[7:] = C.HOME_Q
        mujoco.mj_forward(m, d)
        self.controller = TrotController(self.config.controller)
        self.controller.set_command(0.0, 0.0)
        self.t = 0.0
        self.last_output: ControlOutput | None = None
        self.fell = False
        self.fall_xy: tuple[float, float] | None = None
        self._start_robot_software(float(x), float(y), float(yaw), ground)
        self.energy_true_j = 0.0  # exact joint work since start, every physics step [J]
        self._state = RobotState(
            0.0,
            self.estimator.estimate.pos,
            self.estimator.estimate.R,
            np.zeros(3),
            np.zeros(3),
            C.HOME_Q.copy(),
            np.zeros(12),
            np.zeros(4, bool),
        )
        if self.config.state_source == "exact":
            self._state = self.exact_state()
        self._cp0 = np.full((4, 3), np.nan)
        self._swung = np.ones(4, bool)
        self._apply_friction()

    def _start_robot_software(self, x: float, y: float, yaw: float, ground_z: float) -> None:
        """Power on the robot's side where the lander put it (x, y, yaw; `ground_z` the exact ground height
        there): its sensors, and its state estimator from the start it is given. That start is a survey of
        (x, y, heading) with its error and a height datum that is never the simulator's, unless the comparison
        mode "exact" asks for it (state_estimation/launch.py)."""
        self.sensors = SensorSuite(self.config.sensors, C.HOME_Q)
        self.launch = initial_pose(
            (x, y, yaw),
            self.config.launch,
            np.random.default_rng([self.config.sensors.seed, 0x1A7C]),
            self.datum_sources,
            exact_ground_z=lambda: ground_z,
        )
        est_cfg = replace(self.config.estimator, imu_offset_m=self.config.sensors.imu_offset_m)
        self.estimator = StateEstimator(self.launch, C.HOME_Q, est_cfg)

    def _apply_friction(self) -> None:
        d = self.data
        feet = d.xpos[self._foot_bodies]
        self._mu_feet = self.friction.at_points(feet[:, 0], feet[:, 1])
        self.model.geom_friction[self._foot_geoms, 0] = self._mu_feet

    # ----------------------------------------------------------------------------------------- state
    def exact_state(self) -> RobotState:
        """The simulator's exact state, for evaluation (and the `exact` state source) only."""
        d = self.data
        return RobotState(
            self.t,
            d.qpos[0:3].copy(),
            _quat_to_mat(d.qpos[3:7]),
            d.qvel[0:3].copy(),
            d.qvel[3:6].copy(),
            d.qpos[7:].copy(),
            d.qvel[6:].copy(),
            np.zeros(4, bool),
        )

    def robot_state(self) -> RobotState:
        """The state the robot's software runs on: the estimate (sensor readings), or exact on request."""
        return self._state

    # ------------------------------------------------------------------------------------------ step
    def step(
        self, forward_speed: float | None = None, yaw_rate: float = 0.0
    ) -> tuple[ProprioSample, GroundTruth]:
        """Advance one control tick with the given command (None: keep the last one)."""
        m, d, cfg = self.model, self.data, self.config
        if forward_speed is not None:
            walk = self.t >= cfg.settle_s
            self.controller.set_command(forward_speed if walk else 0.0, yaw_rate if walk else 0.0)
        out = self.controller.step(self._state, self.control_dt)
        self._v_ctrl_tau[:] = out.tau_ff
        self._v_ctrl_pd[:] = out.q_des
        self._v_kp[:] = out.kp
        np.negative(out.kp, out=self._v_bias_p)
        np.negative(out.kd, out=self._v_bias_d)
        sens, q, tau, dq = self._blk_sensors, self._blk_q, self._blk_tau, self._blk_dq
        v_sens, v_q, v_tau, v_dq = self._v_sensors, self._v_q, self._v_tau, self._v_dq
        step = mujoco.mj_step
        for k in range(cfg.decimation):
            step(m, d)
            sens[k] = v_sens
            q[k] = v_q
            tau[k] = v_tau
            dq[k] = v_dq
        energy = 0.0
        for e in np.abs(tau * dq).sum(axis=1).tolist():  # step by step, as the drivers integrate it
            energy += e
        self.energy_true_j += energy * self.dt
        self.t += self.control_dt
        self._apply_friction()
        return self._records(out, energy * self.dt)

    def _mid_stance(self, out: ControlOutput) -> np.ndarray:
        """Legs the gait schedule has in the middle of their stance (`estimator.odometry_stance`)."""
        lo, hi = self.config.estimator.odometry_stance
        prog = self.controller.gait.stance_progress(out.phase)
        return out.stance_planned & (prog >= lo) & (prog <= hi)

    def _records(self, out: ControlOutput, energy_true_j: float) -> tuple[ProprioSample, GroundTruth]:
        d, cfg = self.data, self.config
        qpos = d.qpos.copy()
        con, tz = d.contact, self.terrain
        tt = tick_truth(
            (con.geom, con.efc_address, con.frame, con.pos, d.efc_force),
            self._leg_of_geom,
            self._terrain_geom,
            self._touching,
            qpos,
            tz.z,
            tz.x0,
            tz.y0,
            tz.res,
            cfg.contact_threshold_n,
            out.stance_planned,
            self._cp0,
            self._swung,
        )
        tick = self.sensors.read(
            TrueBlock(self.dt, self._blk_acc, self._blk_gyro, self._blk_q, self._blk_tau, tt.normal_force)
        )
        pos, quat = qpos[0:3], qpos[3:7]
        truth_base = BaseState(pos, quat, d.qvel[0:3].copy(), d.qvel[3:6].copy())
        if cfg.state_source == "exact":
            st = self.exact_state()
            self._state = RobotState(self.t, st.pos, st.R, st.vel, st.omega, tick.q, tick.dq, tick.contact)
            base = BaseState(pos.copy(), quat.copy(), truth_base.vel.copy(), truth_base.omega.copy())
        else:
            est = self.estimator.update(self.t, tick, self.control_dt, self._mid_stance(out))
            self._state = RobotState(
                self.t, est.pos, est.R, est.vel, est.omega, tick.q, tick.dq, tick.contact
            )
            base = BaseState(est.pos, est.quat, est.vel, est.omega)
        sample = ProprioSample(
            t=self.t,
            q=tick.q,
            dq=tick.dq,
            tau=tick.tau,
            contact=tick.contact,
            foot_pressure=tick.foot_pressure,
            joint_energy_j=tick.joint_energy_j,
            imu_acc=tick.imu_acc,
            imu_gyro=tick.imu_gyro,
            base=base,
            foot_pos_des_base=out.foot_pos_des_base,
            foot_vel_des_base=out.foot_vel_des_base,
            stance_planned=out.stance_planned,
            phase=out.phase,
        )
        truth = GroundTruth(
            t=self.t,
            base=truth_base,
            foot_pos_world=tt.feet,
            contact_point_world=tt.contact_point,
            stance_disp=tt.stance_disp,
            terrain_height_at_feet=tt.ground[:4],
            friction_at_feet=self._mu_feet.copy(),
            nonfoot_contacts=tt.n_nonfoot,
            contact=tt.contact,
            foot_force_world=tt.foot_force,
            joint_energy_j=energy_true_j,
            q=qpos[7:],
            dq=d.qvel[6:].copy(),
        )
        tilt = math.degrees(math.acos(min(max(float(tt.R[2, 2]), -1.0), 1.0)))
        clearance = float(pos[2] - tt.ground[4])
        trunk_touch = bool(self._touching[self._trunk_geom])
        if not self.fell and (tilt > cfg.fall_tilt_deg or clearance < cfg.fall_min_height_m or trunk_touch):
            self.fell = True
            self.fall_xy = (float(pos[0]), float(pos[1]))
        self.last_output = out
        return sample, truth
