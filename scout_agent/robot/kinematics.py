"""Leg kinematics in the base frame: Pinocchio from the same MJCF (`LegKinematics`), and a closed form
(`fk`, `jacobians`, `ik`; compiled with numba as `leg_kinematics` and `leg_ik`, which the controller calls every
tick).

All positions are foot-sphere centres relative to the trunk origin, in the trunk frame [m]; Jacobians are
d(foot position)/d(leg joints) in the trunk frame, one 3×3 block per leg (legs in `LEG_NAMES` order).
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
import pinocchio as pin
from numba import njit

from scout_agent.robot import constants as C
from scout_agent.robot.model import aliengo_mjcf

_SX = np.array([s[0] for s in C.LEG_SIGNS], dtype=float)  # (4,)
_SY = np.array([s[1] for s in C.LEG_SIGNS], dtype=float)  # (4,)
_L1 = C.THIGH_LENGTH
_L2 = C.CALF_LENGTH
_D = C.THIGH_OFFSET
_HIP = C.HIP_POS_BASE.copy()  # (4, 3)


@njit(cache=True, nogil=True)
def leg_kinematics(q: np.ndarray, feet: np.ndarray, J: np.ndarray) -> None:
    """Foot positions into `feet` (4, 3) and foot Jacobians into `J` (4, 3, 3), base frame, from joint angles
    (12,); compiled, so the controller's tick pays one call for both."""
    for i in range(4):
        a, t, c = q[3 * i], q[3 * i + 1], q[3 * i + 2]
        s1, c1 = np.sin(t), np.cos(t)
        s12, c12 = np.sin(t + c), np.cos(t + c)
        px = -_L1 * s1 - _L2 * s12
        pz = -_L1 * c1 - _L2 * c12
        py = _SY[i] * _D
        ca, sa = np.cos(a), np.sin(a)
        feet[i, 0] = _HIP[i, 0] + px
        feet[i, 1] = _HIP[i, 1] + py * ca - pz * sa
        feet[i, 2] = py * sa + pz * ca
        dpx_dt, dpz_dt = -_L1 * c1 - _L2 * c12, _L1 * s1 + _L2 * s12
        dpx_dc, dpz_dc = -_L2 * c12, _L2 * s12
        J[i, 0, 0] = 0.0
        J[i, 1, 0] = -py * sa - pz * ca
        J[i, 2, 0] = py * ca - pz * sa
        J[i, 0, 1] = dpx_dt
        J[i, 1, 1] = -dpz_dt * sa
        J[i, 2, 1] = dpz_dt * ca
        J[i, 0, 2] = dpx_dc
        J[i, 1, 2] = -dpz_dc * sa
        J[i, 2, 2] = dpz_dc * ca


@njit(cache=True, nogil=True)
def leg_motion(
    q: np.ndarray, dq: np.ndarray, feet: np.ndarray, vel: np.ndarray, omega: np.ndarray, J: np.ndarray
) -> None:
    """`leg_kinematics` plus each foot's velocity J·q̇ into `vel` (4, 3) and the foot's (calf's) angular
    velocity into `omega` (4, 3), all relative to the base, base frame, from joint angles and rates (12,).
    The hip turns about x, thigh and calf about the hip-rotated y axis: ω = (q̇_hip, (q̇_thigh + q̇_calf)
    cos a, (q̇_thigh + q̇_calf) sin a)."""
    leg_kinematics(q, feet, J)
    for i in range(4):
        for j in range(3):
            vel[i, j] = J[i, j, 0] * dq[3 * i] + J[i, j, 1] * dq[3 * i + 1] + J[i, j, 2] * dq[3 * i + 2]
        a, w = q[3 * i], dq[3 * i + 1] + dq[3 * i + 2]
        omega[i, 0] = dq[3 * i]
        omega[i, 1] = w * np.cos(a)
        omega[i, 2] = w * np.sin(a)


