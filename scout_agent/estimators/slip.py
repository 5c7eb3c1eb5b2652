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
- ``"default"`` (what worked on this machine, see REFERENCE "Estimators"), each a departure from the paper:
  1. ΔP is the vector distance ‖x_des − x‖: the norm difference of eq. 2 is blind to a slip perpendicular to x
     and halves one along it.
  2. The ΔV flag is sticky within a stance and confirmed by ΔP: ΔV peaks at slip onset, ΔP builds up later, so
     "both at the same instant" (eq. 3) almost never holds.
  3. Touchdown is the first contact flag inside the gait's planned stance and is never re-taken inside it:
     contact flicker otherwise resets the reference and hides the displacement.
  4. The first `settle_s` of each stance is skipped (impact transients).

Both forms: ε_v is the `eps_v_percentile` percentile of the ΔV values of contact feet over the last
`eps_v_window_s`, never below `eps_v_floor` (the floor is ours: with no slips the percentile alone sits in the
noise), recomputed every `eps_v_every` ticks to keep the per-tick cost low; ε_p is fixed; at most one event per
foot per planned stance. The base position used for x_des is integrated from the base velocity the robot
knows, so only relative motion within a stance matters (no dependence on absolute position drift).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SlipConfig", "SlipDetector", "SlipTick", "delta_p_paper", "delta_p_vector", "delta_v"]


@dataclass(frozen=True)
class SlipConfig:
    form: str = "default"  # "default" | "paper"
    eps_p_m: float = 0.02  # ε_p [m]
    h_mps: float = 0.05  # h in eq. 1 [m/s]
    eps_v_percentile: float = 95.0  # ε_v = this percentile of recent ΔV
    eps_v_window_s: float = 1.5  # window of recent ΔV [s]
    eps_v_floor: float = 1.5  # ε_v never below this (dimensionless, like ΔV)
    eps_v_every: int = 25  # recompute ε_v every this many ticks
    settle_s: float = 0.05  # start-of-stance settling skipped [s] (default form)
    nominal_dt_s: float = 0.002  # control period used to size the ΔV ring buffer [s]

    def __post_init__(self) -> None:
        if self.form not in ("default", "paper"):
            raise ValueError(f"slip form {self.form!r} unknown; forms: default, paper")


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


@dataclass(frozen=True, slots=True)
class SlipTick:
    """What the detector saw at one tick (arrays of the 4 legs, LEG_NAMES order)."""

    touchdown: np.ndarray  # (4,) bool, the stance's reference was taken this tick
    event: np.ndarray  # (4,) bool, a slip event was declared this tick (at most once per stance)
    stance_end: np.ndarray  # (4,) bool, the planned stance ended this tick (after a touchdown)
    slipped: np.ndarray  # (4,) bool, this stance (current, or the one just ended) holds a slip event
    settled: np.ndarray  # (4,) bool, in contact inside a touched-down stance, past the settling time
    dv: np.ndarray  # (4,) ΔV
    dp: np.ndarray  # (4,) ΔP of the configured form [m]
    eps_v: float  # current ε_v


class SlipDetector:
    """Stateful detector for the 4 legs; feed it one tick at a time with `update`."""

    def __init__(self, config: SlipConfig | None = None) -> None:
        self.config = config or SlipConfig()
        c = self.config
        self._paper = c.form == "paper"
        n = max(1, int(round(c.eps_v_window_s / c.nominal_dt_s)))
        self._ring = np.zeros((n, 4))
        self._ring_ok = np.zeros((n, 4), dtype=bool)
        self._ring_i = 0
        self._ring_full = False
        self._tick = 0
        self.eps_v = c.eps_v_floor
        self._t_prev: float | None = None
        self._p_base = np.zeros(3)  # base position integrated from the known velocity [m]
        self._planned_prev = np.zeros(4, dtype=bool)
        self._contact_prev = np.zeros(4, dtype=bool)
        self._touched = np.zeros(4, dtype=bool)
        self._t_td = np.zeros(4)
        self._p_td = np.zeros((4, 3))  # touchdown foot points, integration frame [m]
        self._vflag = np.zeros(4, dtype=bool)
        self._slipped = np.zeros(4, dtype=bool)

    def reset(self) -> None:
        self.__init__(self.config)  # type: ignore[misc]

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
    ) -> SlipTick:
        c = self.config
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        self._p_base += base_vel_world * dt
        v_b = base_vel_world @ world_R_base  # R^T v
        vel_des = -(v_b + np.cross(base_omega, foot_pos))
        dv = delta_v(vel_des, foot_vel, c.h_mps)

        planned = stance_planned
        stance_end = self._planned_prev & ~planned & self._touched
        ended_slipped = stance_end & self._slipped
        # a new planned stance clears the per-stance state
        start = planned & ~self._planned_prev
        if start.any() or stance_end.any():
            clear = start | stance_end
            self._touched[clear] = False
            self._vflag[clear] = False
            self._slipped[clear] = False
        if self._paper:
            touchdown = contact & ~self._contact_prev & planned
        else:
            touchdown = contact & planned & ~self._touched
        if touchdown.any():
            self._touched |= touchdown
            self._t_td[touchdown] = t
            self._p_td[touchdown] = self._p_base + foot_pos[touchdown] @ world_R_base.T
            if self._paper:
                self._vflag[touchdown] = False
        # x_des: touchdown point in the base frame now
        pos_des = (self._p_td - self._p_base) @ world_R_base
        active = self._touched & contact & planned
        if self._paper:
            dp = delta_p_paper(pos_des, foot_pos)
            settled = active
            cand = settled & (dv > self.eps_v) & (dp > c.eps_p_m)
        else:
            dp = delta_p_vector(pos_des, foot_pos)
            settled = active & (t - self._t_td >= c.settle_s - 1e-9)
            self._vflag |= settled & (dv > self.eps_v)
            cand = settled & self._vflag & (dp > c.eps_p_m)
        event = cand & ~self._slipped
        self._slipped |= event
        self._push_dv(dv, settled)
        self._planned_prev = planned.copy()
        self._contact_prev = contact.copy()
        return SlipTick(
            touchdown=touchdown,
            event=event,
            stance_end=stance_end,
            slipped=self._slipped | ended_slipped,
            settled=settled,
            dv=dv,
            dp=dp,
            eps_v=self.eps_v,
        )

    def _push_dv(self, dv: np.ndarray, ok: np.ndarray) -> None:
        i = self._ring_i
        self._ring[i] = dv
        self._ring_ok[i] = ok
        self._ring_i = (i + 1) % len(self._ring)
        if self._ring_i == 0:
            self._ring_full = True
        self._tick += 1
        if self._tick % self.config.eps_v_every == 0:
            vals = self._ring[self._ring_ok] if self._ring_full else self._ring[: self._ring_i][
                self._ring_ok[: self._ring_i]
            ]
            if vals.size >= 10:
                p = float(np.percentile(vals, self.config.eps_v_percentile))
                self.eps_v = max(p, self.config.eps_v_floor)
