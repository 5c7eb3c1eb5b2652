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
not explain: f_ext = m·(a_GIA,feet − a_GIA,imu) (torque-estimated foot forces vs accelerometer), low-pass
filtered; above
`nonfoot_threshold_n` the tick is flagged and counted in the `contacts` layer of the CoM cell.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np
from numba import njit

from scout_agent.errors import ScoutConfigError
from scout_agent.robot import kinematics as K
from scout_agent.robot.statics import leg_forces_from_torques
from scout_agent.signals import ProprioSample

from .cot import CotConfig, CotMeter
from .elevation import terrain_normal
from .slip import SlipConfig, SlipDetector, SlipTick
from .stability import margins_fast, order_ccw_xy

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
def _world_feet_and_forces(
    feet_b: np.ndarray,
    rot: np.ndarray,
    pos: np.ndarray,
    jacobians: np.ndarray,
    tau: np.ndarray,
    tau_gravity: np.ndarray,
    contact: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The feet (4, 3) in the world (R·f + p) and their ground forces from the joint torques (4, 3), world,
    zeroed off `contact` (`leg_forces_from_torques` rotated by R): numpy's figures (the same BLAS products),
    in one compiled call a tick."""
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
    return fw, f


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
        self._com_b = tuple(float(v) for v in c.com_offset_base)
        self._normal = (0.0, 0.0, 1.0)
        self._last_foot: list[list[float] | None] = [None] * 4  # each foot's current or last stance point [m]
        self._known: list[int] = []  # feet with a foothold, leg order
        self._order: list[int] = []  # the same, CCW about their centroid
        self._reorder = False
        self._td_xy = [(0.0, 0.0)] * 4  # foothold of the current stance at touchdown [m]
        self._fh_sum = [[0.0, 0.0, 0.0] for _ in range(4)]  # sum of settled contact points this stance [m]
        self._fh_n = [0] * 4
        self._f_ext = [0.0, 0.0, 0.0]
        self._t_prev: float | None = None
        self._t0: float | None = None
        self._combined = getattr(kinematics, "feet_base_and_vel", None)

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
        if self._combined is not None:
            feet_b, vel_b = self._combined(s.q, s.dq)
        else:
            feet_b, vel_b = self.kin.feet_base(s.q), self.kin.feet_vel_base(s.q, s.dq)
        rot = quat_to_matrix(s.base.quat)
        f_om = getattr(self.kin, "foot_omega", None)
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
        fw_a, f_w = _world_feet_and_forces(
            feet_b, rot, s.base.pos, self._jacobians(s.q), s.tau, _ZERO12, s.contact
        )
        fw = fw_a.tolist()
        R = rot.tolist()
        bx, by, bz = s.base.pos.tolist()
        c0, c1, c2 = self._com_b
        com = (
            bx + R[0][0] * c0 + R[0][1] * c1 + R[0][2] * c2,
            by + R[1][0] * c0 + R[1][1] * c1 + R[1][2] * c2,
            bz + R[2][0] * c0 + R[2][1] * c1 + R[2][2] * c2,
        )
        r = c.foot_radius_m
        contact = s.contact.tolist()
        lf: list[Any] = self._last_foot  # entries known in self._known are never None

        # footholds: slip layer n at touchdown, events at the same foothold, elevation at the end of the stance
        stance_xy = slip_xy = _EMPTY2
        footholds = _EMPTY3
        if True in st.touchdown or True in st.event or True in st.stance_end:
            footholds, stance_xy, slip_xy = self._stance_changes(st, fw)
        for i in range(4):
            if st.settled[i]:
                f, acc = fw[i], self._fh_sum[i]
                acc[0] += f[0]
                acc[1] += f[1]
                acc[2] += f[2]
                self._fh_n[i] += 1
            if contact[i]:
                if lf[i] is None:
                    self._known = [k for k in range(4) if lf[k] is not None or k == i]
                    self._reorder = True
                lf[i] = fw[i]
        if self._reorder:
            self._reorder = False
            pts = [lf[i] for i in self._known]
            self._order = [self._known[j] for j in order_ccw_xy(pts)] if len(pts) > 2 else list(self._known)

        # CoT
        work, dist = self.cot.update(s.t, s.joint_energy_j, s.base.vel)

        # GIA (world) from the torque-estimated foot forces and from the IMU
        (f0, f1, f2, f3) = f_w.tolist()
        m = c.mass_kg
        gia_f = (
            -(f0[0] + f1[0] + f2[0] + f3[0]) / m,
            -(f0[1] + f1[1] + f2[1] + f3[1]) / m,
            -(f0[2] + f1[2] + f2[2] + f3[2]) / m,
        )
        ax, ay, az = s.imu_acc.tolist()
        gia_i = (
            -(R[0][0] * ax + R[0][1] * ay + R[0][2] * az),
            -(R[1][0] * ax + R[1][1] * ay + R[1][2] * az),
            -(R[2][0] * ax + R[2][1] * ay + R[2][2] * az),
        )
        gia = gia_f if c.gia_source == "forces" else gia_i

        # margins over the four most recent footholds, CCW. The support points are the ground points
        # (sphere centres − r·n̂); shifting the CoM by +r·n̂ instead is the same geometry and copies nothing.
        nx, ny, nz = self._normal
        g_c = (com[0] + r * nx, com[1] + r * ny, com[2] + r * nz)
        giim, giam = margins_fast([lf[i] for i in self._order], g_c, gia)  # type: ignore[misc]
        guarded = (
            (st.slipped[0] and contact[0])
            or (st.slipped[1] and contact[1])
            or (st.slipped[2] and contact[2])
            or (st.slipped[3] and contact[3])
        )
        extra: dict[str, Any] = {}
        if c.paper_margins:
            extra["giim_paper"], extra["giam_paper"] = margins_fast(
                [lf[i] for i in self._known],
                g_c,
                gia,
                absolute=True,  # type: ignore[misc]
            )
        if c.stance_margins:
            pts = [fw[i] for i in range(4) if contact[i]]
            if len(pts) > 2:
                pts = [pts[j] for j in order_ccw_xy(pts)]
            extra["giim_stance"], extra["giam_stance"] = margins_fast(pts, g_c, gia)
        if stp is not None:
            extra["slip_paper"] = stp

        # non-foot contacts: external force the feet do not explain, low-pass filtered
        alpha = dt / (c.nonfoot_tau_s + dt) if dt > 0 else 1.0
        fe = self._f_ext
        for k in range(3):
            fe[k] += alpha * (m * (gia_f[k] - gia_i[k]) - fe[k])
        f_ext = math.sqrt(fe[0] * fe[0] + fe[1] * fe[1] + fe[2] * fe[2])

        return TickEstimates(
            t=s.t,
            com_xy=(com[0], com[1]),
            work_m=work,
            dist_m=dist,
            giim=giim,
            giam=giam,
            stability_guarded=guarded,
            slip=st,
            stance_xy=stance_xy,
            slip_xy=slip_xy,
            footholds=footholds,
            nonfoot=f_ext > c.nonfoot_threshold_n and s.t - self._t0 >= c.nonfoot_warmup_s,
            nonfoot_force_n=f_ext,
            foot_force_w=f_w,
            **extra,
        )

    def _stance_changes(
        self, st: SlipTick, fw: list[list[float]]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Touchdowns, slip events and stance ends of this tick → (footholds (m, 3), stance_xy, slip_xy)."""
        r = self.config.foot_radius_m
        nx, ny, nz = self._normal
        stances, slips, done = [], [], []
        for i in range(4):
            if st.touchdown[i]:
                f = fw[i]
                self._td_xy[i] = (f[0] - r * nx, f[1] - r * ny)
                self._fh_sum[i] = [0.0, 0.0, 0.0]
                self._fh_n[i] = 0
                stances.append(self._td_xy[i])
                self._reorder = True
            if st.event[i]:
                slips.append(self._td_xy[i])
            if st.stance_end[i]:
                if not st.slipped[i] and self._fh_n[i] > 0:
                    n = self._fh_n[i]
                    done.append([v / n for v in self._fh_sum[i]])
                self._fh_n[i] = 0
        footholds = _EMPTY3
        if done:
            known = [f for f in self._last_foot if f is not None]
            if len(known) >= 3:
                self._normal = tuple(terrain_normal(np.array(known)).tolist())
            footholds = np.array(done) - r * np.array(self._normal)
        return (
            footholds,
            np.array(stances) if stances else _EMPTY2,
            np.array(slips) if slips else _EMPTY2,
        )


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
