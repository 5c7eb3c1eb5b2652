"""The trot controller: QP balance control of the trunk on the stance feet, Raibert footholds on a terrain
plane fitted to the last footholds, swing feet tracked by joint PD servos that MuJoCo runs at every
physics step (the controller itself may run at a lower rate).

`TrotController.step(state)` returns a `ControlOutput`: feed-forward joint torques, PD targets and gains,
and what the slip detector needs — each foot's desired position and velocity in the base frame (stance:
the touchdown point held still in the world; swing: the swing trajectory), the planned stance and the phase.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scout_agent.control.gait import GaitConfig, TrotGait
from scout_agent.control.stance import StanceQP, StanceQPConfig
from scout_agent.control.swing import swing_point
from scout_agent.robot import constants as C
from scout_agent.robot import kinematics as K
from scout_agent.robot.vectors import cross

_NOMINAL_FEET = K.fk(C.HOME_Q)  # (4, 3) base frame
_NOMINAL_FEET[:, 2] = 0.0
_EPS3 = 1e-6 * np.eye(3)
_EZ = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class ControllerConfig:
    gait: GaitConfig = field(default_factory=GaitConfig)
    qp: StanceQPConfig = field(default_factory=StanceQPConfig)
    mass: float = C.TOTAL_MASS  # [kg]
    gravity: float = C.LUNAR_G  # [m/s²]
    inertia: tuple[float, float, float] = (0.35, 0.90, 0.92)  # whole body about the trunk, home pose [kg·m²]
    height: float = 0.33  # trunk origin above the foothold plane, along its normal [m]
    kp_pos: tuple[float, float, float] = (12.0, 12.0, 60.0)  # [1/s²] (× mass)
    kd_pos: tuple[float, float, float] = (7.0, 7.0, 12.0)  # [1/s]
    kp_rot: tuple[float, float, float] = (120.0, 120.0, 50.0)  # [1/s²] (× inertia)
    kd_rot: tuple[float, float, float] = (14.0, 14.0, 9.0)
    max_pos_err: float = 0.08  # clamp on the horizontal position error [m]
    terrain_tilt: float = 0.8  # share of the foothold-plane inclination the trunk follows
    swing_height: float = 0.08  # [m]
    raibert_gain: float = 0.12  # [s]
    max_foot_offset: float = 0.15  # [m]
    swing_kp: float = 30.0  # joint PD in swing [N·m/rad]
    swing_kd: float = 1.0  # [N·m·s/rad]
    stance_kd: float = 0.3
    early_contact: float = 0.5  # swing progress after which a contact ends the swing
    search_speed: float = 0.4  # late touchdown: the foot keeps descending at this speed [m/s]
    search_depth: float = 0.12  # ... up to this far below its target [m]


@dataclass(frozen=True, slots=True)
class RobotState:
    """What the controller reads each tick (base pose/twist as the controller believes it)."""

    t: float
    pos: np.ndarray  # (3,) world
    R: np.ndarray  # (3, 3) world_R_base
    vel: np.ndarray  # (3,) world
    omega: np.ndarray  # (3,) base frame
    q: np.ndarray  # (12,)
    dq: np.ndarray  # (12,)
    contact: np.ndarray  # (4,) bool


@dataclass(frozen=True, slots=True)
class ControlOutput:
    tau_ff: np.ndarray  # (12,) feed-forward torque [N·m] (includes kd·dq_des)
    q_des: np.ndarray  # (12,) PD target [rad]
    kp: np.ndarray  # (12,)
    kd: np.ndarray  # (12,)
    foot_pos_des_base: np.ndarray  # (4, 3)
    foot_vel_des_base: np.ndarray  # (4, 3)
    stance_planned: np.ndarray  # (4,) bool
    phase: np.ndarray  # (4,)
    stance_forces: np.ndarray  # (4, 3) QP forces on the feet, world frame [N]


def _fit_plane(P: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane z = a x + b y + c through points P (n, 3); level through their mean if degenerate."""
    m = P.mean(axis=0)
    d = P - m
    sxx, syy, sxy = float(d[:, 0] @ d[:, 0]), float(d[:, 1] @ d[:, 1]), float(d[:, 0] @ d[:, 1])
    sxz, syz = float(d[:, 0] @ d[:, 2]), float(d[:, 1] @ d[:, 2])
    det = sxx * syy - sxy * sxy
    if det < 1e-9:
        return np.zeros(2), float(m[2])
    a = (sxz * syy - syz * sxy) / det
    b = (syz * sxx - sxz * sxy) / det
    return np.array([a, b]), float(m[2] - a * m[0] - b * m[1])


