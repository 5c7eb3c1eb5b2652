"""`ScoutSim`: MuJoCo physics + the trot controller, one `(ProprioSample, GroundTruth)` per control tick.

Timing: physics at `dt` = 0.002 s; the controller every `decimation` physics steps (default 5 → 100 Hz),
while the joint PD servos act at every physics step inside MuJoCo. A tick's joint state and base state are
those after the last physics step; contact forces, contact points and the IMU come from that step's
dynamics (one physics step, 2 ms, older), as a sensor's latest reading would.

Contact flags: the ground reaction on each foot (summed over the foot's contacts with the terrain, world
frame) has a component along the contact normal above `contact_threshold_n`, as a foot sensor reports.

Base state for the scout (`ProprioSample.base`): the simulator's truth degraded by noise — base velocity
+ white noise (σ = 0.03 m/s per axis) + a bias drawn once per run (norm 0.02 m/s, random direction); pose
and angular velocity exact (`NoiseConfig`). `GroundTruth.base` is always exact. The controller balances on
the exact state (a real robot's state estimator would be good enough for balance; the estimators are what
the noise is for), but the desired foot velocities it publishes (`foot_vel_des_base`) are recomputed with the
sample's base velocity, so no exact state leaks into `ProprioSample` (with exact ẋ_des the slip detector
would be circular).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np

from scout_agent.control.controller import ControllerConfig, ControlOutput, RobotState, TrotController
from scout_agent.robot import constants as C
from scout_agent.robot import kinematics as K
from scout_agent.signals import BaseState, GroundTruth, ProprioSample
from scout_agent.sim.friction import FrictionMap
from scout_agent.sim.scene import TERRAIN_GEOM, PhysicsConfig, build_scene
from scout_agent.sim.terrain import Terrain


@dataclass(frozen=True)
class NoiseConfig:
    vel_white_std: float = 0.03  # [m/s] per axis, per tick
    vel_bias: float = 0.02  # [m/s] norm of a constant bias, random direction per run
    seed: int = 0


@dataclass(frozen=True)
class SimConfig:
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    decimation: int = 5  # physics steps per control tick (100 Hz control; PD servos at 500 Hz)
    contact_threshold_n: float = 1.0  # [N]
    fall_tilt_deg: float = 60.0  # trunk tilt from vertical that counts as a fall
    fall_min_height_m: float = 0.12  # trunk origin above the terrain below which it counts as a fall
    settle_s: float = 0.5  # stand still before walking [s]


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


class ScoutSim:
    """One Aliengo on one terrain. `step()` advances one control tick and returns its records."""

    def __init__(self, terrain: Terrain, friction: FrictionMap | None = None, config: SimConfig = SimConfig(),
                 start: tuple[float, float, float] | None = None,
                 base_estimator: Callable[[ProprioSample], BaseState] | None = None) -> None:
        """`base_estimator`, if given, replaces the noisy-truth base state of every `ProprioSample` with its
        own estimate; it receives the sample (whose `base` is the noisy truth) and must not see `GroundTruth`."""
        self.terrain = terrain
        self.base_estimator = base_estimator
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
        self._terrain_geom = m.geom(TERRAIN_GEOM).id
        self._trunk_geom = m.geom("trunk").id
        self._leg_of_geom = np.full(m.ngeom, -1)
        self._leg_of_geom[self._foot_geoms] = np.arange(4)
        self._acc_adr = m.sensor_adr[m.sensor("imu_acc").id]
        self._gyro_adr = m.sensor_adr[m.sensor("imu_gyro").id]
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
        self.contact = np.zeros(4, bool)
        self.fell = False
        self.fall_xy: tuple[float, float] | None = None
        self._rng = np.random.default_rng(self.config.noise.seed)
        b = self._rng.normal(size=3)
        self._vel_bias = self.config.noise.vel_bias * b / np.linalg.norm(b)
        self._cp0 = np.full((4, 3), np.nan)
        self._swung = np.ones(4, bool)
        self._prev_out = None
        self._apply_friction()

    def _apply_friction(self) -> None:
        d = self.data
        feet = d.xpos[self.model.geom_bodyid[self._foot_geoms]]
        self._mu_feet = self.friction.at(feet[:, 0], feet[:, 1])
        self.model.geom_friction[self._foot_geoms, 0] = self._mu_feet

    # ----------------------------------------------------------------------------------------- state
    def robot_state(self) -> RobotState:
        d = self.data
        return RobotState(self.t, d.qpos[0:3].copy(), _quat_to_mat(d.qpos[3:7]), d.qvel[0:3].copy(),
                          d.qvel[3:6].copy(), d.qpos[7:].copy(), d.qvel[6:].copy(), self.contact.copy())

    def _contacts(self):
        """Per-foot summed ground force (4, 3) world, force-weighted contact point (4, 3), normal force (4,),
        and the number of non-foot robot geoms touching the terrain."""
        d = self.data
        forces = np.zeros((4, 3))
        points = np.zeros((4, 3))
        fn = np.zeros(4)
        ncon = d.ncon
        if ncon == 0:
            return forces, np.full((4, 3), np.nan), fn, 0, False
        con = d.contact
        geom = con.geom[:ncon]
        g1, g2 = geom[:, 0], geom[:, 1]
        adr = con.efc_address[:ncon]
        valid = adr >= 0
        efc = d.efc_force
        local = np.zeros((ncon, 3))
        local[valid] = np.stack([efc[adr[valid]], efc[adr[valid] + 1], efc[adr[valid] + 2]], axis=1)
        frame = con.frame[:ncon].reshape(ncon, 3, 3)
        world = np.einsum("ck,ckj->cj", local, frame)  # force of geom1 on geom2
        leg1, leg2 = self._leg_of_geom[g1], self._leg_of_geom[g2]
        nonfoot = set()
        for c in range(ncon):
            a, b = g1[c], g2[c]
            if a == self._terrain_geom or b == self._terrain_geom:
                other = b if a == self._terrain_geom else a
                leg = leg2[c] if a == self._terrain_geom else leg1[c]
                if leg >= 0:
                    sign = 1.0 if a == self._terrain_geom else -1.0
                    f = sign * world[c]
                    forces[leg] += f
                    w = max(local[c, 0], 0.0)
                    points[leg] += w * con.pos[c]
                    fn[leg] += local[c, 0]
                else:
                    nonfoot.add(int(other))
        with np.errstate(invalid="ignore", divide="ignore"):
            points = points / fn[:, None]
        points[fn <= 0] = np.nan
        return forces, points, fn, len(nonfoot), self._trunk_geom in nonfoot

    # ------------------------------------------------------------------------------------------ step
    def step(self, forward_speed: float | None = None, yaw_rate: float = 0.0) -> tuple[ProprioSample, GroundTruth]:
        """Advance one control tick with the given command (None: keep the last one)."""
        m, d, cfg = self.model, self.data, self.config
        if forward_speed is not None:
            walk = self.t >= cfg.settle_s
            self.controller.set_command(forward_speed if walk else 0.0, yaw_rate if walk else 0.0)
        state = self.robot_state()
        out = self.controller.step(state, self.control_dt)
        d.ctrl[self._tau_ids] = out.tau_ff
        d.ctrl[self._pd_ids] = out.q_des
        m.actuator_gainprm[self._pd_ids, 0] = out.kp
        m.actuator_biasprm[self._pd_ids, 1] = -out.kp
        m.actuator_biasprm[self._pd_ids, 2] = -out.kd
        mujoco.mj_step(m, d, nstep=cfg.decimation)
        self.t += self.control_dt
        self._apply_friction()
        return self._records(out)

    def _records(self, out: ControlOutput) -> tuple[ProprioSample, GroundTruth]:
        d, cfg = self.data, self.config
        forces, points, fn, n_nonfoot, trunk_touch = self._contacts()
        contact = fn > cfg.contact_threshold_n
        self.contact = contact
        pos = d.qpos[0:3].copy()
        quat = d.qpos[3:7].copy()
        R = _quat_to_mat(quat)
        vel = d.qvel[0:3].copy()
        omega = d.qvel[3:6].copy()
        q = d.qpos[7:].copy()
        feet_w = pos + K.fk(q) @ R.T
        xy = np.empty((2, 5))
        xy[:, :4] = feet_w[:, :2].T
        xy[:, 4] = pos[:2]
        ground = self.terrain.height(xy[0], xy[1])  # feet, base
        # stance displacement of the contact point since the stance's first contact
        for i in range(4):
            if not out.stance_planned[i]:
                self._swung[i] = True
            if contact[i] and self._swung[i]:
                self._cp0[i] = points[i]
                self._swung[i] = False
        disp = np.where(contact, np.linalg.norm(points - self._cp0, axis=1), np.nan)
        truth_base = BaseState(pos, quat, vel, omega)
        noisy_vel = vel + self._vel_bias + self._rng.normal(0.0, cfg.noise.vel_white_std, 3)
        base = BaseState(pos.copy(), quat.copy(), noisy_vel, omega.copy())
        sample = ProprioSample(
            t=self.t, q=q, dq=d.qvel[6:].copy(), tau=d.qfrc_actuator[6:].copy(), contact=contact,
            foot_force_world=forces, imu_acc=d.sensordata[self._acc_adr:self._acc_adr + 3].copy(),
            imu_gyro=d.sensordata[self._gyro_adr:self._gyro_adr + 3].copy(), base=base,
            foot_pos_des_base=out.foot_pos_des_base, foot_vel_des_base=out.foot_vel_des_base,
            stance_planned=out.stance_planned, phase=out.phase)
        if self.base_estimator is not None:
            sample = dataclasses.replace(sample, base=self.base_estimator(sample))
        # The controller balances on the exact state, but the desired foot velocities it publishes must be
        # those a controller using the robot's own base estimate would command: every desired foot velocity
        # relative to the base contains −R^T·v_base, so swap the exact v_base for the sample's.
        vel_err_b = (sample.base.vel - vel) @ R
        sample = dataclasses.replace(sample, foot_vel_des_base=out.foot_vel_des_base - vel_err_b)
        truth = GroundTruth(
            t=self.t, base=truth_base, foot_pos_world=feet_w,
            contact_point_world=np.where(contact[:, None], points, np.nan), stance_disp=disp,
            terrain_height_at_feet=ground[:4],
            friction_at_feet=self._mu_feet.copy(), nonfoot_contacts=n_nonfoot)
        tilt = np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0)))
        clearance = pos[2] - float(ground[4])
        if not self.fell and (tilt > cfg.fall_tilt_deg or clearance < cfg.fall_min_height_m or trunk_touch):
            self.fell = True
            self.fall_xy = (float(pos[0]), float(pos[1]))
        self.last_output = out
        return sample, truth

