"""The state estimator's fresh tick up to its leg-odometry update, in one compiled call (numba).

`StateEstimator.update` (estimator.py: the model, and the docstring saying why each step is there) did these
steps as a dozen short numpy operations and compiled calls from Python, ≈ 20 µs of dispatch a tick; here they
are the same operations in the same order on the estimator's arrays, in place: the stamped interval, the gyro
carried to the encoders' instant, the IMU's lever arm, the IMU propagation, which feet are settled and in use,
the feet's kinematics, and the odometry update of the feet in use (χ²-gated, heading held). What follows the
update (the inflation, the launch-height anchor, the standstill, the footholds) stays in estimator.py.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from scout_agent.estimators.elevation import _terrain_normal
from scout_agent.robot.kinematics import leg_motion

from . import kernels
from .leg_odometry import odometry_rows

__all__ = ["estimate_arrays", "matrix_to_quat", "odometry_tick", "settled_feet"]


@njit(cache=True, nogil=True)
def settled_feet(
    contact: np.ndarray,
    since: np.ndarray,
    t: float,
    settle_s: float,
    mid_stance: np.ndarray,
    settled: np.ndarray,
    use: np.ndarray,
) -> tuple[int, int, int]:
    """Feet whose contact has lasted `settle_s` into `settled` (4,), and of those the ones in `mid_stance`
    into `use`; `since` (4,) each contact's start [s] (inf without contact), updated in place. Returns the
    counts (in contact, settled, in use): the tick's branches need only those."""
    n_contact = n_settled = n_use = 0
    for i in range(4):
        since[i] = min(since[i], t) if contact[i] else np.inf
        settled[i] = contact[i] and t - since[i] >= settle_s
        use[i] = settled[i] and mid_stance[i]
        n_contact += contact[i]
        n_settled += settled[i]
        n_use += use[i]
    return n_contact, n_settled, n_use


@njit(cache=True, nogil=True)
def odometry_tick(
    ekf: tuple[
        np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray
    ],
    reading: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    feet: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    stance: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    imu: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    normal_w: np.ndarray,
    leg_var: np.ndarray,
    scalars: tuple[float, float, float, float, float, float, float, float, float, float, float, float, float],
    flags: tuple[bool, bool, bool, bool, bool],
) -> tuple[float, float, int, int, int]:
    """One tick to the odometry update, in place; a lost packet's (not `fresh`) only its propagation on the held
    reading over the loop period.

    ekf: R, v, p, bg, ba, P, g, process noise q (the filter's arrays); reading: the tick's imu_acc, imu_gyro,
    q, dq, contact; feet: the kinematics' buffers (positions, velocities, angular velocities, Jacobians);
    stance: contact starts, settled, in use (written), the mid-stance mask to use; imu: the lever arm r, the last
    ω (lever-arm kernel's), the last fresh gyro reading (written), f_base (written: the specific force at the
    base origin). scalars: t, dt (the loop period), stamp_s, stamp_prev, held_s, gyro_age_s, settle_s,
    foot_radius, gate_chi2, lost_acc_std (estimator.py, "Lost packets"), climb_bias (climb_calibration.py), the
    legs' along-track excess and crab angle (`EstimatorConfig.odometry_calibration`); flags: fresh, lever arm, a previous fresh reading exists, standing, hold heading.
    Returns (dt, stamp_prev, n_contact, n_settled, n_rejected)."""
    R, v, p, bg, ba, P, g, q = ekf
    acc, gyro, jq, jdq, contact = reading
    (
        t,
        dt,
        stamp,
        stamp_prev,
        held,
        age,
        settle_s,
        foot_radius,
        gate_chi2,
        lost_acc_std,
        climb,
        excess,
        crab,
    ) = scalars
    fresh, lever, has_prev, stand, hold_heading = flags
    r_imu, w_prev, gyro_fresh, f_base = imu
    if not fresh:  # a lost packet: the held reading propagated, no measurement
        if not lever:  # (with the lever arm: the last fresh tick's specific force at the origin, as held)
            f_base[:] = acc
        kernels.propagate(R, v, p, bg, ba, P, g, q, gyro, f_base, dt)
        var = (lost_acc_std * dt) ** 2  # what the lost tick's own specific force may have added
        for i in range(3, 6):
            P[i, i] += var
        return dt, stamp_prev, 0, 0, 0
    if stamp == stamp:  # integrate over the stamped interval (less what was held)
        dt = min(max(stamp - stamp_prev - held, 0.2 * dt), 3.0 * dt)
        stamp_prev = stamp
    since = dt + held  # the gyro at the encoders' instant (estimator._gyro_at_encoders)
    gyro_now = gyro.copy()
    if has_prev and age > 0.0 and since > 0.0:
        f = age / since
        for i in range(3):
            gyro_now[i] = gyro[i] + (gyro[i] - gyro_fresh[i]) * f
    gyro_fresh[:] = gyro
    if lever:  # ω̇ over the time since the last fresh rate (a lost packet in between: two ticks, not one)
        f_base[:] = kernels.imu_to_base(acc, gyro, bg, w_prev, r_imu, since)
    else:
        f_base[:] = acc
    kernels.propagate(R, v, p, bg, ba, P, g, q, gyro, f_base, dt)
    since_c, settled, use, mid_stance = stance
    n_contact, n_settled, n_use = settled_feet(contact, since_c, t, settle_s, mid_stance, settled, use)
    fb, fv, fw, J = feet
    if n_contact > 0 or stand:
        leg_motion(jq, jdq, fb, fv, fw, J)
    n_rejected = 0
    if n_use:
        n_b = np.dot(R.T, normal_w)  # numpy's `R.T @ n` (the same BLAS call on the transposed view)
        residual, H = odometry_rows(
            use, R, v, bg, (fb, fv, fw), gyro_now, n_b, foot_radius, climb, excess, crab
        )
        keep = kernels.update(
            R,
            v,
            p,
            bg,
            ba,
            P,
            residual,
            H,
            np.ascontiguousarray(leg_var[: H.shape[0]]),
            gate_chi2,
            hold_heading,
        )
        for k in keep:
            n_rejected += not k
    return dt, stamp_prev, n_contact, n_settled, n_rejected


