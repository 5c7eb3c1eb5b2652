"""Gravito-inertial stability margins GIIM and GIAM (paper eq. 8–10; Uno et al. 2022, Ribeiro et al. 2020).

GIA a = g − a_CoM (eq. 8), in the world frame. Two proprioceptive sources:

- `gia_from_forces`: a = −Σ f_contact / m. In simulation the foot contact forces stand in for foot force
  sensors (the Aliengo has foot contact sensors, not 3-axis load cells: this is the simulator's help, said so).
- `gia_from_imu`: a ≈ −world_R_base · f_imu, the accelerometer's specific force rotated into the world
  (ignores the lever arm between IMU and CoM).

Support polygon (default): the four most recent footholds, each foot's current or last stance point, sorted
counter-clockwise about their centroid seen from above (not in leg order). In a trot only two feet stand at
once; over those two every margin is ≤ 0 (kept as `support="stance"`, a diagnostic only). For each
consecutive pair (a, b): n_ab = (p_G − p_a) × (p_G − p_b), outward and upward;
GIIM_ab = acos(n̂·â) − π/2 [rad], GIAM_ab = −n̂·a [m/s²]; margins = min over faces; identity
GIAM_ab = ‖a‖·sin(GIIM_ab). Faces with ‖n‖ ≈ 0 are skipped; fewer than 2 points → NaN; 2 points → the two
opposite faces, so the margin is ≤ 0.

`variant="paper"`: the reading that reproduces the paper's averages (docs/physics.md: they match the front/rear
faces of a static stance): the points in leg order FL, FR, RL, RR (cyclic faces, which cross the polygon's
diagonals) and the absolute value of the minimum. It is not a stability margin (it is ≥ 0 even when the GIA
leaves the support); kept only to compare with the paper's numbers.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from scout_agent.errors import ScoutConfigError

__all__ = [
    "gia_from_forces",
    "gia_from_imu",
    "margins",
    "margins_fast",
    "margins_per_face",
    "order_ccw",
    "order_ccw_xy",
]

_EPS_N = 1e-9


def gia_from_forces(foot_force_world: np.ndarray, mass_kg: float) -> np.ndarray:
    """a = −Σ f / m [m/s²], world frame. foot_force_world: (k, 3) ground reaction forces [N]."""
    return -foot_force_world.sum(axis=0) / mass_kg


def gia_from_imu(imu_acc_base: np.ndarray, world_R_base: np.ndarray) -> np.ndarray:
    """a = −R·f_imu [m/s²], world frame, from the accelerometer's specific force (base frame)."""
    return -(world_R_base @ imu_acc_base)


def order_ccw(points: np.ndarray) -> np.ndarray:
    """Indices sorting (k, 3) points counter-clockwise about their centroid, seen from above (+z)."""
    c = points[:, :2].mean(axis=0)
    return np.argsort(np.arctan2(points[:, 1] - c[1], points[:, 0] - c[0]), kind="stable")


