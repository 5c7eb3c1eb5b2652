"""Leg statics: the ground force on each foot from the joint torques holding it (f = −J⁻ᵀ (τ − τ_g)), and the
joints' gravity torques τ_g of the legs' own links (hip, thigh, calf, foot: `constants`, Unitree's published
inertials, the model the simulated robot is built from, as a maker's model of its robot would be)."""

from __future__ import annotations

import numpy as np
from numba import njit

from scout_agent.robot import constants as C

_SX = np.array([s[0] for s in C.LEG_SIGNS], dtype=float)  # (4,)
_SY = np.array([s[1] for s in C.LEG_SIGNS], dtype=float)  # (4,)
_HIP = C.HIP_POS_BASE.copy()  # (4, 3) hip ab/ad joints, base frame [m]
_HIP_COM = np.array(C.HIP_COM)  # front-left leg's, hip frame (x flips for rear legs, y for right legs) [m]
_THIGH_COM = np.array(C.THIGH_COM)  # left leg's, thigh frame (y flips for right legs) [m]
_CALF_COM = np.array(C.CALF_COM)  # calf frame [m]
_M_HIP, _M_THIGH, _M_CALF, _M_FOOT = C.HIP_MASS, C.THIGH_MASS, C.CALF_MASS, C.FOOT_MASS
_M_BELOW_HIP = _M_THIGH + _M_CALF + _M_FOOT  # [kg]
_M_BELOW_THIGH = _M_CALF + _M_FOOT  # [kg]


@njit(cache=True, nogil=True)
def _leg_moment(i: int, a: float, t: float, c: float) -> np.ndarray:
    """Σ m·p of leg i's links (hip, thigh, calf, foot) about the base origin, base frame [kg·m], at joint angles
    (hip ab/ad a about x, thigh t and calf c about y: `model.aliengo_mjcf`'s chain)."""
    sx, sy = _SX[i], _SY[i]
    ct, st = np.cos(t), np.sin(t)
    ctc, stc = np.cos(t + c), np.sin(t + c)
    # calf and foot in the thigh frame (thigh joint at the origin): Ry(t)·((0, 0, −L1) + Ry(c)·p)
    cc = _CALF_COM
    x = _M_CALF * (cc[0] * ctc + cc[2] * stc) + _M_BELOW_THIGH * (-C.THIGH_LENGTH * st)
    x += _M_FOOT * (-C.CALF_LENGTH * stc)
    z = _M_CALF * (-cc[0] * stc + cc[2] * ctc) + _M_BELOW_THIGH * (-C.THIGH_LENGTH * ct)
    z += _M_FOOT * (-C.CALF_LENGTH * ctc)
    y = _M_CALF * cc[1]
    # the thigh's own COM, rotated by t
    tc0, tc1, tc2 = _THIGH_COM[0], sy * _THIGH_COM[1], _THIGH_COM[2]
    x += _M_THIGH * (tc0 * ct + tc2 * st)
    z += _M_THIGH * (-tc0 * st + tc2 * ct)
    y += _M_THIGH * tc1
    # in the hip frame: the thigh joint sits at (0, sy·D, 0); the hip's own COM
    y += _M_BELOW_HIP * sy * C.THIGH_OFFSET
    x += _M_HIP * sx * _HIP_COM[0]
    y += _M_HIP * sy * _HIP_COM[1]
    z += _M_HIP * _HIP_COM[2]
    # rotated by a about x, moved to the hip joint
    ca, sa = np.cos(a), np.sin(a)
    m_leg = _M_HIP + _M_BELOW_HIP
    out = np.empty(3)
    out[0] = m_leg * _HIP[i, 0] + x
    out[1] = m_leg * _HIP[i, 1] + y * ca - z * sa
    out[2] = m_leg * _HIP[i, 2] + y * sa + z * ca
    return out


@njit(cache=True, nogil=True)
def leg_gravity_torques(q: np.ndarray, gravity_base: np.ndarray, out: np.ndarray) -> None:
    """The joint torques (12,) that hold the legs' own links against gravity, into `out` [N·m]:
    τ_g = −(∂(Σ m·p)/∂q)ᵀ g_b, with `gravity_base` g_b the gravity acceleration in the base frame [m/s²]
    (R_worldᵀ·(0, 0, −g)); the legs at rest (no Coriolis terms). Derivatives by central differences of
    `_leg_moment` (h = 1e-6 rad: within 1e-9 N·m of MuJoCo's bias forces, tests/scout_agent/test_statics.py)."""
    h = 1e-6
    qp = np.empty(3)
    qm = np.empty(3)
    for i in range(4):
        for j in range(3):
            for k in range(3):
                qp[k] = q[3 * i + k]
                qm[k] = q[3 * i + k]
            qp[j] += h
            qm[j] -= h
            d = (_leg_moment(i, qp[0], qp[1], qp[2]) - _leg_moment(i, qm[0], qm[1], qm[2])) / (2.0 * h)
            out[3 * i + j] = -(d[0] * gravity_base[0] + d[1] * gravity_base[1] + d[2] * gravity_base[2])


@njit(cache=True, nogil=True)
def leg_forces_from_torques(jacobians: np.ndarray, tau: np.ndarray, tau_gravity: np.ndarray) -> np.ndarray:
    """Ground forces on the feet (4, 3), base frame [N], from leg Jacobians (4, 3, 3) (d foot / d leg joints,
    base frame), joint torques (12,) and the joints' gravity torques (12,): f = −J⁻ᵀ (τ − τ_g).
    Near-singular legs (a straight knee: |det J| ≤ 1e-5) give zeros rather than huge forces. Compiled (the
    estimators call it every tick); each leg's 3×3 system Jᵀx = τ − τ_g solved in closed form (the adjugate
    over the determinant: no allocations, ≈ 10× faster than a LAPACK call per leg; agrees with it to
    ≈ 1e-15 relative for the Aliengo's well-conditioned legs)."""
    out = np.zeros((4, 3))
    for i in range(4):
        J = jacobians[i]
        # A = Jᵀ: A[r, c] = J[c, r]
        a00, a01, a02 = J[0, 0], J[1, 0], J[2, 0]
        a10, a11, a12 = J[0, 1], J[1, 1], J[2, 1]
        a20, a21, a22 = J[0, 2], J[1, 2], J[2, 2]
        c00 = a11 * a22 - a12 * a21
        c01 = a12 * a20 - a10 * a22
        c02 = a10 * a21 - a11 * a20
        det = a00 * c00 + a01 * c01 + a02 * c02
        if not abs(det) > 1e-5:
            continue
        b0 = tau[3 * i] - tau_gravity[3 * i]
        b1 = tau[3 * i + 1] - tau_gravity[3 * i + 1]
        b2 = tau[3 * i + 2] - tau_gravity[3 * i + 2]
        inv = 1.0 / det
        out[i, 0] = -(c00 * b0 + (a02 * a21 - a01 * a22) * b1 + (a01 * a12 - a02 * a11) * b2) * inv
        out[i, 1] = -(c01 * b0 + (a00 * a22 - a02 * a20) * b1 + (a02 * a10 - a00 * a12) * b2) * inv
        out[i, 2] = -(c02 * b0 + (a01 * a20 - a00 * a21) * b1 + (a00 * a11 - a01 * a10) * b2) * inv
    return out


__all__ = ["leg_forces_from_torques", "leg_gravity_torques"]
