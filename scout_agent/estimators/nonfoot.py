"""The external force the feet do not explain, from the whole robot's dynamics (the non-foot contact detector's
input).

Newton for the whole robot — trunk and legs — with the joints' dynamics, in the trunk frame:

    M(q)·a + h(q, v) = S·(τ − d·q̇) + Σ_feet J_iᵀ f_i + (non-foot contacts)

`M a + h` is the inverse dynamics (`robot.dynamics`: the recursive Newton–Euler algorithm on the simulated robot's
own model as Pinocchio reads it, its rotor inertia (armature) included) at the tick's accelerations: the trunk's from the accelerometer (the specific force at the
trunk origin, gravity folded in: in a uniform field an accelerated frame is the same physics) and the change of
the gyro's rate, the joints' from the change of the drivers' velocities since the last fresh reading. Each leg's
three rows give its foot's force, f_i = J_i⁻ᵀ (M a + h − τ + d·q̇)_leg, and the trunk's three force rows the
sum of all external forces; what that sum holds beyond the feet's is the non-foot force.

Why not the statics (f = −J⁻ᵀτ and m·a of the trunk alone), which it replaces: a leg has mass and a rotor, and
at lunar g the trot's touchdowns are impacts (truth 30–100 N on a foot for a tick where the motor torques read
13–19 N: the impulse goes into stopping the leg, not through the motor) and its flights move the legs against the
trunk (the trunk's acceleration is not the robot's). On the 100 m field (seed 33, 72 s around two false
"contact" stops, no non-foot contact in truth) the statics' low-passed residual reached 27 N (99th percentile
14.6 N, threshold 20 N); the dynamics' 12.7 N (99th percentile 5.0 N).

Feet: a foot counts when its contact flag was on at either end of the tick (its impulse may fall inside a tick
whose end finds it in the air: a foot bouncing on touchdown). A lost packet (`ProprioSample.fresh` False) repeats
the last readings: nothing is computed, and the next fresh one differences over the whole interval.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from numba import njit

from scout_agent.robot.dynamics import dynamics_params, inverse_dynamics
from scout_agent.robot.kinematics import LegKinematics
from scout_agent.robot.statics import solve_transposed
from scout_agent.signals import ProprioSample

__all__ = ["UnexplainedForce", "unexplained_tick"]


class UnexplainedForce:
    """`update(sample, R, jacobians)` → the tick's external force on the robot that its feet do not explain,
    world frame [N] (3,), or None when there is no new reading to difference (the first tick, a lost packet).
    `jacobians` (4, 3, 3): the legs' d foot / d joints at `sample.q`, base frame."""

    def __init__(self, model: pin.Model | None = None) -> None:
        model = model if model is not None else LegKinematics().model
        self._params = dynamics_params(model)  # the robot's links, inertias, axes, rotor inertias
        self._damping = np.array(model.damping[6:], dtype=float)  # (12,) joints' viscous damping
        self._prev = np.zeros(15)  # the last fresh tick's joint velocities (12) and trunk rate (3)
        self._contact_prev = np.zeros(4, bool)
        self._t_prev = math.nan
        self.force_w = np.zeros(3)  # the last result [N], world frame

    def interval(self, s: ProprioSample) -> float:
        """The time since the last fresh reading [s], this one now the last: NaN on the first, −1 for a lost
        packet (nothing new: the state stays)."""
        if not s.fresh:
            return -1.0
        t_prev, self._t_prev = self._t_prev, s.t
        return s.t - t_prev

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """`unexplained_tick`'s model and state arrays (updated in place): parameters, damping, the last fresh
        rates, contacts, the result."""
        return self._params, self._damping, self._prev, self._contact_prev, self.force_w

    def update(self, s: ProprioSample, rot: np.ndarray, jacobians: np.ndarray) -> np.ndarray | None:
        dt = self.interval(s)
        if dt == -1.0:
            return None
        params, damping, prev, contact_prev, force_w = self.state
        done = unexplained_tick(
            params,
            damping,
            s.q,
            s.dq,
            s.base.omega,
            s.imu_acc,
            s.tau,
            jacobians,
            s.contact,
            rot,
            dt,
            prev,
            contact_prev,
            force_w,
        )
        return force_w if done else None


@njit(cache=True, nogil=True)
def unexplained_tick(
    params: np.ndarray,
    damping: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    omega: np.ndarray,
    f_imu: np.ndarray,
    tau: np.ndarray,
    jacobians: np.ndarray,
    contact: np.ndarray,
    rot: np.ndarray,
    dt: float,
    prev: np.ndarray,
    contact_prev: np.ndarray,
    out_w: np.ndarray,
) -> bool:
    """One fresh tick (module docstring), compiled: the accelerations since the last fresh reading (`prev`: its
    joint velocities and trunk rate), the inverse dynamics, the trunk rows' force less the counted feet's
    forces (each from its leg's rows, Jᵀf = (M a + h − τ + d·q̇), `statics.solve_transposed`) rotated into the
    world, into `out_w`; then this tick becomes `prev`. False (nothing computed) when no time has passed since
    the last reading, or on the first (dt NaN)."""
    ok = dt > 0.0
    if ok:
        qdd = np.empty(12)
        omega_dot = np.empty(3)
        for j in range(12):
            qdd[j] = (dq[j] - prev[j]) / dt
        for k in range(3):
            omega_dot[k] = (omega[k] - prev[12 + k]) / dt
        tau_id = np.empty(18)
        inverse_dynamics(params, q, dq, omega, f_imu, omega_dot, qdd, tau_id)
        r0, r1, r2 = tau_id[0], tau_id[1], tau_id[2]
        for i in range(4):
            if not (contact[i] or contact_prev[i]):
                continue
            j, k = 6 + 3 * i, 3 * i
            solved, f0, f1, f2 = solve_transposed(
                jacobians[i],
                tau_id[j] - tau[k] + damping[k] * dq[k],
                tau_id[j + 1] - tau[k + 1] + damping[k + 1] * dq[k + 1],
                tau_id[j + 2] - tau[k + 2] + damping[k + 2] * dq[k + 2],
            )
            if solved:  # (a straight knee: its force is not known)
                r0, r1, r2 = r0 - f0, r1 - f1, r2 - f2
        for k in range(3):
            out_w[k] = rot[k, 0] * r0 + rot[k, 1] * r1 + rot[k, 2] * r2
    for j in range(12):
        prev[j] = dq[j]
    for k in range(3):
        prev[12 + k] = omega[k]
    for i in range(4):
        contact_prev[i] = contact[i]
    return ok