@njit(cache=True, nogil=True)
def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of a rotation matrix (Shepperd's method); compiled, the estimate needs it every tick."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    return q if q[0] >= 0 else -q


@njit(cache=True, nogil=True)
def update_footholds(
    contact: np.ndarray,
    was_contact: np.ndarray,
    feet_b: np.ndarray,
    R: np.ndarray,
    p: np.ndarray,
    footholds: np.ndarray,
) -> bool:
    """Each foot in contact: its world position R·foot + p into `footholds` (4, 3) (the same BLAS product as
    numpy's `feet @ R.T`); True if one of them touched down this tick."""
    k = 0
    for i in range(4):
        k += contact[i]
    sel = np.empty((k, 3))
    m = 0
    for i in range(4):
        if contact[i]:
            sel[m] = feet_b[i]
            m += 1
    w = np.dot(sel, R.T)
    m, new = 0, False
    for i in range(4):
        if contact[i]:
            for j in range(3):
                footholds[i, j] = w[m, j] + p[j]
            m += 1
            new |= not was_contact[i]
    return new


@njit(cache=True, nogil=True)
def estimate_arrays(
    feet: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    state: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    any_contact: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The end of a tick: with `any_contact`, the footholds of the feet in contact (`update_footholds`) and, if one
    of them touched down, the ground normal through them refitted in place (`elevation.terrain_normal`'s kernel);
    then the estimate's arrays: copies of p, R, the quaternion of R, a copy of v, and ω = gyro − bg.
    feet: contact, the last tick's contact, the feet (base frame), footholds (4, 3), normal_w (3,) (both written);
    state: R, p, v, bg, the tick's gyro."""
    contact, was_contact, feet_b, footholds, normal_w = feet
    R, p, v, bg, gyro = state
    if any_contact and update_footholds(contact, was_contact, feet_b, R, p, footholds):
        _terrain_normal(footholds, normal_w)
    return p.copy(), R.copy(), matrix_to_quat(R), v.copy(), gyro - bg
