"""The trot controller: QP balance control of the trunk on the stance feet, Raibert footholds on a terrain
plane fitted to the last footholds, swing feet tracked by joint PD servos that MuJoCo runs at every
physics step (the controller itself may run at a lower rate).

`TrotController.step(state)` returns a `ControlOutput`: feed-forward joint torques, PD targets and gains,
and what the slip detector needs — each foot's desired position and velocity in the base frame (stance:
the touchdown point held still in the world; swing: the swing trajectory), the planned stance and the phase.

The tick's arithmetic is compiled (numba): `_trunk_wrench` (stance bookkeeping, foothold plane, the trunk's
desired wrench) and `_joint_commands` (stance torques, swing trajectories, PD targets) around the stance QP,
which quadprog solves. In numpy the tick cost ≈ 0.4 ms of small-array overhead, most of the scout loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from scout_agent.control.gait import GaitConfig, TrotGait, schedule
from scout_agent.control.stance import StanceQP, StanceQPConfig
from scout_agent.control.swing import swing_point_into
from scout_agent.robot import constants as C
from scout_agent.robot import kinematics as K
from scout_agent.robot.kinematics import leg_ik, leg_kinematics
from scout_agent.robot.statics import leg_gravity_torques

_NOMINAL_FEET = K.fk(C.HOME_Q)  # (4, 3) base frame
_NOMINAL_FEET[:, 2] = 0.0
_EPS = 1e-6  # added to the Jacobian's diagonal before solving with it
# a state estimate's correction (a filter update that moves the position by more than its velocity explains,
# a localization fix) larger than this, summed over the last ≈ 0.1 s (`CORRECTION_LEAK`), moves the
# world-frame points the controller keeps [m]. The corrections that felled the 100 m walks were 0.1–0.2 m within
# 0.1–0.2 s; the filter's ordinary updates and slipping feet stay below it (ramp and slip behaviour as before:
# following every correction above 2 mm a tick changed the ramp hazard test's back-off)
CORRECTION_FOLLOW_M = 0.01
CORRECTION_LEAK = 0.9  # per tick: the pending correction forgets with a ≈ 0.1 s time constant


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
    # the swing lands at this share of its sine's vertical speed (`swing`): 1 landed every foot at 0.9 m/s, a
    # one-tick impact of 50-60 N at a lunar weight of 33 N on every step, unequal between the diagonal's feet on
    # uneven ground (docs/results.md, "The trot's touchdowns")
    land_share: float = 0.4
    # standing (the gait frozen, `hold`): the joints also hold the legs' own weight (`statics.leg_gravity_torques`).
    # Off: left to the ground, each leg's weight (2.9 kg, outboard of its hip ab/ad axis) squeezes its foot with
    # ≈ 0.4 N, but holding it did not lessen the stance's yaw creep (the feet slide down their own ground facets:
    # docs/results.md, "Why a standing robot's feet creep"; `benchmarks/stand_creep.py --leg-gravity`)
    stand_leg_gravity: bool = False


class RobotState(NamedTuple):
    """What the controller reads each tick (base pose/twist as the controller believes it). A NamedTuple, as
    `ControlOutput`: built every tick, at a third of a frozen dataclass's cost."""

    t: float
    pos: np.ndarray  # (3,) world
    R: np.ndarray  # (3, 3) world_R_base
    vel: np.ndarray  # (3,) world
    omega: np.ndarray  # (3,) base frame
    q: np.ndarray  # (12,)
    dq: np.ndarray  # (12,)
    contact: np.ndarray  # (4,) bool


class ControlOutput(NamedTuple):
    tau_ff: np.ndarray  # (12,) feed-forward torque [N·m] (includes kd·dq_des)
    q_des: np.ndarray  # (12,) PD target [rad]
    kp: np.ndarray  # (12,)
    kd: np.ndarray  # (12,)
    foot_pos_des_base: np.ndarray  # (4, 3)
    foot_vel_des_base: np.ndarray  # (4, 3)
    stance_planned: np.ndarray  # (4,) bool
    phase: np.ndarray  # (4,)
    stance_forces: np.ndarray  # (4, 3) QP forces on the feet, world frame [N]


