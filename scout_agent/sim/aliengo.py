"""`SimulatedAliengo`: the simulated hardware — one Aliengo on one terrain, offering what the real robot offers.

Out: sensor readings (`read()` → `lowlevel.LowState`); in: joint commands (`write(lowlevel.LowCmd)`); and,
unlike the real robot, ground truth on a separate evaluation channel (`truth()` → `signals.GroundTruth`, plus
`fell`, `fall_xy`, `energy_true_j` and MuJoCo's `model`/`data`). Nothing here imports the robot's software
(`scout_agent.onboard`, `control`, `state_estimation`, …; tests/scout_agent/test_structure.py checks it): the
loop that joins the two is `scout_agent.loop`.

Timing: physics at `dt` = 0.002 s; one `write` runs `decimation` physics steps (default 5 → a 100 Hz control
tick) under the command, the joint PD servos acting at every physics step inside MuJoCo (τ = τ_ff +
Kp (q_des − q) + Kd (dq_des − dq), as a Unitree motor driver applies a `LowCmd`). The sensor models
(`sim.sensors`) sample the IMU, encoders and motor currents at every physics step (driver rate: the joint energy
is integrated there) and report once per tick: the `LowState` that `read()` returns until the next `write`.

The robot as built, not as designed (`sim/sensors/suite.py`): its IMU site sits where the sensor profile mounts
it and its thigh/calf lengths are off the nominal ones the robot's software uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
from numba import njit

from scout_agent.ccall import c_function, ccall_void, package_library
from scout_agent.lowlevel import LowCmd, LowState
from scout_agent.robot import constants as C
from scout_agent.robot import kinematics as K
from scout_agent.signals import LEG_NAMES, BaseState, GroundTruth
from scout_agent.sim.friction import FrictionMap
from scout_agent.sim.scene import TERRAIN_GEOM, PhysicsConfig, build_scene
from scout_agent.sim.sensors import SensorConfig, SensorSuite
from scout_agent.sim.sensors.suite import TrueBlock, link_length_errors
from scout_agent.sim.terrain import Terrain
from scout_agent.sim.truth import TickTruth, stance_displacement, tick_truth_into

# MuJoCo's `mj_step` in the library its Python bindings loaded: the control tick's physics steps and the copies of
# their readings run in one compiled call (`_physics_tick`) instead of five binding calls and twenty numpy copies
_MJ_STEP = c_function(package_library(Path(mujoco.__file__).parent, "libmujoco"), "mj_step")


@dataclass(frozen=True)
class HardwareConfig:
    """The simulated robot and its world's physics (the robot's software is configured apart: `onboard`)."""

    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    decimation: int = 5  # physics steps per control tick (100 Hz control; PD servos at 500 Hz)
    contact_threshold_n: float = 1.0  # [N] ground truth's contact flag
    fall_tilt_deg: float = 60.0  # trunk tilt from vertical that counts as a fall
    fall_min_height_m: float = 0.12  # trunk origin above the terrain below which it counts as a fall


def _ids_slice(ids: np.ndarray, step: int = 1) -> slice:
    """The slice of evenly spaced ids (the model's actuators are declared in blocks of 12, its legs' geoms in
    blocks of the same length)."""
    lo = int(ids[0])
    if not np.array_equal(ids, np.arange(lo, lo + step * len(ids), step)):
        raise ValueError(f"ids {ids.tolist()} are not evenly spaced by {step}")
    return slice(lo, lo + step * (len(ids) - 1) + 1, step)


class SimulatedAliengo:
    """One Aliengo on one terrain: `write(cmd)` runs one control tick of physics, `read()` its readings,
    `truth(stance_planned)` its ground truth (evaluation only)."""

    def __init__(
        self,
        terrain: Terrain,
        friction: FrictionMap | None = None,
        config: HardwareConfig = HardwareConfig(),
        start: tuple[float, float, float] | None = None,
    ) -> None:
        self.terrain = terrain
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
        # the feet's friction in MuJoCo's geom table, a view set every tick (a view: not a fancy-index write)
        foot_step = int(self._foot_geoms[1] - self._foot_geoms[0])
        self._v_foot_mu = m.geom_friction[_ids_slice(self._foot_geoms, foot_step), 0]
        # the simulated robot as built, not as designed (sensors/suite.py): IMU where it is mounted, and
        # thigh/calf lengths off the nominal ones the robot's software uses
        imu = m.site(C.IMU_SITE).id
        m.site_pos[imu] = config.sensors.imu_offset_m
        # the compiler flagged the URDF's origin site as sharing the trunk's frame, and MuJoCo then copies the
        # trunk's pose to it whatever `site_pos` says: clear the flag, or the IMU never leaves the origin
        m.site_sameframe[imu] = 0
        dl = link_length_errors(config.sensors)
        for i, leg in enumerate(LEG_NAMES):
            m.body_pos[m.body(f"{leg}_calf").id, 2] -= dl[i, 0]
            m.body_pos[m.body(f"{leg}_foot").id, 2] -= dl[i, 1]
        acc_adr = m.sensor_adr[m.sensor("imu_acc").id]
        gyro_adr = m.sensor_adr[m.sensor("imu_gyro").id]
        self._touching = np.zeros(m.ngeom, bool)  # non-foot geoms on the ground (truth.foot_contacts)
        self._normal_force, self._R = np.empty(4), np.empty((3, 3))  # the tick's truth, used within it
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
        # `_physics_tick`'s views and blocks, in its order
        self._v_controls = (self._v_ctrl_tau, self._v_ctrl_pd, self._v_kp, self._v_bias_p, self._v_bias_d)
        self._v_readings = (self._v_sensors, self._v_q, self._v_tau, self._v_dq)
        self._blocks = (self._blk_sensors, self._blk_q, self._blk_tau, self._blk_dq)
        self.reset(start if start is not None else terrain.spawn)

    # ------------------------------------------------------------------------------------------ setup
    def reset(self, start: tuple[float, float, float]) -> None:
        """Put the robot down at `start` (x, y, yaw) in the home posture, a centimetre above the ground, and
        power its sensors on (`read()` has nothing until the first `write`)."""
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
        self.start = (float(x), float(y), float(yaw))  # where the lander put it (truth)
        self.start_ground_z = ground  # the exact ground height there (truth; the "exact" launch only)
        self.t = 0.0
        self.fell = False
        self.fall_xy: tuple[float, float] | None = None
        self.sensors = SensorSuite(self.config.sensors, C.HOME_Q)
        self.energy_true_j = 0.0  # exact joint work since start, every physics step [J]
        self._energy_tick_j = 0.0
        self._low_state: LowState | None = None
        self._tt: TickTruth | None = None
        self._cp0 = np.full((4, 3), np.nan)
        self._swung = np.ones(4, bool)
        self._mu_feet = np.empty(4)  # friction under each foot, this tick (truth)
        self._apply_friction()

    def _apply_friction(self) -> None:
        self.friction.under_bodies(self.data.xpos, self._foot_bodies, self._mu_feet)
        self._v_foot_mu[:] = self._mu_feet

    # ------------------------------------------------------------------------------ the robot's interface
    def write(self, cmd: LowCmd) -> None:
        """Apply `cmd` to the joint drivers and run one control tick of physics under it; the sensors sample
        it, and `read()` then returns their `LowState`."""
        m, d, cfg = self.model, self.data, self.config
        # the drivers' command into the actuators, `decimation` physics steps, each step's readings copied into
        # the blocks, and the exact joint work Σ|τ·q̇|·dt step by step, as the drivers integrate it
        self._energy_tick_j = self.dt * _physics_tick(
            _MJ_STEP,
            m._address,
            d._address,
            cfg.decimation,
            (cmd.q_des, cmd.dq_des, cmd.kp, cmd.kd, cmd.tau_ff),
            self._v_controls,
            self._v_readings,
            self._blocks,
        )
        self.energy_true_j += self._energy_tick_j
        self.t += self.control_dt
        self._apply_friction()
        con, tz = d.contact, self.terrain
        inputs = (
            (con.geom, con.efc_address, con.frame, con.pos, d.efc_force),
            self._leg_of_geom,
            self._terrain_geom,
            self._touching,
            d.qpos,
            tz.z,
            tz.x0,
            tz.y0,
            tz.res,
            cfg.contact_threshold_n,
        )
        self._tt = tt = tick_truth_into(inputs, self._normal_force, self._R)
        self._low_state = self.sensors.read(
            TrueBlock(self.dt, self._blk_acc, self._blk_gyro, self._blk_q, self._blk_tau, tt.normal_force)
        )
        self._check_fall(tt)

    def read(self) -> LowState:
        """The sensors' readings of the last control tick (what the real robot's UDP packet carries)."""
        if self._low_state is None:
            raise RuntimeError("no reading before the first write: the robot has not run a control tick")
        return self._low_state

    # ------------------------------------------------------------------------- the evaluation channel
    def truth(self, stance_planned: np.ndarray) -> GroundTruth:
        """The last control tick's ground truth, for evaluation only: call once per tick. `stance_planned`
        (4,) is the gait's planned stance, handed in by the evaluation loop: it delimits the stances over
        which `GroundTruth.stance_disp` measures each foot's contact-point travel."""
        tt, d = self._tt, self.data
        if tt is None:
            raise RuntimeError("no ground truth before the first write")
        disp = np.empty(4)
        stance_displacement(stance_planned, tt.contact, tt.contact_point, self._cp0, self._swung, disp)
        qpos, qvel = d.qpos.copy(), d.qvel.copy()  # fresh copies; the record's fields are views of them
        return GroundTruth(
            t=self.t,
            base=BaseState(qpos[0:3], qpos[3:7], qvel[0:3], qvel[3:6]),
            foot_pos_world=tt.feet,
            contact_point_world=tt.contact_point,
            stance_disp=disp,
            terrain_height_at_feet=tt.ground[:4],
            friction_at_feet=self._mu_feet.copy(),
            nonfoot_contacts=tt.n_nonfoot,
            contact=tt.contact,
            foot_force_world=tt.foot_force,
            joint_energy_j=self._energy_tick_j,
            q=qpos[7:],
            dq=qvel[6:],
        )

    def _check_fall(self, tt: TickTruth) -> None:
        cfg, pos = self.config, self.data.qpos[0:3]
        tilt = math.degrees(math.acos(min(max(float(tt.R[2, 2]), -1.0), 1.0)))
        clearance = float(pos[2] - tt.ground[4])
        trunk_touch = bool(self._touching[self._trunk_geom])
        if not self.fell and (tilt > cfg.fall_tilt_deg or clearance < cfg.fall_min_height_m or trunk_touch):
            self.fell = True
            self.fall_xy = (float(pos[0]), float(pos[1]))


