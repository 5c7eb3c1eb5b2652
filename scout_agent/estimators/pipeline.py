"""EstimatorPipeline: one `ProprioSample` in, one `TickEstimates` out, every control tick.

It runs the leg kinematics once per tick and feeds slip, CoT, stability and elevation, applying the paper's
rules between them: slip guards elevation (a stance with a slip event gives no foothold) and GIIM/GIAM (no
stability sample while a stance foot has slipped in its current stance); the first `settle_s` of each stance
(start-of-stance settling) gives neither a slip decision nor a foothold.

Assignment to cells (paper §III-B): contact-based metrics (elevation, slip) at the foothold, body-centred
ones (CoT, GIIM, GIAM, non-foot contacts) at the CoM projection. `record(est, acc)` writes one tick into a
`CellAccumulator` with the layer statistics of DESIGN.md.

Non-foot contacts (calf, thigh or body on the ground) are detected proprioceptively as the force the feet do
not explain: f_ext = m·(a_GIA,feet − a_GIA,imu) (foot forces vs accelerometer), low-pass filtered; above
`nonfoot_threshold_n` the tick is flagged and counted in the `contacts` layer of the CoM cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from scout_agent.signals import ProprioSample

from .cot import CotConfig, CotMeter
from .elevation import plane_moments, terrain_normal
from .slip import SlipConfig, SlipDetector, SlipTick
from .stability import gia_from_forces, gia_from_imu, margins

__all__ = ["EstimatorPipeline", "Kinematics", "PipelineConfig", "TickEstimates", "quat_to_matrix", "record"]

_NAN2 = (math.nan, math.nan)


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
    gia_source: str = "forces"  # "forces" (sim foot forces stand in for force sensors) | "imu"
    paper_margins: bool = False  # also compute the paper-variant GIIM/GIAM
    stance_margins: bool = False  # also compute the two-stance-feet margins (diagnostic)
    paper_slip: bool = False  # also run the paper-form slip detector beside the default one
    nonfoot_threshold_n: float = 15.0  # unexplained external force that flags a non-foot contact [N]
    nonfoot_tau_s: float = 0.05  # low-pass time constant of that force [s]

    def __post_init__(self) -> None:
        if self.gia_source not in ("forces", "imu"):
            raise ValueError(f"gia_source {self.gia_source!r} unknown; sources: forces, imu")


@dataclass(frozen=True, slots=True)
class TickEstimates:
    """Everything the estimators concluded at one tick (world = map frame)."""

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
    giim_paper: float = math.nan
    giam_paper: float = math.nan
    giim_stance: float = math.nan
    giam_stance: float = math.nan
    slip_paper: SlipTick | None = None


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """world_R_base from a unit quaternion (w, x, y, z)."""
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


_EMPTY2 = np.zeros((0, 2))
_EMPTY3 = np.zeros((0, 3))


class EstimatorPipeline:
    """Slip, CoT, GIIM/GIAM, elevation and non-foot contacts from proprioception, one tick at a time."""

    def __init__(self, kinematics: Kinematics, config: PipelineConfig | None = None) -> None:
        self.kin = kinematics
        self.config = c = config or PipelineConfig()
        self.slip = SlipDetector(c.slip)
        self.slip_paper = SlipDetector(SlipConfig(**{**c.slip.__dict__, "form": "paper"})) if c.paper_slip else None
        self.cot = CotMeter(CotConfig(**{**c.cot.__dict__, "mass_kg": c.mass_kg, "gravity_mps2": c.gravity_mps2}))
        self._com_b = np.asarray(c.com_offset_base, dtype=float)
        self._normal = np.array([0.0, 0.0, 1.0])
        self._last_foot = np.full((4, 3), np.nan)  # each foot's current or last stance point (sphere centre) [m]
        self._td_xy = np.zeros((4, 2))  # foothold of the current stance at touchdown [m]
        self._fh_sum = np.zeros((4, 3))  # sum of settled contact points this stance [m]
        self._fh_n = np.zeros(4)
        self._f_ext = np.zeros(3)
        self._t_prev: float | None = None
        self._combined = getattr(kinematics, "feet_base_and_vel", None)

    def update(self, s: ProprioSample) -> TickEstimates:
        c = self.config
        dt = 0.0 if self._t_prev is None else s.t - self._t_prev
        self._t_prev = s.t
        if self._combined is not None:
            feet_b, vel_b = self._combined(s.q, s.dq)
        else:
            feet_b, vel_b = self.kin.feet_base(s.q), self.kin.feet_vel_base(s.q, s.dq)
        rot = quat_to_matrix(s.base.quat)
        base_pos = s.base.pos
        feet_w = base_pos + feet_b @ rot.T  # (4, 3) sphere centres, world
        com = base_pos + rot @ self._com_b

        st = self.slip.update(s.t, s.stance_planned, s.contact, feet_b, vel_b, rot, s.base.vel, s.base.omega)
        stp = None
        if self.slip_paper is not None:
            stp = self.slip_paper.update(s.t, s.stance_planned, s.contact, feet_b, vel_b, rot, s.base.vel, s.base.omega)

        # footholds: slip layer n at touchdown, events at the same foothold, elevation at the end of the stance
        ground_off = c.foot_radius_m * self._normal
        stance_xy = slip_xy = _EMPTY2
        footholds = _EMPTY3
        if st.touchdown.any():
            self._td_xy[st.touchdown] = feet_w[st.touchdown, :2] - ground_off[:2]
            self._fh_sum[st.touchdown] = 0.0
            self._fh_n[st.touchdown] = 0.0
            stance_xy = self._td_xy[st.touchdown].copy()
        if st.event.any():
            slip_xy = self._td_xy[st.event].copy()
        if st.settled.any():
            self._fh_sum[st.settled] += feet_w[st.settled]
            self._fh_n[st.settled] += 1.0
        if st.stance_end.any():
            done = st.stance_end & ~st.slipped & (self._fh_n > 0)
            if done.any():
                centres = self._fh_sum[done] / self._fh_n[done, None]
                self._normal = terrain_normal(self._last_foot[~np.isnan(self._last_foot[:, 0])])
                footholds = centres - c.foot_radius_m * self._normal
            self._fh_n[st.stance_end] = 0.0
        contact = s.contact
        self._last_foot[contact] = feet_w[contact]

        # CoT
        work, dist = self.cot.update(s.t, s.tau, s.dq, s.base.vel)

        # GIA and margins over the four most recent footholds
        gia_f = gia_from_forces(s.foot_force_world, c.mass_kg)
        gia_i = gia_from_imu(s.imu_acc, rot)
        gia = gia_f if c.gia_source == "forces" else gia_i
        known = ~np.isnan(self._last_foot[:, 0])
        support = self._last_foot[known] - ground_off
        giim, giam = margins(support, com, gia) if len(support) >= 2 else _NAN2
        guarded = bool((st.slipped & s.stance_planned).any())
        extra: dict[str, Any] = {}
        if c.paper_margins:
            extra["giim_paper"], extra["giam_paper"] = margins(support, com, gia, "paper") if len(support) >= 2 else _NAN2
        if c.stance_margins:
            pts = feet_w[contact] - ground_off
            extra["giim_stance"], extra["giam_stance"] = margins(pts, com, gia) if len(pts) >= 2 else _NAN2
        if stp is not None:
            extra["slip_paper"] = stp

        # non-foot contacts: external force the feet do not explain, low-pass filtered
        alpha = dt / (c.nonfoot_tau_s + dt) if dt > 0 else 1.0
        self._f_ext += alpha * (c.mass_kg * (gia_f - gia_i) - self._f_ext)
        f_ext = math.sqrt(float(self._f_ext @ self._f_ext))

        return TickEstimates(
            t=s.t,
            com_xy=(float(com[0]), float(com[1])),
            work_m=work,
            dist_m=dist,
            giim=giim,
            giam=giam,
            stability_guarded=guarded,
            slip=st,
            stance_xy=stance_xy,
            slip_xy=slip_xy,
            footholds=footholds,
            nonfoot=f_ext > c.nonfoot_threshold_n,
            nonfoot_force_n=f_ext,
            **extra,
        )


def record(est: TickEstimates, acc: Any) -> None:
    """Add one tick's estimates to a `CellAccumulator` (layer stats per DESIGN.md)."""
    x, y = est.com_xy
    acc.add("cot", x, y, work=est.work_m, dist=est.dist_m, n=1.0)
    if not est.stability_guarded and not math.isnan(est.giim):
        acc.add("giim", x, y, n=1.0, sum=est.giim, sumsq=est.giim * est.giim, min=est.giim)
        acc.add("giam", x, y, n=1.0, sum=est.giam, sumsq=est.giam * est.giam, min=est.giam)
    acc.add("contacts", x, y, n=1.0, nonfoot=1.0 if est.nonfoot else 0.0)
    for fx, fy in est.stance_xy:
        acc.add("slip", fx, fy, n=1.0, events=0.0)
    for fx, fy in est.slip_xy:
        acc.add("slip", fx, fy, n=0.0, events=1.0)
    for fx, fy, fz in est.footholds:
        acc.add_elevation(fx, fy, fz)