def margins_per_face(points: np.ndarray, p_g: np.ndarray, gia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GIIM [rad] and GIAM [m/s²] of the faces (points[i], points[i+1 mod k]), in the given order.

    points: (k, 3) support points, world frame [m]; p_g: (3,) CoM; gia: (3,) [m/s²]. Faces with ‖n‖ ≈ 0 get NaN.
    """
    u = points - p_g  # (k, 3) = −(p_G − p_a)
    n = np.cross(u, np.roll(u, -1, axis=0))  # (p_G − p_a) × (p_G − p_b) = u_a × u_b
    nn = np.sqrt(np.einsum("ij,ij->i", n, n))
    ok = nn > _EPS_N * max(1.0, float(np.abs(u).max()) ** 2)
    nhat = n / np.where(ok, nn, 1.0)[:, None]
    proj = nhat @ gia  # n̂·a
    a_norm = math.sqrt(float(gia @ gia))
    cosang = np.clip(proj / a_norm, -1.0, 1.0) if a_norm > 0 else np.zeros_like(proj)
    giim = np.arccos(cosang) - math.pi / 2
    giam = -proj
    giim[~ok] = np.nan
    giam[~ok] = np.nan
    return giim, giam


def margins(
    points: np.ndarray, p_g: np.ndarray, gia: np.ndarray, variant: str = "correct"
) -> tuple[float, float]:
    """(GIIM [rad], GIAM [m/s²]) = minima over the faces of the support `points` (k, 3).

    variant "correct": points sorted counter-clockwise about their centroid, min over faces.
    variant "paper": points taken in the order given (leg order), |min| over faces.
    """
    k = len(points)
    if k < 2:
        return math.nan, math.nan
    if variant == "correct":
        pts = points[order_ccw(points)] if k > 2 else points
    elif variant == "paper":
        pts = points
    else:
        raise ScoutConfigError(f"margin variant {variant!r} unknown; variants: correct, paper")
    giim, giam = margins_per_face(pts, p_g, gia)
    if np.isnan(giim).all():
        return math.nan, math.nan
    m_i, m_a = float(np.nanmin(giim)), float(np.nanmin(giam))
    if variant == "paper":
        return abs(m_i), abs(m_a)
    return m_i, m_a


def order_ccw_xy(points: list[list[float]]) -> list[int]:
    """`order_ccw` on a short list of [x, y, ...] points (Python scalars: cheaper than numpy at k ≤ 4)."""
    k = len(points)
    cx = sum(p[0] for p in points) / k
    cy = sum(p[1] for p in points) / k
    return sorted(range(k), key=lambda i: math.atan2(points[i][1] - cy, points[i][0] - cx))


def margins_fast(
    points: list[list[float]],
    p_g: list[float] | tuple[float, ...],
    gia: list[float] | tuple[float, ...],
    absolute: bool = False,
) -> tuple[float, float]:
    """`margins` for points already in face order (the per-tick path: compiled, `_face_margins`).

    Uses GIIM_ab = asin(GIAM_ab / ‖a‖) (the identity above), so only the faces' GIAM is needed and the face
    with the least GIAM also has the least GIIM. `absolute` gives the paper variant's |min|.
    """
    if len(points) < 2:
        return math.nan, math.nan
    (px, py, pz), (gx, gy, gz) = p_g, gia
    giim, giam = _face_margins(np.array(points, dtype=float), px, py, pz, gx, gy, gz, _EPS_N)
    if absolute:
        return abs(giim), abs(giam)
    return giim, giam


@njit(cache=True, nogil=True)
def _face_margins(
    pts: np.ndarray, px: float, py: float, pz: float, gx: float, gy: float, gz: float, tol: float
) -> tuple[float, float]:
    """(GIIM, GIAM) of the support polygon `pts` (k, 3) in face order about the CoM (px, py, pz) under the
    GIA (gx, gy, gz): the least GIAM over the faces whose normal is longer than `tol` (degenerate faces of a
    robot's ~0.1 m² support are skipped), and its GIIM = asin(GIAM / ‖a‖); NaN without a face."""
    k = pts.shape[0]
    a_norm = math.sqrt(gx * gx + gy * gy + gz * gz)
    if k < 2 or a_norm == 0.0:
        return math.nan, math.nan
    best = math.inf
    for i in range(k):
        j = (i + 1) % k
        ux, uy, uz = pts[i, 0] - px, pts[i, 1] - py, pts[i, 2] - pz
        wx, wy, wz = pts[j, 0] - px, pts[j, 1] - py, pts[j, 2] - pz
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        if nn <= tol:
            continue
        giam = -(nx * gx + ny * gy + nz * gz) / nn
        if giam < best:
            best = giam
    if best == math.inf:
        return math.nan, math.nan
    return math.asin(max(-1.0, min(1.0, best / a_norm))), best
