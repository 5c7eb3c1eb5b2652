"""Swing-foot trajectories: a cubic (smoothstep) in xy and height plus a bump in z: h·(w·sin πs + (1 − w)·sin² πs),
so the foot lifts off and lands at w times the sine's vertical speed h·π/T (w = 1: the plain sine)."""

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
    land_share: float = 1.0,
) -> None:
    """`swing_point` into `pos`, `vel` (k, 3) (compiled; the controller's tick calls it)."""
    for i in range(s.shape[0]):
        si = min(max(s[i], 0.0), 1.0)
        b = si * si * (3.0 - 2.0 * si)
        db = 6.0 * si * (1.0 - si) / duration
        for j in range(3):
            pos[i, j] = p0[i, j] + (p1[i, j] - p0[i, j]) * b
            vel[i, j] = (p1[i, j] - p0[i, j]) * db
        sn, cs = np.sin(np.pi * si), np.cos(np.pi * si)
        w = land_share
        pos[i, 2] += height * (w * sn + (1.0 - w) * sn * sn)
        vel[i, 2] += height * np.pi * (w * cs + (1.0 - w) * 2.0 * sn * cs) / duration


def swing_point(
    p0: np.ndarray, p1: np.ndarray, s: np.ndarray, height: float, duration: float, land_share: float = 1.0
):
    """Position and velocity (k, 3) at progress `s` (k,) ∈ [0, 1] from lift-off `p0` to touchdown `p1`
    (k, 3), world frame; `duration` is the swing time [s]; `land_share` the share of the sine's vertical speed
    the foot lands with."""
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
        land_share,
    )
    return pos, vel