def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (log map) of a rotation matrix."""
    c = min(1.0, max(-1.0, (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0))
    angle = np.arccos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * v
    return v * (angle / (2.0 * np.sin(angle)))


class TrotController:
    def __init__(self, config: ControllerConfig = ControllerConfig()) -> None:
        self.config = config
        self.gait = TrotGait(config.gait)
        self.qp = StanceQP(config.qp)
        self._I = np.diag(config.inertia)
        self._kp_pos = np.asarray(config.kp_pos)
        self._kd_pos = np.asarray(config.kd_pos)
        self._kp_rot = np.asarray(config.kp_rot)
        self._kd_rot = np.asarray(config.kd_rot)
        self.v_cmd = 0.0  # forward speed command [m/s]
        self.yaw_rate_cmd = 0.0  # [rad/s]
        self.mu_feet: np.ndarray | None = None  # each foot's friction for the stance QP (None: its constant)
        self.height_offset = 0.0  # trunk height change from the adaptive gait [m] (negative: lower)
        self._initialized = False
        self.t0 = 0.0

    def set_command(self, forward_speed: float, yaw_rate: float) -> None:
        self.v_cmd = forward_speed
        self.yaw_rate_cmd = yaw_rate

    def set_friction(self, mu_feet: np.ndarray | None) -> None:
        """Each foot's friction coefficient the stance QP's cone uses from now on (None: the constant)."""
        self.mu_feet = None if mu_feet is None else np.asarray(mu_feet, dtype=float).copy()

    def reset(self, state: RobotState) -> None:
        feet_w = state.pos + K.fk(state.q) @ state.R.T
        self.footholds = feet_w.copy()  # (4, 3) last stance points, world
        self.liftoff = feet_w.copy()
        self.in_stance = [True] * 4
        self.prev_stance_sched = [True] * 4
        self.p_ref = state.pos[:2].copy()
        self.yaw_ref = float(np.arctan2(state.R[1, 0], state.R[0, 0]))
        self.f_prev = np.zeros((4, 3))
        self.sched_td_t = np.zeros(4)
        self.targets = feet_w.copy()  # (4, 3) current swing targets, world
        self.t0 = state.t
        self._initialized = True

    def plane(self) -> tuple[np.ndarray, float]:
        """Foothold plane z = g·(x, y) + c through the last footholds (foot-sphere centres)."""
        return _fit_plane(self.footholds)

    def step(self, s: RobotState, dt: float) -> ControlOutput:
        if not self._initialized:
            self.reset(s)
        c = self.config
        R = s.R
        feet_b = K.fk(s.q)
        J = K.jacobians(s.q)
        feet_w = s.pos + feet_b @ R.T
        phase = self.gait.phase(s.t - self.t0)
        sched = self.gait.stance(phase)
        sw = self.gait.swing_progress(phase)
        # stance bookkeeping. A leg is in stance once it is scheduled in stance *and* has touched down
        # (late touchdown: it keeps searching downwards); a contact late in swing ends the swing early.
        sched_l, sw_l, con_l, prev = sched.tolist(), sw.tolist(), s.contact.tolist(), self.prev_stance_sched
        ins = self.in_stance
        for i in range(4):
            if sched_l[i] and not prev[i]:
                self.sched_td_t[i] = s.t
                if not ins[i] and con_l[i]:
                    ins[i] = True
                    self.footholds[i] = feet_w[i]
            elif not sched_l[i] and prev[i]:
                ins[i] = False
                self.liftoff[i] = feet_w[i]
            elif not ins[i] and con_l[i] and (sched_l[i] or sw_l[i] > c.early_contact):
                ins[i] = True
                self.footholds[i] = feet_w[i]
        self.prev_stance_sched = sched_l
        stance = np.array(ins)

        grad, z0 = self.plane()
        n = np.array([-grad[0], -grad[1], 1.0])
        n /= np.linalg.norm(n)

        # desired trunk motion
        yaw = float(np.arctan2(R[1, 0], R[0, 0]))
        heading = np.array([np.cos(yaw), np.sin(yaw)])
        v_des = np.zeros(3)
        v_des[:2] = self.v_cmd * heading
        v_des[2] = grad @ v_des[:2]
        self.p_ref += v_des[:2] * dt
        err = self.p_ref - s.pos[:2]
        norm = np.hypot(*err)
        if norm > c.max_pos_err:
            self.p_ref = s.pos[:2] + err * (c.max_pos_err / norm)
        self.yaw_ref += self.yaw_rate_cmd * dt
        self.yaw_ref = yaw + min(0.2, max(-0.2, (self.yaw_ref - yaw + np.pi) % (2 * np.pi) - np.pi))
        z_des = grad @ s.pos[:2] + z0 + (c.height + self.height_offset) / n[2]
        pos_err = np.array([self.p_ref[0] - s.pos[0], self.p_ref[1] - s.pos[1], z_des - s.pos[2]])
        F = c.mass * (self._kp_pos * pos_err + self._kd_pos * (v_des - s.vel))
        F[2] += c.mass * c.gravity

        up = c.terrain_tilt * n + (1.0 - c.terrain_tilt) * _EZ
        up /= np.linalg.norm(up)
        hx = np.array([np.cos(self.yaw_ref), np.sin(self.yaw_ref), 0.0])
        x_axis = hx - (hx @ up) * up
        x_axis /= np.linalg.norm(x_axis)
        R_des = np.column_stack([x_axis, cross(up, x_axis), up])
        e_rot_w = _rotvec(R_des @ R.T)
        omega_w = R @ s.omega
        w_des = np.array([0.0, 0.0, self.yaw_rate_cmd])
        e_b = R.T @ e_rot_w
        de_b = R.T @ (w_des - omega_w)
        Tq = R @ (self._I @ (self._kp_rot * e_b + self._kd_rot * de_b))
        wrench = np.concatenate([F, Tq])

        forces = np.zeros((4, 3))
        idx = np.flatnonzero(stance)
        if idx.size:
            r = feet_w[idx] - s.pos
            mu = None if self.mu_feet is None else self.mu_feet[idx]
            forces[idx] = self.qp.solve(r, n, wrench, self.f_prev[idx], mu)
        self.f_prev = forces

        tau = np.zeros(12)
        q_des = s.q.copy()
        kp = np.zeros(12)
        kd = np.full(12, c.stance_kd)
        pos_des_b = np.empty((4, 3))
        vel_des_b = np.empty((4, 3))
        f_b = forces @ R  # rows: R^T f
        # stance feet: touchdown point held still in the world
        p_hold_b = (self.footholds - s.pos) @ R
        v_hold_b = -(s.vel @ R + cross(s.omega, p_hold_b))
        tau_st = (
            -np.einsum("lji,lj->li", J, f_b)
            + c.stance_kd * np.linalg.solve(J + _EPS3, v_hold_b[..., None])[..., 0]
        )
        for i in idx.tolist():
            tau[3 * i : 3 * i + 3] = tau_st[i]
        pos_des_b[idx] = p_hold_b[idx]
        vel_des_b[idx] = v_hold_b[idx]

        sw_idx = np.flatnonzero(~stance)
        if sw_idx.size:
            T_sw, T_st = self.gait.swing_s, self.gait.stance_s
            hips_w = s.pos + (_NOMINAL_FEET[sw_idx] @ R.T)
            v_xy = s.vel[:2]
            rem = (1.0 - sw[sw_idx])[:, None] * T_sw
            off = v_des[:2] * T_st / 2 + c.raibert_gain * (v_xy - v_des[:2])
            off = np.clip(off, -c.max_foot_offset, c.max_foot_offset)
            target = np.empty((sw_idx.size, 3))
            target[:, :2] = hips_w[:, :2] + v_des[:2] * rem + off
            target[:, 2] = target[:, :2] @ grad + z0 - 0.01
            late = sched[sw_idx]  # scheduled stance, no touchdown yet: hold xy, search downwards
            if late.any():
                li = sw_idx[late]
                target[late] = self.targets[li]
                target[late, 2] -= np.minimum(c.search_speed * (s.t - self.sched_td_t[li]), c.search_depth)
            self.targets[sw_idx] = target
            prog = np.where(late, 1.0, sw[sw_idx])
            p_w, v_w = swing_point(self.liftoff[sw_idx], target, prog, c.swing_height, T_sw)
            p_b = (p_w - s.pos) @ R
            v_b = (v_w - s.vel) @ R - cross(s.omega, p_b)
            pos_des_b[sw_idx] = p_b
            vel_des_b[sw_idx] = v_b
            q_ik = K.ik(pos_des_b).reshape(4, 3)
            dq_sw = np.linalg.solve(J[sw_idx] + _EPS3, v_b[..., None])[..., 0]
            for k, i in enumerate(sw_idx.tolist()):
                sl = slice(3 * i, 3 * i + 3)
                q_des[sl] = q_ik[i]
                kp[sl] = c.swing_kp
                kd[sl] = c.swing_kd
                tau[sl] += c.swing_kd * dq_sw[k]
        return ControlOutput(tau, q_des, kp, kd, pos_des_b, vel_des_b, sched, phase, forces)
