"""The simulator's ground truth each control tick, compiled (numba): per-foot ground forces from MuJoCo's
contact list, the trunk's rotation and the feet in the world (`tick_truth`), and each stance's contact-point
displacement (`stance_displacement`).

In numpy these cost ≈ 120 µs a tick (a Python loop over contacts and a few dozen small array operations), here
a few µs. The arithmetic is the same, in the same order, so the figures are bit-identical to the numpy version
they replaced.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from scout_agent.robot.kinematics import leg_kinematics
from scout_agent.sim.terrain import heights_at

__all__ = ["TickTruth", "foot_contacts", "pose_and_feet", "stance_displacement", "tick_truth"]


@njit(cache=True, nogil=True)
def foot_contacts(
    geom: np.ndarray,
    efc_address: np.ndarray,
    frame: np.ndarray,
    pos: np.ndarray,
    efc_force: np.ndarray,
    leg_of_geom: np.ndarray,
    terrain_geom: int,
    forces: np.ndarray,
    points: np.ndarray,
    normal: np.ndarray,
    touching: np.ndarray,
) -> int:
    """Fill, for the 4 feet, the summed ground force on each (world frame) `forces` (4, 3) [N], the
    normal-force-weighted contact point `points` (4, 3) [m] (NaN without a pushing contact) and the normal
    force `normal` (4,) [N]; flag in `touching` (ngeom,) every non-foot geom touching the terrain and return
    their count. Inputs are MuJoCo's contact arrays for the `ncon` active contacts: `geom` (ncon, 2),
    `efc_address` (ncon,), `frame` (ncon, 9), `pos` (ncon, 3), and `efc_force`; `leg_of_geom` (ngeom,) maps
    a foot geom to its leg, other geoms to -1."""
    forces[:] = 0.0
    points[:] = 0.0
    normal[:] = 0.0
    touching[:] = False
    for c in range(geom.shape[0]):
        a, b = geom[c, 0], geom[c, 1]
        if a != terrain_geom and b != terrain_geom:
            continue
        adr = efc_address[c]
        l0 = l1 = l2 = 0.0
        if adr >= 0:
            l0, l1, l2 = efc_force[adr], efc_force[adr + 1], efc_force[adr + 2]
        other, sign = (b, 1.0) if a == terrain_geom else (a, -1.0)  # force of geom1 on geom2
        leg = leg_of_geom[other]
        if leg < 0:
            touching[other] = True
            continue
        w = max(l0, 0.0)
        for j in range(3):
            forces[leg, j] += sign * (l0 * frame[c, j] + l1 * frame[c, 3 + j] + l2 * frame[c, 6 + j])
            points[leg, j] += w * pos[c, j]
        normal[leg] += l0
    for leg in range(4):
        for j in range(3):
            points[leg, j] = points[leg, j] / normal[leg] if normal[leg] > 0.0 else np.nan
    return int(touching.sum())


@njit(cache=True, nogil=True)
def quat_to_mat(q: np.ndarray, R: np.ndarray) -> None:
    """Rotation matrix `R` (3, 3) of the unit quaternion q = (w, x, y, z)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    R[0, 0], R[0, 1], R[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)


@njit(cache=True, nogil=True)
def pose_and_feet(qpos: np.ndarray, R: np.ndarray, feet_w: np.ndarray) -> None:
    """From the free-floating robot's `qpos` (19,): the trunk's rotation `R` (3, 3) and the foot-sphere
    centres in the world `feet_w` (4, 3)."""
    quat_to_mat(qpos[3:7], R)
    feet_b = np.empty((4, 3))
    leg_kinematics(qpos[7:19], feet_b, np.empty((4, 3, 3)))
    for i in range(4):
        for j in range(3):
            feet_w[i, j] = qpos[j] + (
                feet_b[i, 0] * R[j, 0] + feet_b[i, 1] * R[j, 1] + feet_b[i, 2] * R[j, 2]
            )