@njit(cache=True, nogil=True)
def _fit_plane(P: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane z = a x + b y + c through points P (n, 3); level through their mean if degenerate."""
    n = P.shape[0]
    m = np.zeros(3)
    for i in range(n):
        m += P[i]
    m /= n
    sxx = syy = sxy = sxz = syz = 0.0
    for i in range(n):
        dx, dy, dz = P[i, 0] - m[0], P[i, 1] - m[1], P[i, 2] - m[2]
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
        sxz += dx * dz
        syz += dy * dz
    det = sxx * syy - sxy * sxy
    if det < 1e-9:
        return np.zeros(2), m[2]
    a = (sxz * syy - syz * sxy) / det
    b = (syz * sxx - sxz * sxy) / det
    return np.array([a, b]), m[2] - a * m[0] - b * m[1]


@njit(cache=True, nogil=True)
def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (log map) of a rotation matrix."""
    c = min(1.0, max(-1.0, (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0))
    angle = np.arccos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * v
    return v * (angle / (2.0 * np.sin(angle)))


@njit(cache=True, nogil=True)
def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@njit(cache=True, nogil=True)
def _mv(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R v for R (3, 3)."""
    return np.array([R[j, 0] * v[0] + R[j, 1] * v[1] + R[j, 2] * v[2] for j in range(3)])


@njit(cache=True, nogil=True)
def _mtv(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rᵀ v for R (3, 3)."""
    return np.array([R[0, j] * v[0] + R[1, j] * v[1] + R[2, j] * v[2] for j in range(3)])


@njit(cache=True, nogil=True)
def _solve3(A: np.ndarray, b: np.ndarray, eps: float) -> np.ndarray:
    """x with (A + eps I) x = b, A (3, 3): Gaussian elimination with partial pivoting."""
    M = A.copy()
    for i in range(3):
        M[i, i] += eps
    x = b.copy()
    for col in range(3):
        piv = col
        for r in range(col + 1, 3):
            if abs(M[r, col]) > abs(M[piv, col]):
                piv = r
        if piv != col:
            for j in range(3):
                M[col, j], M[piv, j] = M[piv, j], M[col, j]
            x[col], x[piv] = x[piv], x[col]
        for r in range(col + 1, 3):
            f = M[r, col] / M[col, col]
            for j in range(col, 3):
                M[r, j] -= f * M[col, j]
            x[r] -= f * x[col]
    for i in range(2, -1, -1):
        acc = x[i]
        for j in range(i + 1, 3):
            acc -= M[i, j] * x[j]
        x[i] = acc / M[i, i]
    return x


@njit(cache=True, nogil=True)
def _trunk_wrench(
    t: float,
    pos: np.ndarray,
    R: np.ndarray,
    vel: np.ndarray,
    omega: np.ndarray,
    q: np.ndarray,
    contact: np.ndarray,
    sched: np.ndarray,
    sw: np.ndarray,
    v_cmd: float,
    yaw_rate_cmd: float,
    dt: float,
    gains: np.ndarray,
    limits: np.ndarray,
    ref: np.ndarray,
    footholds: np.ndarray,
    liftoff: np.ndarray,
    in_stance: np.ndarray,
    prev_sched: np.ndarray,
    sched_td_t: np.ndarray,
    J: np.ndarray,
    feet_w: np.ndarray,
    out: np.ndarray,
) -> None:
    """Stance bookkeeping, foothold plane and desired trunk wrench for one tick (compiled).

    `gains` (17,): mass, gravity, inertia (3), kp_pos (3), kd_pos (3), kp_rot (3), kd_rot (3); `limits` (5,):
    height (with the gait's offset), max_pos_err, terrain_tilt, early_contact (`ControllerConfig`) and the trunk's
    horizontal acceleration limit [m/s²] (`TrotController.accel_limit`, inf: none). Updated in place: `ref` (3,)
    (p_ref x, y and yaw_ref), footholds, liftoff, in_stance, prev_sched, sched_td_t. Filled: J (4, 3, 3), feet_w
    (4, 3) and `out` (15,): plane gradient (2), plane offset, unit normal (3), wrench (6: force, moment about the
    CoM, world), v_des (3)."""
    mass, gravity = gains[0], gains[1]
    height, max_pos_err, terrain_tilt, early_contact = limits[0], limits[1], limits[2], limits[3]
    feet_b = np.empty((4, 3))
    leg_kinematics(q, feet_b, J)
    for i in range(4):
        feet_w[i] = pos + _mv(R, feet_b[i])
    # stance bookkeeping. A leg is in stance once it is scheduled in stance *and* has touched down
    # (late touchdown: it keeps searching downwards); a contact late in swing ends the swing early.
    for i in range(4):
        if sched[i] and not prev_sched[i]:
            sched_td_t[i] = t
            if not in_stance[i] and contact[i]:
                in_stance[i] = True
                footholds[i] = feet_w[i]
        elif not sched[i] and prev_sched[i]:
            in_stance[i] = False
            liftoff[i] = feet_w[i]
        elif not in_stance[i] and contact[i] and (sched[i] or sw[i] > early_contact):
            in_stance[i] = True
            footholds[i] = feet_w[i]
        prev_sched[i] = sched[i]

    grad, z0 = _fit_plane(footholds)
    n = np.array([-grad[0], -grad[1], 1.0])
    n /= np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])

    # desired trunk motion
    yaw = np.arctan2(R[1, 0], R[0, 0])
    v_des = np.array([v_cmd * np.cos(yaw), v_cmd * np.sin(yaw), 0.0])
    accel_limit = limits[4]
    if accel_limit < np.inf:
        # ask the ground for no more than it holds: the desired velocity stays within accel_limit / kd of the
        # trunk's own, so the velocity loop brakes or pushes at most that hard, and the footholds (Raibert,
        # `_joint_commands`) and the position reference follow the trunk where it goes
        dvx, dvy = v_des[0] - vel[0], v_des[1] - vel[1]
        dv = np.hypot(dvx, dvy)
        lim = accel_limit / gains[8]
        if dv > lim:
            v_des[0] = vel[0] + dvx * (lim / dv)
            v_des[1] = vel[1] + dvy * (lim / dv)
    v_des[2] = grad[0] * v_des[0] + grad[1] * v_des[1]
    ref[0] += v_des[0] * dt
    ref[1] += v_des[1] * dt
    ex, ey = ref[0] - pos[0], ref[1] - pos[1]
    norm = np.hypot(ex, ey)
    if norm > max_pos_err:
        ref[0] = pos[0] + ex * (max_pos_err / norm)
        ref[1] = pos[1] + ey * (max_pos_err / norm)
    yaw_ref = ref[2] + yaw_rate_cmd * dt
    yaw_ref = yaw + min(0.2, max(-0.2, (yaw_ref - yaw + np.pi) % (2 * np.pi) - np.pi))
    ref[2] = yaw_ref
    z_des = grad[0] * pos[0] + grad[1] * pos[1] + z0 + height / n[2]
    pos_err = np.array([ref[0] - pos[0], ref[1] - pos[1], z_des - pos[2]])
    F = mass * (gains[5:8] * pos_err + gains[8:11] * (v_des - vel))
    if accel_limit < np.inf:
        fh = np.hypot(F[0], F[1])
        if fh > mass * accel_limit:
            F[0] *= mass * accel_limit / fh
            F[1] *= mass * accel_limit / fh
    F[2] += mass * gravity

    up = terrain_tilt * n
    up[2] += 1.0 - terrain_tilt
    up /= np.sqrt(up[0] * up[0] + up[1] * up[1] + up[2] * up[2])
    hx = np.array([np.cos(yaw_ref), np.sin(yaw_ref), 0.0])
    x_axis = hx - (hx[0] * up[0] + hx[1] * up[1]) * up
    x_axis /= np.sqrt(x_axis[0] * x_axis[0] + x_axis[1] * x_axis[1] + x_axis[2] * x_axis[2])
    R_des = np.empty((3, 3))
    R_des[:, 0] = x_axis
    R_des[:, 1] = _cross(up, x_axis)
    R_des[:, 2] = up
    E = np.empty((3, 3))  # R_des Rᵀ
    for i in range(3):
        for j in range(3):
            E[i, j] = R_des[i, 0] * R[j, 0] + R_des[i, 1] * R[j, 1] + R_des[i, 2] * R[j, 2]
    e_rot_w = _rotvec(E)
    omega_w = _mv(R, omega)
    w_des = np.array([0.0, 0.0, yaw_rate_cmd])
    e_b = _mtv(R, e_rot_w)
    de_b = _mtv(R, w_des - omega_w)
    Tq = _mv(R, gains[2:5] * (gains[11:14] * e_b + gains[14:17] * de_b))
    out[0], out[1], out[2] = grad[0], grad[1], z0
    out[3:6] = n
    out[6:9] = F
    out[9:12] = Tq
    out[12:15] = v_des


@njit(cache=True, nogil=True)
def _joint_commands(
    t: float,
    pos: np.ndarray,
    R: np.ndarray,
    vel: np.ndarray,
    omega: np.ndarray,
    q: np.ndarray,
    J: np.ndarray,
    stance: np.ndarray,
    sched: np.ndarray,
    sw: np.ndarray,
    forces: np.ndarray,
    plane_v: np.ndarray,
    swing_s: float,
    stance_s: float,
    params: np.ndarray,
    footholds: np.ndarray,
    liftoff: np.ndarray,
    targets: np.ndarray,
    sched_td_t: np.ndarray,
    tau: np.ndarray,
    q_des: np.ndarray,
    kp: np.ndarray,
    kd: np.ndarray,
    pos_des_b: np.ndarray,
    vel_des_b: np.ndarray,
) -> None:
    """Joint torques, PD targets and gains, and each foot's desired position/velocity in the base frame
    (compiled). `plane_v` is `_trunk_wrench`'s `out`; `params` (11,): stance_kd, swing_kp, swing_kd,
    raibert_gain, max_foot_offset, swing_height, search_speed, search_depth (`ControllerConfig`); `targets`
    (the swing targets, world) updated in place; `params[8:10]`: the trunk's sway (world x, y) this tick, taken
    off the hips the footholds are placed under (else a swaying crawl narrows its stance by the sway each step);
    `params[10]`: land_share."""
    stance_kd, swing_kp, swing_kd = params[0], params[1], params[2]
    raibert, max_off, swing_h, search_speed, search_depth = (
        params[3],
        params[4],
        params[5],
        params[6],
        params[7],
    )
    g0, g1, z0 = plane_v[0], plane_v[1], plane_v[2]
    vd0, vd1 = plane_v[12], plane_v[13]
    q_des[:] = q
    kp[:] = 0.0
    kd[:] = stance_kd
    tau[:] = 0.0
    p0, p1, p_w, v_w = np.empty((1, 3)), np.empty((1, 3)), np.empty((1, 3)), np.empty((1, 3))
    prog = np.empty(1)
    for i in range(4):
        if stance[i]:
            # stance foot: touchdown point held still in the world
            p_b = _mtv(R, footholds[i] - pos)
            v_b = -(_mtv(R, vel) + _cross(omega, p_b))
            f_b = _mtv(R, forces[i])
            dq = _solve3(J[i], v_b, _EPS)
            for j in range(3):
                tau[3 * i + j] = (
                    -(J[i, 0, j] * f_b[0] + J[i, 1, j] * f_b[1] + J[i, 2, j] * f_b[2]) + stance_kd * dq[j]
                )
        else:
            # swing foot: to the Raibert foothold on the plane or (late touchdown) down from its held target
            late = sched[i]
            if late:  # the held target, lowered by the search so far (the target itself stays)
                p1[0] = targets[i]
                p1[0, 2] -= min(search_speed * (t - sched_td_t[i]), search_depth)
            else:
                hip_w = pos + _mv(R, _NOMINAL_FEET[i])
                hip_w[0] -= params[8]  # where the hip stands without the gait's sway
                hip_w[1] -= params[9]
                rem = (1.0 - sw[i]) * swing_s
                o0 = min(max(vd0 * stance_s / 2 + raibert * (vel[0] - vd0), -max_off), max_off)
                o1 = min(max(vd1 * stance_s / 2 + raibert * (vel[1] - vd1), -max_off), max_off)
                p1[0, 0] = hip_w[0] + vd0 * rem + o0
                p1[0, 1] = hip_w[1] + vd1 * rem + o1
                p1[0, 2] = p1[0, 0] * g0 + p1[0, 1] * g1 + z0 - 0.01
                targets[i] = p1[0]
            p0[0] = liftoff[i]
            prog[0] = 1.0 if late else sw[i]
            swing_point_into(p0, p1, prog, swing_h, swing_s, p_w, v_w, params[10])
            p_b = _mtv(R, p_w[0] - pos)
            v_b = _mtv(R, v_w[0] - vel) - _cross(omega, p_b)
            dq = _solve3(J[i], v_b, _EPS)
            for j in range(3):
                kp[3 * i + j] = swing_kp
                kd[3 * i + j] = swing_kd
                tau[3 * i + j] = swing_kd * dq[j]
        pos_des_b[i] = p_b
        vel_des_b[i] = v_b
    q_ik = np.empty(12)
    leg_ik(pos_des_b, q_ik)
    for i in range(4):
        if not stance[i]:
            q_des[3 * i : 3 * i + 3] = q_ik[3 * i : 3 * i + 3]


@njit(cache=True, nogil=True)
def _pending_correction(
    pos: np.ndarray,
    vel: np.ndarray,
    last_pos: np.ndarray,
    last_vel: np.ndarray,
    pending: np.ndarray,
    leak: float,
    dt: float,
) -> float:
    """`TrotController._follow_correction`'s arithmetic, compiled (nine numpy operations on 3-vectors every
    tick, the same operations in the same order): the position change the velocity does not explain,
    (p − p₋) − ½(v + v₋)·dt, added to the leaky `pending` sum (in place); `last_pos`, `last_vel` take p, v.
    Returns |pending|² (BLAS's dot, as numpy's `@`)."""
    for j in range(3):
        step = pos[j] - last_pos[j] - 0.5 * (vel[j] + last_vel[j]) * dt
        pending[j] = leak * pending[j] + step
        last_pos[j] = pos[j]
        last_vel[j] = vel[j]
    return np.dot(pending, pending)


class TrotController:
    def __init__(self, config: ControllerConfig = ControllerConfig()) -> None:
        self.config = config
        self.gait = TrotGait(config.gait)
        self.qp = StanceQP(config.qp)
        c = config
        # the compiled tick's parameters (layouts: `_trunk_wrench`, `_joint_commands`)
        self._gains = np.array(
            [c.mass, c.gravity, *c.inertia, *c.kp_pos, *c.kd_pos, *c.kp_rot, *c.kd_rot], dtype=float
        )
        self._limits = np.array(
            [c.height, c.max_pos_err, c.terrain_tilt, c.early_contact, np.inf], dtype=float
        )
        self._params = np.array(
            [
                c.stance_kd,
                c.swing_kp,
                c.swing_kd,
                c.raibert_gain,
                c.max_foot_offset,
                c.swing_height,
                c.search_speed,
                c.search_depth,
                0.0,  # the gait's sway, world x, y [m] (set each tick)
                0.0,
                c.land_share,
            ],
            dtype=float,
        )
        self._J = np.empty((4, 3, 3))
        self._feet_w = np.empty((4, 3))
        self._plane_v = np.empty(15)
        self.v_cmd = 0.0  # forward speed command [m/s]
        self.yaw_rate_cmd = 0.0  # [rad/s]
        self.mu_feet: np.ndarray | None = None  # each foot's friction for the stance QP (None: its constant)
        self.height_offset = 0.0  # trunk height change from the adaptive gait [m] (negative: lower)
        # the most horizontal acceleration the trunk controller asks of the ground [m/s²] (inf: none; the
        # adaptive gait sets it from the felt friction, `adaptation.GaitSetting.accel_limit_mps2`)
        self.accel_limit = np.inf
        self.terrain_tilt: float | None = None  # share of the foothold plane's tilt the trunk follows (None:
        # the config's); 0 keeps the trunk level, so on a slope its CoM stands over the middle of its feet
        self._initialized = False
        self.t0 = 0.0
        # stand still on four feet: the gait's clock stops at the next instant all four feet are down
        # (the estimator's standstill updates, state_estimation/standstill.py)
        self.hold = False
        self._frozen_at: float | None = None  # the gait time it stopped at [s]
        self._stand_feet: np.ndarray | None = None  # (4, 3) centred feet, base frame, when it froze [m]
        self._stand_centre = np.zeros(3)  # their centre then, base frame [m]
        self._tau_g = np.empty(12)  # the legs' gravity torques while standing [N·m]
        self.corrections_followed = 0  # ticks whose estimate correction moved the kept points

    def set_command(self, forward_speed: float, yaw_rate: float) -> None:
        self.v_cmd = forward_speed
        self.yaw_rate_cmd = yaw_rate

    def _stand_refs(self, s: RobotState) -> None:
        """Standing: hold the trunk where it froze against its planted feet, from the leg kinematics, not the
        estimate. An estimate update moves neither reference: a pose fix on frozen feet toppled it, and with a
        wrong gyro bias a held estimated heading twisted the trunk on its legs at the bias error; following the
        estimate instead let the trunk drift off the stance's centre over a 20 s stand, and the first diagonal
        to carry it on walking on lost a foot."""
        f = K.fk(s.q)
        c = f.mean(axis=0)
        if self._stand_feet is None:
            self._stand_feet = f - c
            self._stand_centre = c
        d = s.R @ (c - self._stand_centre)  # the trunk moved by −d over its feet (world frame)
        self._ref[0], self._ref[1] = s.pos[0] + d[0], s.pos[1] + d[1]
        f0, f2 = self._stand_feet[:, :2], (f - c)[:, :2]
        # the feet turned by θ in the base frame (2-D Kabsch, closed form): the trunk turned by −θ over them
        theta = np.arctan2(float(np.sum(f0[:, 0] * f2[:, 1] - f0[:, 1] * f2[:, 0])), float(np.sum(f0 * f2)))
        self._ref[2] = np.arctan2(s.R[1, 0], s.R[0, 0]) + theta

    def _add_leg_gravity(self, s: RobotState, tau: np.ndarray) -> None:
        """Standing: add the torques that hold the legs' own links (the estimate's gravity direction) to `tau`."""
        g_base = s.R[2] * -self.config.gravity  # Rᵀ (0, 0, −g)
        leg_gravity_torques(np.ascontiguousarray(s.q, dtype=float), g_base, self._tau_g)
        tau += self._tau_g

    @property
    def standing(self) -> bool:
        """The gait is frozen with every foot down (`hold` reached)."""
        return self._frozen_at is not None

    def set_friction(self, mu_feet: np.ndarray | None) -> None:
        """Each foot's friction coefficient the stance QP's cone uses from now on (None: the constant)."""
        self.mu_feet = None if mu_feet is None else np.asarray(mu_feet, dtype=float).copy()

    def set_gait(self, gait: GaitConfig, t: float) -> None:
        """Walk with `gait` from time `t` [s] on, its phases starting at its offsets (a leg scheduled in stance
        that is still in the air keeps descending to its target until it touches down)."""
        if gait != self.gait.config:
            self.gait = TrotGait(gait)
            self.t0 = t

    def reset(self, state: RobotState) -> None:
        feet_w = state.pos + K.fk(state.q) @ state.R.T
        self.footholds = feet_w.copy()  # (4, 3) last stance points, world
        self.liftoff = feet_w.copy()
        self.in_stance = np.ones(4, bool)
        self.prev_stance_sched = np.ones(4, bool)
        # p_ref x, y [m] and yaw_ref [rad]: where the trunk should be
        self._ref = np.array([state.pos[0], state.pos[1], np.arctan2(state.R[1, 0], state.R[0, 0])])
        self.f_prev = np.zeros((4, 3))
        self.sched_td_t = np.zeros(4)
        self.targets = feet_w.copy()  # (4, 3) current swing targets, world
        self.t0 = state.t
        self._last_pos = np.array(state.pos, dtype=float)
        self._last_vel = np.array(state.vel, dtype=float)
        self._pending = np.zeros(3)  # the estimate's recent correction not yet followed [m]
        self._initialized = True

    def _follow_correction(self, s: RobotState, dt: float) -> None:
        """Move the world-frame points this controller keeps (footholds, lift-off points, swing targets, the
        trunk's position reference) with a correction of the state estimate: they were placed with the estimate
        before it. Else the correction itself drives the trunk: a filter update that moves the estimated height
        by −0.09 m raises the foothold plane's target height by as much, and at lunar g that thrust lifts the
        feet off a crater wall (the 100 m walks' falls, docs/results.md issue 23). The correction is the part
        of the position change its velocity does not explain; below `CORRECTION_FOLLOW_M` it is left alone
        (ordinary walking)."""
        # a correction spread over a few ticks counts as one (leaky sum, ≈ 0.1 s memory)
        moved2 = _pending_correction(
            np.asarray(s.pos, dtype=float),
            np.asarray(s.vel, dtype=float),
            self._last_pos,
            self._last_vel,
            self._pending,
            CORRECTION_LEAK,
            dt,
        )
        jump = self._pending
        if moved2 > CORRECTION_FOLLOW_M**2:
            self._pending = np.zeros(3)
            self.footholds += jump
            self.liftoff += jump
            self.targets += jump
            self._ref[:2] += jump[:2]
            self.corrections_followed += 1

    def _sway(self, s: RobotState) -> np.ndarray:
        """(2,) the gait's sideways trunk offset this tick along the base's horizontal +y, world x, y [m]
        (`TrotGait.sway`; zero for a gait without one)."""
        d = self.gait.sway(s.t - self.t0)
        y = s.R[:2, 1]
        return d * y / max(float(np.hypot(y[0], y[1])), 1e-6)

    def plane(self) -> tuple[np.ndarray, float]:
        """Foothold plane z = g·(x, y) + c through the last footholds (foot-sphere centres)."""
        return _fit_plane(self.footholds)

    def step(self, s: RobotState, dt: float) -> ControlOutput:
        if not self._initialized:
            self.reset(s)
        else:
            self._follow_correction(s, dt)
        g = self.gait.config
        phase, sched, sw = np.empty(4), np.empty(4, bool), np.empty(4)
        if not self.hold:
            self._frozen_at = None
        elif self._frozen_at is not None:
            self.t0 = s.t - self._frozen_at
        schedule(s.t - self.t0, g.freq_hz, g.duty, self.gait.offsets, phase, sched, sw)
        if self.hold and self._frozen_at is None and sched.all() and s.contact.all():
            self._frozen_at = s.t - self.t0
            self._stand_feet = None
        if self._frozen_at is not None:
            self._stand_refs(s)
        J, feet_w, pv = self._J, self._feet_w, self._plane_v
        # a swaying gait (`GaitConfig.sway_m`): the trunk tracks its reference plus the sway this tick (the trot
        # skips this: no per-tick cost)
        sway = self._sway(s) if self.gait.config.sway_m > 0.0 and self._frozen_at is None else None
        if sway is not None:
            self._ref[:2] += sway
        self._limits[0] = self.config.height + self.height_offset
        self._limits[2] = self.config.terrain_tilt if self.terrain_tilt is None else self.terrain_tilt
        self._limits[4] = self.accel_limit
        _trunk_wrench(
            s.t,
            s.pos,
            s.R,
            s.vel,
            s.omega,
            s.q,
            s.contact,
            sched,
            sw,
            self.v_cmd,
            self.yaw_rate_cmd,
            dt,
            self._gains,
            self._limits,
            self._ref,
            self.footholds,
            self.liftoff,
            self.in_stance,
            self.prev_stance_sched,
            self.sched_td_t,
            J,
            feet_w,
            pv,
        )
        if sway is not None:
            self._ref[:2] -= sway
            self._params[8:10] = sway
        elif self._params[8] != 0.0 or self._params[9] != 0.0:
            self._params[8:10] = 0.0
        stance = self.in_stance.copy()
        forces = self.qp.solve_feet(stance, feet_w, s.pos, pv[3:6], pv[6:12], self.f_prev, self.mu_feet)
        self.f_prev = forces
        tau, q_des, kp, kd = np.empty(12), np.empty(12), np.empty(12), np.empty(12)
        pos_des_b, vel_des_b = np.empty((4, 3)), np.empty((4, 3))
        _joint_commands(
            s.t,
            s.pos,
            s.R,
            s.vel,
            s.omega,
            s.q,
            J,
            stance,
            sched,
            sw,
            forces,
            pv,
            self.gait.swing_s,
            self.gait.stance_s,
            self._params,
            self.footholds,
            self.liftoff,
            self.targets,
            self.sched_td_t,
            tau,
            q_des,
            kp,
            kd,
            pos_des_b,
            vel_des_b,
        )
        if self._frozen_at is not None and self.config.stand_leg_gravity:
            self._add_leg_gravity(s, tau)
        return ControlOutput(tau, q_des, kp, kd, pos_des_b, vel_des_b, sched, phase, forces)
