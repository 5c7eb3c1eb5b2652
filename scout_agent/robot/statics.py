"""Leg statics: the ground force on each foot from the joint torques holding it (f = −J⁻ᵀ (τ − τ_g))."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def leg_forces_from_torques(jacobians: np.ndarray, tau: np.ndarray, tau_gravity: np.ndarray) -> np.ndarray:
    """Ground forces on the feet (4, 3), base frame [N], from leg Jacobians (4, 3, 3) (d foot / d leg joints,
    base frame), joint torques (12,) and the joints' gravity torques (12,): f = −J⁻ᵀ (τ − τ_g).
    Near-singular legs (a straight knee) give zeros rather than huge forces. Compiled (the estimators call it
    every tick); the same LAPACK solve per leg as numpy's, so the same figures."""
    out = np.zeros((4, 3))
    for i in range(4):
        Jt = np.ascontiguousarray(jacobians[i].T)
        if not abs(np.linalg.det(Jt)) > 1e-5:
            continue
        x = np.linalg.solve(Jt, tau[3 * i : 3 * i + 3] - tau_gravity[3 * i : 3 * i + 3])
        for j in range(3):
            out[i, j] = -x[j]
    return out


__all__ = ["leg_forces_from_torques"]