@njit(cache=True, nogil=True)
def leg_ik(p: np.ndarray, q: np.ndarray) -> None:
    """Joint angles into `q` (12,) placing the feet at `p` (4, 3), base frame; knees backwards (calf < 0).
    Unreachable targets are pulled onto the workspace boundary instead of raising."""
    for i in range(4):
        x, y, z = p[i, 0] - _HIP[i, 0], p[i, 1] - _HIP[i, 1], p[i, 2] - _HIP[i, 2]
        rho2 = max(y * y + z * z, _D * _D + 1e-6)
        L = np.sqrt(rho2 - _D * _D)
        a = np.arctan2(z, y) - np.arctan2(-L, _SY[i] * _D)
        a = (a + np.pi) % (2 * np.pi) - np.pi
        D2 = x * x + L * L
        cos_c = min(max((D2 - _L1 * _L1 - _L2 * _L2) / (2 * _L1 * _L2), -1.0), 0.999)
        c = -np.arccos(cos_c)
        q[3 * i] = a
        q[3 * i + 1] = np.arctan2(-x, L) - np.arctan2(_L2 * np.sin(c), _L1 + _L2 * np.cos(c))
        q[3 * i + 2] = c


def fk(q: np.ndarray) -> np.ndarray:
    """Foot positions (4, 3) in the base frame from joint angles (12,)."""
    feet = np.empty((4, 3))
    leg_kinematics(np.ascontiguousarray(q, dtype=float).reshape(12), feet, np.empty((4, 3, 3)))
    return feet


def jacobians(q: np.ndarray) -> np.ndarray:
    """Foot Jacobians (4, 3, 3) in the base frame: J[i] = d p_i / d (hip, thigh, calf)_i."""
    J = np.empty((4, 3, 3))
    leg_kinematics(np.ascontiguousarray(q, dtype=float).reshape(12), np.empty((4, 3)), J)
    return J


def ik(p: np.ndarray) -> np.ndarray:
    """Joint angles (12,) placing the feet at `p` (4, 3), base frame; knees backwards (calf < 0).

    Unreachable targets are pulled onto the workspace boundary instead of raising.
    """
    q = np.empty(12)
    leg_ik(np.ascontiguousarray(p, dtype=float).reshape(4, 3), q)
    return q


class LegKinematics:
    """Pinocchio model of the same MJCF the simulator runs; base fixed at the origin (trunk frame)."""

    def __init__(self) -> None:
        fd, path = tempfile.mkstemp(suffix=".xml")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(aliengo_mjcf())
            self.model = pin.buildModelFromMJCF(path)
        finally:
            os.unlink(path)
        self.data = self.model.createData()
        self.foot_frames = [self.model.getFrameId(name) for name in C.FOOT_BODIES]
        self._q = pin.neutral(self.model)  # base at identity; joints from index 7
        self._v = np.zeros(self.model.nv)

    def _set(self, q: np.ndarray) -> None:
        self._q[7:] = q
        pin.forwardKinematics(self.model, self.data, self._q)
        pin.updateFramePlacements(self.model, self.data)

    def feet_base(self, q: np.ndarray) -> np.ndarray:
        """Foot sphere centres (4, 3) relative to the base, base frame [m]."""
        self._set(q)
        return np.array([self.data.oMf[f].translation for f in self.foot_frames])

    def foot_jacobians_base(self, q: np.ndarray) -> np.ndarray:
        """(4, 3, 3): d foot / d leg joints, base frame."""
        self._set(q)
        pin.computeJointJacobians(self.model, self.data, self._q)
        out = np.empty((4, 3, 3))
        for i, f in enumerate(self.foot_frames):
            J = pin.getFrameJacobian(self.model, self.data, f, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            out[i] = J[:3, 6 + 3 * i : 9 + 3 * i]
        return out

    def feet_vel_base(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Foot velocities (4, 3) relative to the base (base held still), base frame [m/s]."""
        J = self.foot_jacobians_base(q)
        return np.einsum("lij,lj->li", J, dq.reshape(4, 3))
