"""The external force the feet do not explain, from the whole robot's dynamics (the non-foot contact detector's
input).

Newton for the whole robot — trunk and legs — with the joints' dynamics, in the trunk frame:

    M(q)·a + h(q, v) = S·(τ − d·q̇) + Σ_feet J_iᵀ f_i + (non-foot contacts)

`M a + h` is the inverse dynamics (Pinocchio's RNEA on the simulated robot's own model, its rotor inertia
(armature) included) at the tick's accelerations: the trunk's from the accelerometer (the specific force at the
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

from scout_agent.robot.kinematics import LegKinematics
from scout_agent.robot.statics import solve_transposed
from scout_agent.signals import ProprioSample

__all__ = ["UnexplainedForce"]


class UnexplainedForce:
    """`update(sample, R, jacobians)` → the tick's external force on the robot that its feet do not explain,
    world frame [N] (3,), or None when there is no new reading to difference (the first tick, a lost packet).
    `jacobians` (4, 3, 3): the legs' d foot / d joints at `sample.q`, base frame."""

    def __init__(self, model: pin.Model | None = None) -> None:
        self.model = pin.Model(model if model is not None else LegKinematics().model)  # a copy: gravity off
        self.model.gravity.linear = np.zeros(3)  # folded into the trunk's acceleration (the specific force)
        self.data = self.model.createData()
        self._damping = np.array(self.model.damping[6:], dtype=float)  # (12,) joints' viscous damping
        self._q = pin.neutral(self.model)  # trunk at the origin: the result is in the trunk frame
        self._v = np.zeros(self.model.nv)
        self._a = np.zeros(self.model.nv)
        self._prev = np.zeros(15)  # the last fresh tick's joint velocities (12) and trunk rate (3)
        self._contact_prev = np.zeros(4, bool)
        self._t_prev = math.nan
        self.force_w = np.zeros(3)  # the last result [N], world frame

    def update(self, s: ProprioSample, rot: np.ndarray, jacobians: np.ndarray) -> np.ndarray | None:
        if not s.fresh:
            return None
        t_prev, self._t_prev = self._t_prev, s.t
        if not s.t > t_prev:  # the first reading (NaN), or no time passed
            _remember(s.dq, s.base.omega, s.contact, self._prev, self._contact_prev)
            return None
        _motion(s.q, s.dq, s.base.omega, s.imu_acc, self._prev, s.t - t_prev, self._q, self._v, self._a)
        tau_id = pin.rnea(self.model, self.data, self._q, self._v, self._a)
        _residual(
            tau_id, s.tau, s.dq, self._damping, jacobians, s.contact, self._contact_prev, rot, self.force_w
        )
        _remember(s.dq, s.base.omega, s.contact, self._prev, self._contact_prev)
        return self.force_w


@njit(cache=True, nogil=True)
def _remember(
    dq: np.ndarray, omega: np.ndarray, contact: np.ndarray, prev: np.ndarray, c_prev: np.ndarray
) -> None:
    for j in range(12):
        prev[j] = dq[j]
    for k in range(3):
        prev[12 + k] = omega[k]
    for i in range(4):
        c_prev[i] = contact[i]


@njit(cache=True, nogil=True)
def _motion(
    q: np.ndarray,
    dq: np.ndarray,
    omega: np.ndarray,
    f_imu: np.ndarray,
    prev: np.ndarray,
    dt: float,
    q_full: np.ndarray,
    v: np.ndarray,
    a: np.ndarray,
) -> None:
    """Pinocchio's configuration, velocity and acceleration of the free-flyer robot, trunk at the origin: the
    trunk's linear velocity zero (the forces do not depend on it: Galilean invariance) and its linear
    acceleration the specific force (gravity switched off in the model); angular and joint accelerations from
    the change since the last fresh reading."""
    for j in range(12):
        q_full[7 + j] = q[j]
        v[6 + j] = dq[j]
        a[6 + j] = (dq[j] - prev[j]) / dt
    for k in range(3):
        v[k] = 0.0
        v[3 + k] = omega[k]
        a[k] = f_imu[k]
        a[3 + k] = (omega[k] - prev[12 + k]) / dt


@njit(cache=True, nogil=True)
def _residual(
    tau_id: np.ndarray,
    tau: np.ndarray,
    dq: np.ndarray,
    damping: np.ndarray,
    jacobians: np.ndarray,
    contact: np.ndarray,
    contact_prev: np.ndarray,
    rot: np.ndarray,
    out_w: np.ndarray,
) -> None:
    """The trunk rows' force less the counted feet's forces (each from its leg's rows, Jᵀf = (M a + h − τ + d·q̇),
    `statics.solve_transposed`), rotated into the world, into `out_w`."""
    r0, r1, r2 = tau_id[0], tau_id[1], tau_id[2]
    for i in range(4):
        if not (contact[i] or contact_prev[i]):
            continue
        j, k = 6 + 3 * i, 3 * i
        ok, f0, f1, f2 = solve_transposed(
            jacobians[i],
            tau_id[j] - tau[k] + damping[k] * dq[k],
            tau_id[j + 1] - tau[k + 1] + damping[k + 1] * dq[k + 1],
            tau_id[j + 2] - tau[k + 2] + damping[k + 2] * dq[k + 2],
        )
        if ok:  # (a straight knee: its force is not known)
            r0, r1, r2 = r0 - f0, r1 - f1, r2 - f2
    for k in range(3):
        out_w[k] = rot[k, 0] * r0 + rot[k, 1] * r1 + rot[k, 2] * r2
