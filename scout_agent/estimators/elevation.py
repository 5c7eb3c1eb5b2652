"""Elevation from stance footholds (paper eq. 11–12) and the per-cell plane fit.

A foothold is the ground point under a non-slipping stance foot, in the map frame:
p = base_pos + world_R_base · p_foot_base − r · n̂, with p_foot_base the foot sphere centre from leg kinematics,
r the foot radius and n̂ the terrain normal (the paper takes the foot centre's z; removing the radius along the
normal makes the point lie on the ground, whatever the slope). n̂ comes from a plane fitted to the four most
recent footholds (proprioceptive), +z until there are three.

Cells keep summed moments with x, y relative to the cell centre (DESIGN "elevation" layer):
n, sum (Σz), sumsq (Σz²), sx, sy, sxx, syy, sxy, sxz, syz. `plane_from_moments` solves
z = z0 + gx·dx + gy·dy by least squares per cell, so that a cell whose points
lie on one line (one foot track) still gets a height: the slope is fitted only along directions the points
span (its unobservable component is set to zero).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from protocol.layers import plane_fit

__all__ = [
    "PLANE_STATS",
    "foothold_world",
    "plane_from_moments",
    "plane_moments",
    "slope_deg",
    "terrain_normal",
]

PLANE_STATS = ("n", "sum", "sumsq", "sx", "sy", "sxx", "syy", "sxy", "sxz", "syz")
_UP = np.array([0.0, 0.0, 1.0])


def terrain_normal(points: np.ndarray) -> np.ndarray:
    """Upward unit normal of the least-squares plane z = a + b·x + c·y through (k, 3) points; +z if k < 3."""
    if len(points) < 3:
        return _UP.copy()
    out = np.empty(3)
    _terrain_normal(np.asarray(points, dtype=float), out)
    return out


@njit(cache=True, nogil=True)
def _terrain_normal(points: np.ndarray, out: np.ndarray) -> None:
    """`terrain_normal` compiled (the state estimator refits it at every new foothold: 20 µs of small numpy
    operations, 0.7 µs here), numpy's arithmetic in numpy's order: the column means as numpy's add.reduce
    takes them (first row, then the others in turn, then ÷ k), the normal equations' products through
    BLAS (`np.dot`, as `@`); equal to the numpy form it replaced on 200,000 random point sets."""
    k = points.shape[0]
    mx, my, mz = points[0, 0], points[0, 1], points[0, 2]
    for i in range(1, k):
        mx += points[i, 0]
        my += points[i, 1]
        mz += points[i, 2]
    mx, my, mz = mx / k, my / k, mz / k
    xy = np.empty((k, 2))
    z = np.empty(k)
    for i in range(k):
        xy[i, 0] = points[i, 0] - mx
        xy[i, 1] = points[i, 1] - my
        z[i] = points[i, 2] - mz
    a = np.dot(xy.T, xy)
    det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    if abs(det) < 1e-12:
        out[0], out[1], out[2] = 0.0, 0.0, 1.0
        return
    rhs = np.dot(xy.T, z)
    b = (a[1, 1] * rhs[0] - a[0, 1] * rhs[1]) / det
    c = (a[0, 0] * rhs[1] - a[1, 0] * rhs[0]) / det
    n = np.array([-b, -c, 1.0])
    norm = math.sqrt(np.dot(n, n))
    out[0], out[1], out[2] = n[0] / norm, n[1] / norm, n[2] / norm


def foothold_world(
    base_pos: np.ndarray, world_R_base: np.ndarray, foot_base: np.ndarray, radius_m: float, normal: np.ndarray
) -> np.ndarray:
    """Ground contact point(s) [m], map frame: base_pos + R·foot_base − r·n̂. foot_base: (3,) or (k, 3)."""
    return base_pos + foot_base @ world_R_base.T - radius_m * normal


def plane_moments(x: np.ndarray, y: np.ndarray, z: np.ndarray, cx: np.ndarray, cy: np.ndarray) -> dict:
    """Per-point contributions to the elevation stats, x, y relative to the cell centre (cx, cy)."""
    dx = np.asarray(x, dtype=float) - cx
    dy = np.asarray(y, dtype=float) - cy
    z = np.asarray(z, dtype=float)
    return {
        "n": np.ones_like(z),
        "sum": z,
        "sumsq": z * z,
        "sx": dx,
        "sy": dy,
        "sxx": dx * dx,
        "syy": dy * dy,
        "sxy": dx * dy,
        "sxz": dx * z,
        "syz": dy * z,
    }


def plane_from_moments(stats: dict, min_spread_m: float = 0.03) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plane z = z0 + gx·dx + gy·dy per cell from summed moments (dx, dy about the cell centre): the map's own
    truncated fit (`protocol.layers.plane_fit`), so the scout, the server and the planner read one slope.
    Returns (z_centre [m], gx, gy) arrays; NaN where n == 0."""
    z0, gx, gy, _ = plane_fit(stats, min_spread_m)
    return z0, gx, gy


def slope_deg(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """Slope angle [deg] of the plane with gradient (gx, gy)."""
    return np.degrees(np.arctan(np.hypot(gx, gy)))
