"""Foot slip detection after Nisticò et al. (Sensors 2022, 22(8):2967), per stance foot, in the base frame.

Two indicators per stance foot f (all vectors in the base frame):

- ΔV = ‖(ẋ_des − ẋ) ⊘ (|ẋ_des| + h)‖ (eq. 1, element-wise division), where ẋ is the foot velocity from leg
  kinematics (J(q)·q̇, relative to the base) and ẋ_des = −(v_base + ω × x) is the velocity the foot must have
  relative to the base to stay put in the world.
- ΔP between the desired foot position x_des (the touchdown point, fixed in the world, expressed in the base
  frame now) and the measured x: paper form (eq. 2) ΔP = | ‖x_des‖ − ‖x‖ |; default form ΔP = ‖x_des − x‖.

Two detector forms share this module (`SlipConfig.form`):

- ``"paper"``: the paper taken literally. Stance = contact flag; the touchdown reference is re-taken at every
  rising edge of the contact flag; a slip is flagged at a tick where ΔV > ε_v and ΔP_paper > ε_p together.
- ``"default"`` (what worked on this machine; docs/physics.md, "Slip"), each a departure from the paper:
  1. ΔP is the vector distance ‖x_des − x‖: the norm difference of eq. 2 is blind to a slip perpendicular to x
     and halves one along it.
  2. The ΔV flag is sticky within a stance and confirmed by ΔP: ΔV peaks at slip onset, ΔP builds up later, so
     "both at the same instant" (eq. 3) almost never holds.
  3. Touchdown is the first contact flag inside the gait's planned stance and is never re-taken inside it:
     contact flicker otherwise resets the reference and hides the displacement. Its reference point, though,
     is where the foot was at the last tick of the planned swing if the foot was already in contact then
     (it usually lands a tick early: 77 % of stances on lunar terrain): the foot moves 1 mm on average,
     up to 7 mm, between that tick and the first in-stance tick, and the ground-truth criterion (the contact
     point's displacement since its first contact) counts that motion. Measured on the 9 lunar runs: without
     it ΔP read 1–3 mm short of the true displacement on exactly the borderline 2.0–2.6 cm slips that were
     missed. (Uses only the contact flag and the gait schedule, both in ProprioSample.)
  4. The first `settle_s` of each stance is skipped (impact transients): no ΔV or ΔP is looked at then. A
     displacement made inside it still counts once settled (ΔP is measured from the touchdown point), as in
     the ground truth, but only through ΔP > `eps_p_alone_m` (item 8), since its ΔV was not seen.
  5. The base velocity the robot knows carries a bias (the simulator's honest input: 0.02 m/s); integrated
     over a 0.4 s stance it alone makes ΔP ≈ 8 mm. The detector estimates it like a kinematic-inertial state
     estimator would: the apparent world velocity of a planted foot, minus its rolling ω_foot × r·n̂ (a ball
     foot's centre rolls 4–7 mm per stance), is the base velocity's error; its per-stance mean, from stances
     that ended without a slip, moves the estimate with time constant `bias_tau_s`, and the estimate is
     subtracted from the base velocity before ΔV and ΔP. Not circular: one stance weighs ≈ 0.2 in a 2 s
     average across all feet, and slipping stances are left out. Only ticks ≥ `bias_settle_s` (0.1 s) after
     touchdown feed it: a landing foot rebounds out of the (soft) ground, its centre rises ≈ 5.5 mm in the
     first 0.1 s (≈ 0.07 m/s at 0.05–0.075 s, measured on ramps with exact state), and with those ticks
     the estimate carried a spurious +0.005 m/s vertical bias even with exact state (2 mm of false ΔP per
     stance; 3 of the 49 lunar slips missed with exact state were missed for this alone).
  6. The velocity error is low-passed (`dv_tau_s` = 24 ms) within a stance before ΔV: the 0.03 m/s white
     noise divided by h = 0.05 m/s on the axes where ẋ_des ≈ 0 otherwise puts ΔV ≈ 1 on every tick.
  7. ε_v history: the ΔV values of stances that ended without a slip (the paper: "recent ΔV"). Where slips
     are dense (25–75 % of stances on a slippery patch) the plain percentile rises into the slips themselves.
     Floor `eps_v_floor` = 1.0 (an earlier trial suggested 1.5 for a 500 Hz loop without input noise; here slow
     downhill slips peak at ΔV ≈ 1–2, because eq. 1 divides the along-track error by |ẋ_des| + h ≈ 0.25).
  8. A ΔP above `eps_p_alone_m` (0.024 m = 1.2 ε_p) is a slip without any ΔV flag. Slow creeping slips
     (0.1 m/s or less, common on lunar slippery patches) never raise the noise-filtered ΔV above ε_v: on the
     9 lunar runs 3 true slips of 2.6–3.3 cm (ΔP 2.4–3.3 cm) had ΔV peaks of 0.76–0.96 with ε_v 1.0–1.26;
     the velocity normalisation of eq. 1 divides a slow along-track creep by |ẋ_des| + h ≈ 0.3. ΔV's job is to
     reject ΔP made of base-velocity error; with the bias estimated, ΔP of non-slipping stances stayed
     ≤ 0.0216 m on lunar terrain and ≤ 0.016 m on plain 5–20° ramps (honest state), so 0.024 m keeps a
     margin. Between ε_p and this, the ΔV confirmation of item 2 is still required.

Both forms: ε_v = max(`eps_v_floor`, `eps_v_percentile` percentile of ≈ `eps_v_window_s` of recent ΔV), updated
when a stance ends; ε_p is fixed (0.02 m, the ground-truth criterion); at most one event per foot per planned
stance. The base position used for x_des is integrated from the (bias-corrected) base velocity, so only motion
within a stance matters, not absolute position drift.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from scout_agent.errors import ScoutConfigError

from . import slip_kernel as K

__all__ = ["SlipConfig", "SlipDetector", "SlipTick", "delta_p_paper", "delta_p_vector", "delta_v"]


@dataclass(frozen=True)
class SlipConfig:
    form: str = "default"  # "default" | "paper"
    eps_p_m: float = 0.02  # ε_p [m]
    h_mps: float = 0.05  # h in eq. 1 [m/s]
    eps_v_percentile: float = 95.0  # ε_v = this percentile of recent ΔV
    eps_v_window_s: float = 1.5  # window of recent ΔV [s]
    eps_v_floor: float = 1.0  # ε_v never below this (dimensionless, like ΔV)
    eps_p_alone_m: float = 0.024  # ΔP above this is a slip with no ΔV flag [m] (default form; inf = off)
    settle_s: float = 0.05  # start-of-stance settling skipped [s] (default form)
    dv_tau_s: float = 0.024  # low-pass of the foot velocity error before ΔV [s] (default form; 0 = off)
    bias_tau_s: float = 2.0  # time constant of the base-velocity bias estimate [s] (default form; 0 = off)
    bias_settle_s: float = 0.1  # planted feet feed the bias only this long after touchdown [s]
    bias_gate_mps: float = 0.15  # feet whose apparent world velocity exceeds this do not feed the bias [m/s]
    foot_radius_m: float = 0.0265  # ball foot radius, for the rolling term of the bias estimate [m]

    def __post_init__(self) -> None:
        if self.form not in ("default", "paper"):
            raise ScoutConfigError(f"slip form {self.form!r} unknown; forms: default, paper")


def delta_v(vel_des: np.ndarray, vel: np.ndarray, h: float) -> np.ndarray:
    """Eq. 1 per foot: ‖(ẋ_des − ẋ) ⊘ (|ẋ_des| + h)‖. vel_des, vel: (..., 3) [m/s] → (...,)."""
    r = (vel_des - vel) / (np.abs(vel_des) + h)
    return np.sqrt(np.einsum("...i,...i->...", r, r))


def delta_p_paper(pos_des: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Eq. 2 per foot: | ‖x_des‖ − ‖x‖ |. pos_des, pos: (..., 3) [m] → (...,) [m]."""
    return np.abs(np.linalg.norm(pos_des, axis=-1) - np.linalg.norm(pos, axis=-1))


