"""EstimatorPipeline: one `ProprioSample` in, one `TickEstimates` out, every control tick.

It runs the leg kinematics once per tick and feeds slip, CoT, stability and elevation, applying the paper's
rules between them: slip guards elevation (a stance with a slip event gives no foothold) and GIIM/GIAM (no
stability sample while a stance foot has slipped in its current stance); the first `settle_s` of each stance
(start-of-stance settling) gives neither a slip decision nor a foothold.

Elevation: one foothold per non-slipping stance, the mean of its settled contact-tick foot positions, minus
the foot radius along the terrain normal fitted to the four most recent footholds; committed when the stance
ends (only then is it known to have no slip). Stability: GIA from the accelerometer (a = −R·f_imu with the
estimated orientation; `gia_source="forces"` uses the ground forces estimated from joint torques instead,
f = −J⁻ᵀτ per stance foot — an Aliengo has no 3-axis foot force sensors), support = the four most recent footholds
(each foot's current or last stance point) ordered counter-clockwise about their centroid seen from above;
the paper variant and the two-stance-feet diagnostic are computed beside it on request.

Assignment to cells (paper §III-B): contact-based metrics (elevation, slip) at the foothold, body-centred
ones (CoT, GIIM, GIAM, non-foot contacts) at the CoM projection. `record(est, acc)` writes one tick into a
`CellAccumulator` with the layer statistics of docs/design.md.

Non-foot contacts (calf, thigh or body on the ground) are detected proprioceptively as the force the feet do
not explain (`nonfoot.UnexplainedForce`: the whole robot's inverse dynamics, legs and rotors included, at the
accelerations the accelerometer, gyro and joint drivers report, less each counted foot's force from its leg's
rows), low-pass filtered; above `nonfoot_threshold_n` the tick is flagged and counted in the `contacts` layer of
the CoM cell. The accelerometer's specific force is the trunk origin's (`ProprioSample.imu_acc`: the state
estimator removed the IMU's lever arm), and nothing is flagged while a leg in contact stands at a joint limit, nor
`nonfoot_limit_hold_s` after (the limit's torque is not in the motor's); the limit is watched every tick.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np
import pinocchio as pin
from numba import njit

from scout_agent.errors import ScoutConfigError
from scout_agent.robot import constants as C
from scout_agent.robot import kinematics as K
from scout_agent.robot.kinematics import leg_motion
from scout_agent.robot.statics import leg_forces_from_torques
from scout_agent.signals import ProprioSample

from .cot import CotConfig, CotMeter
from .elevation import terrain_normal
from .nonfoot import UnexplainedForce, unexplained_tick
from .slip import SlipConfig, SlipDetector, SlipTick
from .stability import _EPS_N, _face_margins, margins_fast, order_ccw_xy

__all__ = ["EstimatorPipeline", "Kinematics", "PipelineConfig", "TickEstimates", "quat_to_matrix", "record"]


class Kinematics(Protocol):
    def feet_base(self, q: np.ndarray) -> np.ndarray: ...  # (4, 3) [m], base frame

    def feet_vel_base(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray: ...  # (4, 3) [m/s], base frame


@dataclass(frozen=True)
class PipelineConfig:
    slip: SlipConfig = field(default_factory=SlipConfig)
    cot: CotConfig = field(default_factory=CotConfig)
    mass_kg: float = 24.64  # robot mass [kg] (GIA from forces, CoT); set from the simulated model
    gravity_mps2: float = 1.62
    foot_radius_m: float = 0.0265
    com_offset_base: tuple[float, float, float] = (0.0, 0.0, 0.0)  # CoM in the base frame [m]
    gia_source: str = "imu"  # "imu" (accelerometer) | "forces" (ground forces estimated from joint torques)
    paper_margins: bool = False  # also compute the paper-variant GIIM/GIAM
    stance_margins: bool = False  # also compute the two-stance-feet margins (diagnostic)
    paper_slip: bool = False  # also run the paper-form slip detector beside the default one
    nonfoot_threshold_n: float = (
        20.0  # unexplained external force that flags a non-foot contact [N] (≈ 0.6 m·g)
    )
    nonfoot_tau_s: float = 0.05  # low-pass time constant of that force [s]
    nonfoot_warmup_s: float = (
        0.25  # no flag before this much time since the first tick (landing transient) [s]
    )
    # no flag while a leg in contact has a joint within this of its range's end, nor for `nonfoot_limit_hold_s`
    # after: the joint limit then bears torque the motor's current does not show, so the feet's forces from the
    # torques are wrong (100 m field, seed 33, realistic sensors: a hind knee stretched to its stop into a
    # hollow read 15–30 N of "non-foot" force the truth had no contact for, and stopped the scout) [rad]
    nonfoot_limit_margin_rad: float = 0.05
    nonfoot_limit_hold_s: float = 0.15  # 3 time constants of the low-pass: what the limit added has decayed

    def __post_init__(self) -> None:
        if self.gia_source not in ("forces", "imu"):
            raise ScoutConfigError(f"gia_source {self.gia_source!r} unknown; sources: forces, imu")


class TickEstimates(NamedTuple):
    """Everything the estimators concluded at one tick (world = map frame).

    (A NamedTuple rather than a frozen dataclass: it is built every tick, and costs a third as much.)"""

    t: float
    com_xy: tuple[float, float]  # CoM projection [m]
    work_m: float  # E_tick / (m·g) [m]
    dist_m: float  # horizontal base travel this tick [m]
    giim: float  # [rad], NaN if unavailable
    giam: float  # [m/s²], NaN if unavailable
    stability_guarded: bool  # a slipping stance foot: GIIM/GIAM not mapped this tick
    slip: SlipTick
    stance_xy: np.ndarray  # (k, 2) footholds of stances that started this tick (slip layer n)
    slip_xy: np.ndarray  # (j, 2) footholds of slip events declared this tick (slip layer events)
    footholds: np.ndarray  # (m, 3) committed non-slipping stance footholds (elevation)
    nonfoot: bool  # non-foot contact flagged this tick
    nonfoot_force_n: float  # filtered unexplained external force [N]
    foot_force_w: np.ndarray  # (4, 3) ground force on each foot from its joint torques, world [N]; zero
    # on feet out of contact (the friction estimate's force ratios read it too)
    giim_paper: float = math.nan
    giam_paper: float = math.nan
    giim_stance: float = math.nan
    giam_stance: float = math.nan
    slip_paper: SlipTick | None = None


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """world_R_base from a unit quaternion (w, x, y, z)."""
    return _quat_to_matrix(np.asarray(q, dtype=float))


@njit(cache=True, nogil=True)
def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """`quat_to_matrix`, compiled (the pipeline and the pilot ask every tick)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return R


