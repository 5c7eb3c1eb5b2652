"""Leg statics: the ground force on each foot from the joint torques holding it (f = −J⁻ᵀ (τ − τ_g)), and the
joints' gravity torques τ_g of the legs' own links (hip, thigh, calf, foot: `constants`, Unitree's published
inertials, the model the simulated robot is built from, as a maker's model of its robot would be; computed by
Pinocchio on that model)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from numba import njit

from scout_agent.robot.kinematics import LegKinematics

_GRAVITY_MODEL: tuple[pin.Model, pin.Data, np.ndarray] | None = None  # built on first use


def leg_gravity_torques(q: np.ndarray, gravity_base: np.ndarray, out: np.ndarray) -> None:
    """The joint torques (12,) that hold the legs' own links against gravity, into `out` [N·m], the legs at rest
    (no Coriolis terms): Pinocchio's generalized gravity on the model of the MJCF the simulator runs
    (`kinematics.LegKinematics`), the base held at identity and `gravity_base` g_b the gravity acceleration in the
    base frame [m/s²] (R_worldᵀ·(0, 0, −g)). Within 1e-9 N·m of MuJoCo's bias forces
    (tests/scout_agent/test_statics.py); ≈ 1 µs a call."""
    global _GRAVITY_MODEL
    if _GRAVITY_MODEL is None:
        model = LegKinematics().model  # a model of its own: its gravity is set per call
        _GRAVITY_MODEL = (model, model.createData(), pin.neutral(model))
    model, data, q_full = _GRAVITY_MODEL
    model.gravity.linear = np.asarray(gravity_base, dtype=float)
    q_full[7:] = q
    out[:] = pin.computeGeneralizedGravity(model, data, q_full)[6:]


@njit(cache=True, nogil=True)
def solve_transposed(J: np.ndarray, b0: float, b1: float, b2: float) -> tuple[bool, float, float, float]:
    """x with Jᵀx = b for one leg's 3×3 Jacobian J, in closed form (the adjugate over the determinant: no
    allocations, ≈ 10× faster than a LAPACK call; agrees with it to ≈ 1e-15 relative for the Aliengo's
    well-conditioned legs). (False, 0, 0, 0) for a near-singular leg (a straight knee: |det J| ≤ 1e-5)."""
    # A = Jᵀ: A[r, c] = J[c, r]
    a00, a01, a02 = J[0, 0], J[1, 0], J[2, 0]
    a10, a11, a12 = J[0, 1], J[1, 1], J[2, 1]
    a20, a21, a22 = J[0, 2], J[1, 2], J[2, 2]
    c00 = a11 * a22 - a12 * a21
    c01 = a12 * a20 - a10 * a22
    c02 = a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    if not abs(det) > 1e-5:
        return False, 0.0, 0.0, 0.0
    inv = 1.0 / det
    return (
        True,
        (c00 * b0 + (a02 * a21 - a01 * a22) * b1 + (a01 * a12 - a02 * a11) * b2) * inv,
        (c01 * b0 + (a00 * a22 - a02 * a20) * b1 + (a02 * a10 - a00 * a12) * b2) * inv,
        (c02 * b0 + (a01 * a20 - a00 * a21) * b1 + (a00 * a11 - a01 * a10) * b2) * inv,
    )


@njit(cache=True, nogil=True)
def leg_forces_from_torques(jacobians: np.ndarray, tau: np.ndarray, tau_gravity: np.ndarray) -> np.ndarray:
    """Ground forces on the feet (4, 3), base frame [N], from leg Jacobians (4, 3, 3) (d foot / d leg joints,
    base frame), joint torques (12,) and the joints' gravity torques (12,): f = −J⁻ᵀ (τ − τ_g).
    Near-singular legs (a straight knee) give zeros rather than huge forces. Compiled (the estimators call it
    every tick); each leg's 3×3 system Jᵀx = τ − τ_g solved in closed form (`solve_transposed`)."""
    out = np.zeros((4, 3))
    for i in range(4):
        ok, x0, x1, x2 = solve_transposed(
            jacobians[i],
            tau[3 * i] - tau_gravity[3 * i],
            tau[3 * i + 1] - tau_gravity[3 * i + 1],
            tau[3 * i + 2] - tau_gravity[3 * i + 2],
        )
        if ok:
            out[i, 0], out[i, 1], out[i, 2] = -x0, -x1, -x2
    return out


__all__ = ["leg_forces_from_torques", "leg_gravity_torques", "solve_transposed"]