@njit(cache=True, nogil=True)
def _set_controls(
    q_des: np.ndarray,
    dq_des: np.ndarray,
    kp: np.ndarray,
    kd: np.ndarray,
    tau_ff: np.ndarray,
    ctrl_tau: np.ndarray,
    ctrl_pd: np.ndarray,
    gain_p: np.ndarray,
    bias_p: np.ndarray,
    bias_d: np.ndarray,
) -> None:
    """The joint drivers' command into MuJoCo's actuators: the torque motors get τ_ff + Kd·dq_des (the driver's
    Kd (dq_des − dq): the dq_des part is a feed-forward torque), the position servos q_des with gain Kp and
    biases −Kp, −Kd."""
    for j in range(12):
        ctrl_tau[j] = tau_ff[j] + kd[j] * dq_des[j] if dq_des[j] != 0.0 else tau_ff[j]
        ctrl_pd[j] = q_des[j]
        gain_p[j] = kp[j]
        bias_p[j] = -kp[j]
        bias_d[j] = -kd[j]


@njit(cache=True, nogil=True)
def _physics_tick(
    mj_step: int,
    model: int,
    data: int,
    steps: int,
    cmd: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    controls: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    readings: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    blocks: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> float:
    """One control tick of physics: the command `cmd` (q_des, dq_des, kp, kd, tau_ff) into the actuators'
    `controls` (`_set_controls`), `steps` × MuJoCo's `mj_step` at its address on the `mjModel`/`mjData` at
    theirs, after each step the `readings` (views of sensordata, joint q, actuator τ, joint q̇) copied into
    row k of the `blocks` (`steps` rows); returns the steps' Σ|τ·q̇| (`_joint_work`, to be multiplied by dt).
    Called so, MuJoCo runs without the Python bindings' error interception: an mju_error (none occurs in
    stepping a compiled model short of memory exhaustion) ends the process with MuJoCo's message instead of
    raising `mujoco.FatalError`."""
    q_des, dq_des, kp, kd, tau_ff = cmd
    ctrl_tau, ctrl_pd, gain_p, bias_p, bias_d = controls
    _set_controls(q_des, dq_des, kp, kd, tau_ff, ctrl_tau, ctrl_pd, gain_p, bias_p, bias_d)
    v_sens, v_q, v_tau, v_dq = readings
    sens, q, tau, dq = blocks
    for k in range(steps):
        ccall_void(mj_step, (model, data))
        sens[k, :] = v_sens
        q[k, :] = v_q
        tau[k, :] = v_tau
        dq[k, :] = v_dq
    return _joint_work(tau, dq)


@njit(cache=True, nogil=True)
def _joint_work(tau: np.ndarray, dq: np.ndarray) -> float:
    """Σ over the (k, 12) steps of Σ_j |τ_j·q̇_j|, each step's 12 terms summed in numpy's pairwise order (8
    partial sums, then the rest: `np.abs(tau * dq).sum(axis=1)`, which this replaced, bit for bit)."""
    total = 0.0
    a = np.empty(12)
    for s in range(tau.shape[0]):
        for j in range(12):
            a[j] = abs(tau[s, j] * dq[s, j])
        step = ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]))
        for j in range(8, 12):
            step += a[j]
        total += step
    return total


__all__ = ["HardwareConfig", "SimulatedAliengo"]