def delta_p_vector(pos_des: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Default form: ‖x_des − x‖ per foot. (..., 3) [m] → (...,) [m]."""
    d = pos_des - pos
    return np.sqrt(np.einsum("...i,...i->...", d, d))


class SlipTick(NamedTuple):
    """What the detector saw at one tick; each field holds the 4 legs in LEG_NAMES order.

    (A NamedTuple rather than a frozen dataclass: it is built every tick, and costs a quarter as much.)"""

    touchdown: tuple[bool, ...]  # the stance's reference was taken this tick
    event: tuple[bool, ...]  # a slip event was declared this tick (at most once per stance)
    stance_end: tuple[bool, ...]  # the planned stance ended this tick (after a touchdown)
    slipped: tuple[bool, ...]  # this stance (current, or the one just ended) holds a slip event
    settled: tuple[bool, ...]  # in contact inside a touched-down stance, past the settling time
    dv: tuple[float, ...]  # ΔV; NaN where not settled (computed only where it is used)
    dp: tuple[float, ...]  # ΔP of the configured form [m]; NaN where not settled
    eps_v: float  # current ε_v


class SlipDetector:
    """Stateful detector for the 4 legs; feed it one tick at a time with `update`.

    The per-tick step is compiled (`slip_kernel.slip_step`: the four feet in one call, the state below in
    place; ΔV/ΔP only for settled stance feet). `delta_v`/`delta_p_*` above are the vectorised reference
    forms (tests check the two agree).
    """

    def __init__(self, config: SlipConfig | None = None) -> None:
        self.config = config or SlipConfig()
        c = self.config
        self._paper = c.form == "paper"
        self._use_bias = not self._paper and c.bias_tau_s > 0
        # ΔV of finished stances (default form: non-slipping ones only), sized at the second tick
        self._ring = np.zeros(0)
        self._stance_dv = np.zeros((4, _STANCE_DV_CAP0))  # this stance's ΔV per leg (circular, see kernel)
        self._counts = np.zeros(10, np.int64)  # per-leg and ring counts (slip_kernel)
        self.eps_v = c.eps_v_floor
        self._t_prev: float | None = None
        self._pb = np.zeros(3)  # base position integrated from the known velocity [m]
        self._flags = np.zeros((7, 4), bool)  # per-leg flags, rows in slip_kernel
        self._flags[K.ERR_NEW] = True
        self._t_td = np.zeros(4)
        self._p_td = np.zeros((4, 3))  # touchdown foot points, integration frame [m]
        self._p_pre = np.zeros((4, 3))  # the foot point at the last planned-swing tick, integration frame [m]
        self._err = np.zeros((4, 3))  # low-passed foot velocity error, base frame [m/s]
        self.bias = np.zeros(3)  # estimated bias of the known base velocity, world frame [m/s]
        self._ap_sum = np.zeros((4, 3))  # apparent planted-foot velocity this stance, summed (world)
        self._dt = 0.0
        self._out_flags = np.zeros((5, 4), bool)
        self._out_vals = np.zeros((2, 4))
        self._params = np.array(
            [
                c.eps_v_floor,
                c.eps_p_m,
                c.eps_p_alone_m,
                c.h_mps,
                c.settle_s,
                c.bias_settle_s,
                c.bias_gate_mps**2,
                c.foot_radius_m,
                c.bias_tau_s,
                2.0,  # the ΔP squares' exponent (slip_kernel: libm's pow, as Python's ** calls)
            ]
        )

    def reset(self) -> None:
        self.__init__(self.config)  # type: ignore[misc]

    @property
    def base_pos_integrated(self) -> tuple[float, float, float]:
        """The base position integrated from the base velocity since the first tick [m]."""
        return tuple(self._pb.tolist())  # type: ignore[return-value]

    def update(
        self,
        t: float,
        stance_planned: np.ndarray,  # (4,) bool
        contact: np.ndarray,  # (4,) bool
        foot_pos: np.ndarray,  # (4, 3) foot centres relative to the base, base frame [m]
        foot_vel: np.ndarray,  # (4, 3) foot velocities relative to the base, base frame [m/s]
        world_R_base: np.ndarray,  # (3, 3)
        base_vel_world: np.ndarray,  # (3,) base linear velocity, world frame [m/s]
        base_omega: np.ndarray,  # (3,) base angular velocity, base frame [rad/s]
        foot_omega: np.ndarray | None = None,  # (4, 3) foot angular velocities relative to the base [rad/s]
    ) -> SlipTick:
        c = self.config
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        if dt > 0 and len(self._ring) == 0:  # ≈ 2 feet in stance at a time
            self._ring = np.zeros(max(20, 2 * int(round(c.eps_v_window_s / dt))))
            self._grow_stance_dv(len(self._ring))
        paper = self._paper
        a_v = dt / (c.dv_tau_s + dt) if (not paper and c.dv_tau_s > 0 and dt > 0) else 1.0
        self._dt = dt if dt > 0 else self._dt
        params = self._params
        params[0] = self.eps_v
        fed = K.slip_step(
            t,
            dt,
            self._dt,
            a_v,
            params,
            paper,
            self._use_bias,
            stance_planned,  # (numba compiles a variant for other dtypes or layouts: no copies here)
            contact,
            foot_pos,
            foot_vel,
            world_R_base,
            base_vel_world,
            base_omega,
            foot_omega if foot_omega is not None else _NO_OMEGA,
            foot_omega is not None,
            self._flags,
            self._pb,
            self.bias,
            self._t_td,
            self._p_td,
            self._p_pre,
            self._err,
            self._ap_sum,
            self._stance_dv,
            self._ring,
            self._counts,
            self._out_flags,
            self._out_vals,
        )
        eps_v = self.eps_v  # this tick's decisions used the ε_v from before its finished stances
        if fed:
            self._update_eps_v()
        td, ev, end, slip_out, settled = self._out_flags.tolist()
        dv, dp = self._out_vals.tolist()
        return SlipTick(
            tuple(td), tuple(ev), tuple(end), tuple(slip_out), tuple(settled), tuple(dv), tuple(dp), eps_v
        )

    def _update_eps_v(self) -> None:
        """ε_v = the configured percentile of the ring's ΔV history (once it holds 10), never below the floor."""
        ring_n = int(self._counts[K.RING_FILLED])
        if ring_n >= 10:
            hist = self._ring[:ring_n]
            k = min(ring_n - 1, int(round(self.config.eps_v_percentile / 100.0 * (ring_n - 1))))
            self.eps_v = max(float(np.partition(hist, k)[k]), self.config.eps_v_floor)

    def _grow_stance_dv(self, cap: int) -> None:
        """Make each leg's stance ΔV buffer hold at least `cap` values (the ring's length), keeping its last
        values in order."""
        old = self._stance_dv
        if old.shape[1] >= cap:
            return
        new = np.zeros((4, cap))
        for i in range(4):
            cnt = int(self._counts[K.STANCE_N + i])
            for j in range(max(0, cnt - old.shape[1]), cnt):
                new[i, j % cap] = old[i, j % old.shape[1]]
        self._stance_dv = new


_STANCE_DV_CAP0 = 20  # each leg's stance ΔV buffer before the ring is sized (the first tick's values)
_NO_OMEGA = np.zeros((4, 3))
