"""Leg kinematics in the base frame: Pinocchio from the same MJCF (`LegKinematics`), and a closed form
(`fk`, `jacobians`, `ik`) the controller uses at every tick because it is allocation-light.

All positions are foot-sphere centres relative to the trunk origin, in the trunk frame [m]; Jacobians are
d(foot position)/d(leg joints) in the trunk frame, one 3×3 block per leg (legs in `LEG_NAMES` order).
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
import pinocchio as pin

from scout_agent.robot import constants as C
from scout_agent.robot.model import aliengo_mjcf

_SX = np.array([s[0] for s in C.LEG_SIGNS], dtype=float)  # (4,)
_SY = np.array([s[1] for s in C.LEG_SIGNS], dtype=float)  # (4,)
_L1 = C.THIGH_LENGTH
_L2 = C.CALF_LENGTH
_D = C.THIGH_OFFSET


def fk(q: np.ndarray) -> np.ndarray:
    """Foot positions (4, 3) in the base frame from joint angles (12,)."""
    q = q.reshape(4, 3)
    a, t, c = q[:, 0], q[:, 1], q[:, 2]
    px = -_L1 * np.sin(t) - _L2 * np.sin(t + c)
    pz = -_L1 * np.cos(t) - _L2 * np.cos(t + c)
    py = _SY * _D
    ca, sa = np.cos(a), np.sin(a)
    out = np.empty((4, 3))
    out[:, 0] = C.HIP_POS_BASE[:, 0] + px
    out[:, 1] = C.HIP_POS_BASE[:, 1] + py * ca - pz * sa
    out[:, 2] = py * sa + pz * ca
    return out


def jacobians(q: np.ndarray) -> np.ndarray:
    """Foot Jacobians (4, 3, 3) in the base frame: J[i] = d p_i / d (hip, thigh, calf)_i."""
    q = q.reshape(4, 3)
    a, t, c = q[:, 0], q[:, 1], q[:, 2]
    s1, c1 = np.sin(t), np.cos(t)
    s12, c12 = np.sin(t + c), np.cos(t + c)
    pz = -_L1 * c1 - _L2 * c12
    py = _SY * _D
    ca, sa = np.cos(a), np.sin(a)
    dpx_dt, dpz_dt = -_L1 * c1 - _L2 * c12, _L1 * s1 + _L2 * s12
    dpx_dc, dpz_dc = -_L2 * c12, _L2 * s12
    J = np.zeros((4, 3, 3))
    J[:, 1, 0] = -py * sa - pz * ca
    J[:, 2, 0] = py * ca - pz * sa
    J[:, 0, 1] = dpx_dt
    J[:, 1, 1] = -dpz_dt * sa
    J[:, 2, 1] = dpz_dt * ca
    J[:, 0, 2] = dpx_dc
    J[:, 1, 2] = -dpz_dc * sa
    J[:, 2, 2] = dpz_dc * ca
    return J


def ik(p: np.ndarray) -> np.ndarray:
    """Joint angles (12,) placing the feet at `p` (4, 3), base frame; knees backwards (calf < 0).

    Unreachable targets are pulled onto the workspace boundary instead of raising.
    """
    r = p - C.HIP_POS_BASE
    y, z = r[:, 1], r[:, 2]
    rho2 = np.maximum(y * y + z * z, _D * _D + 1e-6)
    L = np.sqrt(rho2 - _D * _D)
    a = np.arctan2(z, y) - np.arctan2(-L, _SY * _D)
    a = (a + np.pi) % (2 * np.pi) - np.pi
    x = r[:, 0]
    D2 = x * x + L * L
    cos_c = np.clip((D2 - _L1 * _L1 - _L2 * _L2) / (2 * _L1 * _L2), -1.0, 0.999)
    c = -np.arccos(cos_c)
    t = np.arctan2(-x, L) - np.arctan2(_L2 * np.sin(c), _L1 + _L2 * np.cos(c))
    return np.stack([a, t, c], axis=1).reshape(12)


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
