"""Foot positions and velocities relative to the base, in one kinematics pass per tick.

The robot's mass and CoM come from the Pinocchio model of the same MJCF the simulator runs. The per-tick
feet (positions, velocities, the feet's angular velocities) come from the compiled closed form
`scout_agent.robot.kinematics.leg_motion` (≈ 0.5 µs a tick; Pinocchio's `forwardKinematics(q, v)` and four
frame reads cost ≈ 16 µs from Python), which the tests check against Pinocchio and MuJoCo. The base is held at
the origin with zero velocity, so the results are relative to the base, in the base frame.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from scout_agent.robot import constants as C
from scout_agent.robot.kinematics import LegKinematics, leg_motion

__all__ = ["PinocchioFeet"]


class PinocchioFeet:
    """`feet_base_and_vel(q, dq)` → ((4, 3) positions [m], (4, 3) velocities [m/s]), base frame.

    The returned arrays are reused by the next call (copy them to keep them); `foot_omega` (4, 3) holds the
    feet's angular velocities from the same pass [rad/s] (the slip detector's rolling term) and `jacobians`
    (4, 3, 3) the legs' Jacobians d foot / d leg joints, base frame (`kinematics.jacobians` of that q).
    """

    def __init__(self, model: pin.Model | None = None) -> None:
        if model is None:
            model = LegKinematics().model
        self.model = model
        self.data = model.createData()
        self.frames = [model.getFrameId(name) for name in C.FOOT_BODIES]
        self._q = pin.neutral(model)
        self._v = np.zeros(model.nv)
        self._pos = np.zeros((4, 3))
        self._vel = np.zeros((4, 3))
        self._J = np.zeros((4, 3, 3))
        self.jacobians = self._J  # the last pass's (filled in place)
        self.foot_omega = np.zeros(
            (4, 3)
        )  # angular velocity of each foot (calf) relative to the base, base frame
        self.total_mass_kg = float(pin.computeTotalMass(model))
        q_home = pin.neutral(model)
        q_home[7:] = C.HOME_Q
        self.com_home_base = np.array(pin.centerOfMass(model, self.data, q_home))  # (3,) [m]

    def feet_base_and_vel(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        leg_motion(
            np.ascontiguousarray(q, dtype=float),
            np.ascontiguousarray(dq, dtype=float),
            self._pos,
            self._vel,
            self.foot_omega,
            self._J,
        )
        return self._pos, self._vel

    def buffers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The arrays `feet_base_and_vel` fills in place: positions, velocities, angular velocities (4, 3),
        Jacobians (4, 3, 3) (for a compiled caller that runs `kinematics.leg_motion` on them itself)."""
        return self._pos, self._vel, self.foot_omega, self._J

    def feet_base(self, q: np.ndarray) -> np.ndarray:
        return self.feet_base_and_vel(q, np.zeros(12))[0].copy()

    def feet_vel_base(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        return self.feet_base_and_vel(q, dq)[1].copy()