@njit(cache=True, nogil=True)
def stance_displacement(
    stance_planned: np.ndarray,
    contact: np.ndarray,
    points: np.ndarray,
    first_point: np.ndarray,
    swung: np.ndarray,
    disp: np.ndarray,
) -> None:
    """How far each foot's contact point moved since its stance's first contact, into `disp` (4,) [m] (NaN
    without contact). `first_point` (4, 3) and `swung` (4,) (the leg swung since its last first contact) carry
    over from tick to tick and are updated in place."""
    for i in range(4):
        if not stance_planned[i]:
            swung[i] = True
        if contact[i] and swung[i]:
            first_point[i] = points[i]
            swung[i] = False
        if contact[i]:
            d0 = points[i, 0] - first_point[i, 0]
            d1 = points[i, 1] - first_point[i, 1]
            d2 = points[i, 2] - first_point[i, 2]
            disp[i] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        else:
            disp[i] = np.nan


class TickTruth(NamedTuple):
    """The simulator's ground truth at the end of a control tick (`tick_truth`)."""

    foot_force: np.ndarray  # (4, 3) summed ground force on each foot, world [N]
    contact_point: np.ndarray  # (4, 3) force-weighted contact point, world [m]; NaN without a pushing contact
    normal_force: np.ndarray  # (4,) normal force on each foot [N]
    contact: np.ndarray  # (4,) bool, normal force above the contact threshold
    n_nonfoot: int  # non-foot robot geoms touching the terrain
    R: np.ndarray  # (3, 3) trunk rotation, world_R_base
    feet: np.ndarray  # (4, 3) foot-sphere centres, world [m]
    ground: np.ndarray  # (5,) terrain height under the four feet and the trunk origin [m]


@njit(cache=True, nogil=True)
def tick_truth(
    contacts: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    leg_of_geom: np.ndarray,
    terrain_geom: int,
    touching: np.ndarray,
    qpos: np.ndarray,
    z: np.ndarray,
    x0: float,
    y0: float,
    res: float,
    contact_threshold_n: float,
    forces: np.ndarray,
    contact_point: np.ndarray,
    fn: np.ndarray,
    contact: np.ndarray,
    R: np.ndarray,
    feet: np.ndarray,
    ground: np.ndarray,
) -> int:
    """All of a tick's ground truth in one compiled pass: `foot_contacts` (MuJoCo's contact arrays `contacts`:
    geom, efc_address, frame, pos, and efc_force; the `touching` flags), `pose_and_feet` (qpos), and the terrain
    (grid z, x0, y0, res) under the feet and the trunk, into the `TickTruth` fields given (`tick_truth_into`
    allocates them). Returns the number of non-foot geoms touching the terrain."""
    points = np.empty((4, 3))
    geom, efc_address, frame, pos, efc_force = contacts
    n_nonfoot = foot_contacts(
        geom, efc_address, frame, pos, efc_force, leg_of_geom, terrain_geom, forces, points, fn, touching
    )
    for i in range(4):
        contact[i] = fn[i] > contact_threshold_n
    pose_and_feet(qpos, R, feet)
    x, y = np.empty(5), np.empty(5)
    x[:4], y[:4] = feet[:, 0], feet[:, 1]
    x[4], y[4] = qpos[0], qpos[1]
    heights_at(z, x0, y0, res, x, y, ground)
    contact_point[:] = points
    for i in range(4):
        if not contact[i]:
            contact_point[i] = np.nan
    return n_nonfoot


def tick_truth_into(inputs: tuple, normal_force: np.ndarray, R: np.ndarray) -> TickTruth:
    """`tick_truth` on its ten `inputs` (contacts … contact_threshold_n) into fresh arrays for the fields a
    tick's `GroundTruth` record keeps, and into the caller's buffers `normal_force` (4,) and `R` (3, 3), which
    only serve the tick itself (the sensors, the fall check): arrays allocated here and filled in place cost a
    third of arrays returned by the kernel."""
    forces, contact_point = np.empty((4, 3)), np.empty((4, 3))
    contact, feet, ground = np.empty(4, bool), np.empty((4, 3)), np.empty(5)
    n = tick_truth(*inputs, forces, contact_point, normal_force, contact, R, feet, ground)  # type: ignore[call-arg]
    return TickTruth(forces, contact_point, normal_force, contact, n, R, feet, ground)
