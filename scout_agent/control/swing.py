"""Swing-foot trajectories: a cubic (smoothstep) in xy and height plus a sine bump in z."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def swing_point_into(
    p0: np.ndarray,
    p1: np.ndarray,
    s: np.ndarray,
    height: float,
    duration: float,
    pos: np.ndarray,
    vel: np.ndarray,
) -> None:
    """`swing_point` into `pos`, `vel` (k, 3) (compiled; the controller's tick calls it)."""
    for i in range(s.shape[0]):
        si = min(max(s[i], 0.0), 1.0)
        b = si * si * (3.0 - 2.0 * si)
        db = 6.0 * si * (1.0 - si) / duration
        for j in range(3):
            pos[i, j] = p0[i, j] + (p1[i, j] - p0[i, j]) * b
            vel[i, j] = (p1[i, j] - p0[i, j]) * db
        pos[i, 2] += height * np.sin(np.pi * si)
        vel[i, 2] += height * np.pi * np.cos(np.pi * si) / duration


def swing_point(p0: np.ndarray, p1: np.ndarray, s: np.ndarray, height: float, duration: float):
    """Position and velocity (k, 3) at progress `s` (k,) ∈ [0, 1] from lift-off `p0` to touchdown `p1`
    (k, 3), world frame; `duration` is the swing time [s]."""
    k = len(s)
    pos, vel = np.empty((k, 3)), np.empty((k, 3))
    swing_point_into(
        np.asarray(p0, dtype=float),
        np.asarray(p1, dtype=float),
        np.asarray(s, dtype=float),
        height,
        duration,
        pos,
        vel,
    )
    return pos, vel
