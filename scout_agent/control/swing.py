"""Swing-foot trajectories: a cubic (smoothstep) in xy and height plus a sine bump in z."""

from __future__ import annotations

import numpy as np


def swing_point(p0: np.ndarray, p1: np.ndarray, s: np.ndarray, height: float, duration: float):
    """Position and velocity (k, 3) at progress `s` (k,) ∈ [0, 1] from lift-off `p0` to touchdown `p1`
    (k, 3), world frame; `duration` is the swing time [s]."""
    s = np.clip(s, 0.0, 1.0)[:, None]
    b = s * s * (3.0 - 2.0 * s)
    db = 6.0 * s * (1.0 - s) / duration
    pos = p0 + (p1 - p0) * b
    vel = (p1 - p0) * db
    pos[:, 2:3] += height * np.sin(np.pi * s)
    vel[:, 2:3] += height * np.pi * np.cos(np.pi * s) / duration
    return pos, vel