@njit(cache=True, nogil=True)
def _legs_and_rotation(
    q: np.ndarray,
    dq: np.ndarray,
    quat: np.ndarray,
    feet: np.ndarray,
    vel: np.ndarray,
    omega: np.ndarray,
    J: np.ndarray,
) -> np.ndarray:
    """`PinocchioFeet.feet_base_and_vel` into its buffers (`kinematics.leg_motion`) and world_R_base from
    `quat`, in one compiled call a tick."""
    leg_motion(q, dq, feet, vel, omega, J)
    return _quat_to_matrix(quat)


_ZERO12 = np.zeros(12)  # joint gravity torques: the legs below the joints weigh ≈ 0.2 N at a foot at lunar g
_EMPTY2 = np.zeros((0, 2))
_EMPTY3 = np.zeros((0, 3))


class EstimatorPipeline:
    """Slip, CoT, GIIM/GIAM, elevation and non-foot contacts from proprioception, one tick at a time.

    The per-tick path works on Python scalars wherever arrays would hold 3 or 4 numbers (numpy's per-call
    overhead dominates at that size); `benchmarks/estimators.py` measures it.
    """

    def __init__(self, kinematics: Kinematics, config: PipelineConfig | None = None) -> None:
        self.kin = kinematics
        self.config = c = config or PipelineConfig()
        self.slip = SlipDetector(c.slip)
        self.slip_paper = SlipDetector(dataclasses.replace(c.slip, form="paper")) if c.paper_slip else None
        self.cot = CotMeter(dataclasses.replace(c.cot, mass_kg=c.mass_kg, gravity_mps2=c.gravity_mps2))
        self._com_b = np.array([float(v) for v in c.com_offset_base])
        self._normal = np.array([0.0, 0.0, 1.0])  # ground normal of the latest footholds, world
        self._last_foot = np.zeros((4, 3))  # each foot's current or last stance point [m] (where `_known`)
        self._known = np.zeros(4, bool)  # feet with a foothold
        self._order = np.zeros(5, np.int64)  # the known feet CCW about their centroid, their count last
        self._reorder = False
        self._td_xy = [(0.0, 0.0)] * 4  # foothold of the current stance at touchdown [m]
        self._fh_sum = np.zeros((4, 3))  # sum of settled contact points this stance [m]
        self._fh_n = np.zeros(4, np.int64)
        self._f_ext = np.zeros(3)
        self._core = np.empty(10)  # `_tick_core`'s figures: CoM (3), GIIM, GIAM, |f_ext|, CoM + r·n̂ (3), 0
        self._t_prev: float | None = None
        self._t0: float | None = None
        self._combined = getattr(kinematics, "feet_base_and_vel", None)
        buffers = getattr(kinematics, "buffers", None)  # a `PinocchioFeet`: its closed form, compiled here
        self._buffers = buffers() if buffers is not None else None
        self._foot_omega = getattr(kinematics, "foot_omega", None)
        lo, hi = np.array(C.JOINT_RANGES, dtype=float).T
        self._q_lo = np.tile(lo + c.nonfoot_limit_margin_rad, 4)  # (12,) joints nearer their end than this:
        self._q_hi = np.tile(hi - c.nonfoot_limit_margin_rad, 4)  # at the limit
        self._t_limit = -math.inf  # a leg in contact was at a joint limit then [s]
        model = getattr(kinematics, "model", None)
        self._unexplained = UnexplainedForce(model if isinstance(model, pin.Model) else None)

    def _jacobians(self, q: np.ndarray) -> np.ndarray:
        """The legs' Jacobians at `q`: from this tick's kinematics pass when it computed them, else anew."""
        J = getattr(self.kin, "jacobians", None)
        return J if J is not None and self._combined is not None else K.jacobians(q)

    def update(self, s: ProprioSample) -> TickEstimates:
        c = self.config
        dt = 0.0 if self._t_prev is None else s.t - self._t_prev
        self._t_prev = s.t
        if self._t0 is None:
            self._t0 = s.t
        if self._buffers is not None:  # the legs' closed form and the trunk's rotation in one compiled call
            feet_b, vel_b, f_om, jac = self._buffers
            rot = _legs_and_rotation(s.q, s.dq, s.base.quat, feet_b, vel_b, f_om, jac)
        else:
            if self._combined is not None:
                feet_b, vel_b = self._combined(s.q, s.dq)
            else:
                feet_b, vel_b = self.kin.feet_base(s.q), self.kin.feet_vel_base(s.q, s.dq)
            rot = quat_to_matrix(s.base.quat)
            f_om = self._foot_omega
            jac = self._jacobians(s.q)
        st = self.slip.update(
            s.t, s.stance_planned, s.contact, feet_b, vel_b, rot, s.base.vel, s.base.omega, f_om
        )
        stp = None
        if self.slip_paper is not None:
            stp = self.slip_paper.update(
                s.t, s.stance_planned, s.contact, feet_b, vel_b, rot, s.base.vel, s.base.omega
            )

        # foot sphere centres (4, 3), world [m]; ground forces on the feet from their joint torques (4, 3),
        # world [N], zero off contact
        # and the force the feet do not explain (`nonfoot`), in one compiled call
        uf = self._unexplained
        params, damping, prev, contact_prev, resid = uf.state
        fw, f_w, at_limit, fresh = _legs_tick(
            feet_b,
            rot,
            s.base.pos,
            jac,
            s.tau,
            _ZERO12,
            s.contact,
            s.q,
            self._q_lo,
            self._q_hi,
            params,
            damping,
            s.dq,
            s.base.omega,
            s.imu_acc,
            uf.interval(s),
            prev,
            contact_prev,
            resid,
        )
        if at_limit:
            self._t_limit = s.t
        r, m = c.foot_radius_m, c.mass_kg

        # footholds: slip layer n at touchdown, events at the same foothold, elevation at the end of the stance
        stance_xy = slip_xy = _EMPTY2
        footholds = _EMPTY3
        if True in st.touchdown or True in st.event or True in st.stance_end:
            footholds, stance_xy, slip_xy = self._stance_changes(st, fw)

        # CoT
        work, dist = self.cot.update(s.t, s.joint_energy_j, s.base.vel)

        # settled sums, latest footholds and their CCW order, CoM, GIA (torque-estimated foot forces and IMU),
        # margins over the four most recent footholds and the non-foot force's low-pass: one compiled call.
        # The support points are the ground points (sphere centres − r·n̂); shifting the CoM by +r·n̂ instead
        # is the same geometry and copies nothing.
        alpha = dt / (c.nonfoot_tau_s + dt) if dt > 0 else 1.0
        if not fresh:
            alpha = 0.0  # nothing new to difference (the first tick, a lost packet): the low-pass holds
        core = self._core
        self._reorder = _tick_core(
            fw,
            f_w,
            rot,
            s.base.pos,
            self._com_b,
            s.imu_acc,
            resid,
            s.contact,
            st.settled,
            self._normal,
            self._last_foot,
            self._known,
            self._order,
            self._fh_sum,
            self._fh_n,
            self._f_ext,
            self._reorder,
            r,
            m,
            alpha,
            c.gia_source == "forces",
            _EPS_N,
            core,
        )
        com_x, com_y, _, giim, giam, f_ext, gcx, gcy, gcz, _ = core.tolist()
        contact = s.contact.tolist()
        guarded = (
            (st.slipped[0] and contact[0])
            or (st.slipped[1] and contact[1])
            or (st.slipped[2] and contact[2])
            or (st.slipped[3] and contact[3])
        )
        extra: dict[str, Any] = {}
        if c.paper_margins or c.stance_margins:
            gia = tuple(self._gia(s, rot, f_w))
            g_c = (gcx, gcy, gcz)
            if c.paper_margins:
                extra["giim_paper"], extra["giam_paper"] = margins_fast(
                    self._last_foot[self._known].tolist(),
                    g_c,
                    gia,
                    absolute=True,  # type: ignore[misc]
                )
            if c.stance_margins:
                pts = fw[s.contact].tolist()
                if len(pts) > 2:
                    pts = [pts[j] for j in order_ccw_xy(pts)]
                extra["giim_stance"], extra["giam_stance"] = margins_fast(pts, g_c, gia)
        if stp is not None:
            extra["slip_paper"] = stp

        return TickEstimates(
            t=s.t,
            com_xy=(com_x, com_y),
            work_m=work,
            dist_m=dist,
            giim=giim,
            giam=giam,
            stability_guarded=guarded,
            slip=st,
            stance_xy=stance_xy,
            slip_xy=slip_xy,
            footholds=footholds,
            nonfoot=f_ext > c.nonfoot_threshold_n
            and s.t - self._t0 >= c.nonfoot_warmup_s
            and s.t - self._t_limit > c.nonfoot_limit_hold_s,
            nonfoot_force_n=f_ext,
            foot_force_w=f_w,
            **extra,
        )

    def _gia(self, s: ProprioSample, rot: np.ndarray, f_w: np.ndarray) -> list[float]:
        """The GIA the margins used (world), for the evaluation's extra margin variants: `_tick_core`'s."""
        out = np.empty(3)
        _gia_of(rot, s.imu_acc, f_w, self.config.mass_kg, self.config.gia_source == "forces", out)
        return out.tolist()  # type: ignore[no-any-return]

    def _stance_changes(self, st: SlipTick, fw_a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Touchdowns, slip events and stance ends of this tick → (footholds (m, 3), stance_xy, slip_xy)."""
        r = self.config.foot_radius_m
        nx, ny, _ = self._normal.tolist()
        fw = fw_a.tolist()
        stances, slips, done = [], [], []
        for i in range(4):
            if st.touchdown[i]:
                f = fw[i]
                self._td_xy[i] = (f[0] - r * nx, f[1] - r * ny)
                self._fh_sum[i] = 0.0
                self._fh_n[i] = 0
                stances.append(self._td_xy[i])
                self._reorder = True
            if st.event[i]:
                slips.append(self._td_xy[i])
            if st.stance_end[i]:
                n = int(self._fh_n[i])
                if not st.slipped[i] and n > 0:
                    done.append([v / n for v in self._fh_sum[i].tolist()])
                self._fh_n[i] = 0
        footholds = _EMPTY3
        if done:
            if np.count_nonzero(self._known) >= 3:
                self._normal = terrain_normal(self._last_foot[self._known])
            footholds = np.array(done) - r * self._normal
        return (
            footholds,
            np.array(stances) if stances else _EMPTY2,
            np.array(slips) if slips else _EMPTY2,
        )


@njit(cache=True, nogil=True)
def _legs_tick(
    feet_b: np.ndarray,
    rot: np.ndarray,
    pos: np.ndarray,
    jacobians: np.ndarray,
    tau: np.ndarray,
    tau_gravity: np.ndarray,
    contact: np.ndarray,
    q: np.ndarray,
    q_lo: np.ndarray,
    q_hi: np.ndarray,
    params: np.ndarray,
    damping: np.ndarray,
    dq: np.ndarray,
    omega: np.ndarray,
    f_imu: np.ndarray,
    dt_fresh: float,
    prev: np.ndarray,
    contact_prev: np.ndarray,
    resid: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, bool, bool]:
    """The feet (4, 3) in the world (R·f + p) and their ground forces from the joint torques (4, 3), world,
    zeroed off `contact` (`leg_forces_from_torques` rotated by R: numpy's figures, the same BLAS products);
    whether a leg in contact has a joint within the margin of its range's end (`q` outside [`q_lo`, `q_hi`]:
    its motor's torque then does not give its foot's force, the limit bears the rest, and the non-foot force is
    not known); and the force the feet do not explain into `resid` (`nonfoot.unexplained_tick` on its state
    arrays; `dt_fresh` −1: a lost packet, nothing new) — one compiled call a tick. Returns the world feet, their
    forces, the joint-limit flag, and whether `resid` is new."""
    Rt = np.ascontiguousarray(rot.T)
    fw = np.dot(feet_b, Rt)
    for i in range(4):
        for j in range(3):
            fw[i, j] += pos[j]
    f = np.dot(leg_forces_from_torques(jacobians, tau, tau_gravity), Rt)
    for i in range(4):
        if not contact[i]:
            for j in range(3):
                f[i, j] = 0.0
    at_limit = False
    for j in range(12):
        if (q[j] < q_lo[j] or q[j] > q_hi[j]) and contact[j // 3]:
            at_limit = True
    fresh = False
    if dt_fresh != -1.0:
        fresh = unexplained_tick(
            params,
            damping,
            q,
            dq,
            omega,
            f_imu,
            tau,
            jacobians,
            contact,
            rot,
            dt_fresh,
            prev,
            contact_prev,
            resid,
        )
    return fw, f, at_limit, fresh


@njit(cache=True, nogil=True)
def _gia_of(
    rot: np.ndarray, imu_acc: np.ndarray, f_w: np.ndarray, mass: float, from_forces: bool, out: np.ndarray
) -> None:
    """The GIA (world) into `out`: −Σf/m from the torque-estimated foot forces, or −R·f_imu."""
    for k in range(3):
        if from_forces:
            out[k] = -(f_w[0, k] + f_w[1, k] + f_w[2, k] + f_w[3, k]) / mass
        else:
            out[k] = -(rot[k, 0] * imu_acc[0] + rot[k, 1] * imu_acc[1] + rot[k, 2] * imu_acc[2])


@njit(cache=True, nogil=True)
def _tick_core(
    fw: np.ndarray,
    f_w: np.ndarray,
    rot: np.ndarray,
    pos: np.ndarray,
    com_b: np.ndarray,
    imu_acc: np.ndarray,
    resid: np.ndarray,
    contact: np.ndarray,
    settled: tuple,
    normal: np.ndarray,
    last_foot: np.ndarray,
    known: np.ndarray,
    order: np.ndarray,
    fh_sum: np.ndarray,
    fh_n: np.ndarray,
    f_ext: np.ndarray,
    reorder: bool,
    r: float,
    mass: float,
    alpha: float,
    gia_from_forces: bool,
    eps: float,
    out: np.ndarray,
) -> bool:
    """The pipeline's per-tick arithmetic after the slip detector, compiled (the same operations in the same
    order as the Python it replaced): settled contact points summed per stance (`fh_sum`, `fh_n`), each
    foot's latest stance point (`last_foot`, `known`) and, when a foot became known or touched down
    (`reorder`), their CCW order about their centroid (`order`: indices, count last; stable on ties, as
    Python's sort); the CoM; the GIA (from the IMU, or the foot forces); the margins over the ordered
    footholds about CoM + r·n̂; the low-pass of the force the feet do not explain (`resid`, world: `f_ext`, in
    place). `out`: CoM (3), GIIM, GIAM, |f_ext|, CoM + r·n̂ (3), 0. Returns False (the order is current)."""
    for i in range(4):
        if settled[i]:
            fh_sum[i, 0] += fw[i, 0]
            fh_sum[i, 1] += fw[i, 1]
            fh_sum[i, 2] += fw[i, 2]
            fh_n[i] += 1
        if contact[i]:
            if not known[i]:
                known[i] = True
                reorder = True
            last_foot[i, 0], last_foot[i, 1], last_foot[i, 2] = fw[i, 0], fw[i, 1], fw[i, 2]
    if reorder:
        n = 0
        for i in range(4):
            if known[i]:
                order[n] = i
                n += 1
        order[4] = n
        if n > 2:
            cx, cy = 0.0, 0.0
            for j in range(n):
                cx += last_foot[order[j], 0]
                cy += last_foot[order[j], 1]
            cx, cy = cx / n, cy / n
            key = np.empty(n)
            for j in range(n):
                key[j] = math.atan2(last_foot[order[j], 1] - cy, last_foot[order[j], 0] - cx)
            for j in range(1, n):  # insertion sort by key: stable
                kj, oj = key[j], order[j]
                m = j - 1
                while m >= 0 and key[m] > kj:
                    key[m + 1], order[m + 1] = key[m], order[m]
                    m -= 1
                key[m + 1], order[m + 1] = kj, oj
    c0, c1, c2 = com_b[0], com_b[1], com_b[2]
    com_x = pos[0] + rot[0, 0] * c0 + rot[0, 1] * c1 + rot[0, 2] * c2
    com_y = pos[1] + rot[1, 0] * c0 + rot[1, 1] * c1 + rot[1, 2] * c2
    com_z = pos[2] + rot[2, 0] * c0 + rot[2, 1] * c1 + rot[2, 2] * c2
    gia = np.empty(3)
    _gia_of(rot, imu_acc, f_w, mass, gia_from_forces, gia)
    gx, gy, gz = com_x + r * normal[0], com_y + r * normal[1], com_z + r * normal[2]
    giim, giam = math.nan, math.nan
    k = order[4]
    if k >= 2:
        pts = np.empty((k, 3))
        for j in range(k):
            pts[j, 0], pts[j, 1], pts[j, 2] = (
                last_foot[order[j], 0],
                last_foot[order[j], 1],
                last_foot[order[j], 2],
            )
        giim, giam = _face_margins(pts, gx, gy, gz, gia[0], gia[1], gia[2], eps)
    for j in range(3):
        f_ext[j] += alpha * (resid[j] - f_ext[j])
    out[0], out[1], out[2] = com_x, com_y, com_z
    out[3], out[4] = giim, giam
    out[5] = math.sqrt(f_ext[0] * f_ext[0] + f_ext[1] * f_ext[1] + f_ext[2] * f_ext[2])
    out[6], out[7], out[8], out[9] = gx, gy, gz, 0.0
    return False


def record(est: TickEstimates, acc: Any) -> None:
    """Add one tick's estimates to a `CellAccumulator` (layer stats per docs/design.md / protocol.layers)."""
    x, y = est.com_xy
    acc.append("cot", (x, y, est.work_m, est.dist_m, 1.0))  # work, dist, n
    g = est.giim
    if g == g and not est.stability_guarded:  # not NaN
        a = est.giam
        acc.append("giim", (x, y, 1.0, g, g * g, g))  # n, sum, sumsq, min
        acc.append("giam", (x, y, 1.0, a, a * a, a))
    acc.append("contacts", (x, y, 1.0, 1.0 if est.nonfoot else 0.0))  # n, nonfoot
    if len(est.stance_xy):
        for fx, fy in est.stance_xy.tolist():
            acc.append("slip", (fx, fy, 1.0, 0.0))  # n, events
    if len(est.slip_xy):
        for fx, fy in est.slip_xy.tolist():
            acc.append("slip", (fx, fy, 0.0, 1.0))
    if len(est.footholds):
        for fx, fy, fz in est.footholds.tolist():
            acc.add_elevation(fx, fy, fz)
