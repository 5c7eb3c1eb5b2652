"""Foot positions and velocities relative to the base from Pinocchio, in one kinematics pass per tick.

`scout_agent.robot.kinematics.LegKinematics` answers `feet_base` and `feet_vel_base` separately (two passes
plus Jacobians, ≈ 14 µs); the estimators need both every tick, so `PinocchioFeet` runs one
`forwardKinematics(q, v)` on the same model and reads the four foot frames' placements and velocities
(≈ 6.5 µs). The base is held at the origin with zero velocity, so the results are relative to the base, in
the base frame.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from scout_agent.robot import constants as C

__all__ = ["PinocchioFeet"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class PinocchioFeet:
    """`feet_base_and_vel(q, dq)` → ((4, 3) positions [m], (4, 3) velocities [m/s]), base frame.

    The returned arrays are reused by the next call (copy them to keep them); `foot_omega` (4, 3) holds the
    feet's angular velocities from the same pass [rad/s] (the slip detector's rolling term).
    """

    def __init__(self, model: pin.Model | None = None) -> None:
        if model is None:
            from scout_agent.robot.kinematics import LegKinematics

            model = LegKinematics().model
        self.model = model
        self.data = model.createData()
        self.frames = [model.getFrameId(name) for name in C.FOOT_BODIES]
        self._q = pin.neutral(model)
        self._v = np.zeros(model.nv)
        self._pos = np.zeros((4, 3))
        self._vel = np.zeros((4, 3))
        self.foot_omega = np.zeros(
            (4, 3)
        )  # angular velocity of each foot (calf) relative to the base, base frame
        self.total_mass_kg = float(pin.computeTotalMass(model))
        q_home = pin.neutral(model)
        q_home[7:] = C.HOME_Q
        self.com_home_base = np.array(pin.centerOfMass(model, self.data, q_home))  # (3,) [m]

    def feet_base_and_vel(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m, d = self.model, self.data
        self._q[7:] = q
        self._v[6:] = dq
        pin.forwardKinematics(m, d, self._q, self._v)
        for i, f in enumerate(self.frames):
            self._pos[i] = pin.updateFramePlacement(m, d, f).translation
            v = pin.getFrameVelocity(m, d, f, _LWA)
            self._vel[i] = v.linear
            self.foot_omega[i] = v.angular
        return self._pos, self._vel

    def feet_base(self, q: np.ndarray) -> np.ndarray:
        return self.feet_base_and_vel(q, np.zeros(12))[0].copy()

    def feet_vel_base(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        return self.feet_base_and_vel(q, dq)[1].copy()
