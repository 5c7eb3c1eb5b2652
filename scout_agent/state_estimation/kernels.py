"""Compiled EKF steps (numba, `njit(cache=True)`): the filter's arithmetic without numpy's per-call overhead.

At 15 states and 3–12 measurement rows every numpy call costs more in dispatch than in arithmetic; the state
estimator ran at ≈ 140 µs per control tick, which put the scout loop on the estimate at 0.79× the exact-state
loop's real-time factor (issue 11's goal: within 20 %). These kernels do the same algebra as the reference
equations in `ekf.py`, in place on the filter's arrays. The first call in a fresh environment compiles for a
few seconds; later processes load the machine code from numba's on-disk cache (no compiler at run time).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "add_bias_noise",
    "add_heading_variance",
    "gravity_shift2",
    "heading_variance",
    "imu_to_base",
    "inflate",
    "propagate",
    "so3_exp",
    "update",
    "velocity_rows_many",
    "world_z_rate",
]


@njit(cache=True, nogil=True)
def _skew(w: np.ndarray) -> np.ndarray:
    out = np.zeros((3, 3))
    out[0, 1], out[0, 2] = -w[2], w[1]
    out[1, 0], out[1, 2] = w[2], -w[0]
    out[2, 0], out[2, 1] = -w[1], w[0]
    return out


@njit(cache=True, nogil=True)
def so3_exp(w: np.ndarray) -> np.ndarray:
    """Exp of a rotation vector (Rodrigues; second order below 1e-8 rad)."""
    th = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    K = _skew(w)
    K2 = K @ K
    if th < 1e-8:
        return np.eye(3) + K + 0.5 * K2
    return np.eye(3) + (np.sin(th) / th) * K + ((1.0 - np.cos(th)) / (th * th)) * K2


@njit(cache=True, nogil=True)
def propagate(
    R: np.ndarray,
    v: np.ndarray,
    p: np.ndarray,
    bg: np.ndarray,
    ba: np.ndarray,
    P: np.ndarray,
    g: np.ndarray,
    q: np.ndarray,
    gyro: np.ndarray,
    acc: np.ndarray,
    dt: float,
) -> np.ndarray:
    """One IMU step in place on (R, v, p, P); returns the bias-corrected angular velocity."""
    w = gyro - bg
    f = acc - ba
    a = R @ f + g
    for i in range(3):
        p[i] += v[i] * dt + 0.5 * a[i] * dt * dt
        v[i] += a[i] * dt
    F = np.eye(15)
    Sw = _skew(w)
    RSf = R @ _skew(f)
    for i in range(3):
        for j in range(3):
            F[i, j] -= Sw[i, j] * dt
            F[3 + i, j] = -RSf[i, j] * dt
            F[3 + i, 12 + j] = -R[i, j] * dt
        F[i, 9 + i] = -dt
        F[6 + i, 3 + i] = dt
    R[:, :] = R @ so3_exp(w * dt)
    FP = F @ P
    P[:, :] = FP @ np.ascontiguousarray(F.T)
    for i in range(15):
        P[i, i] += q[i] * dt
    return w


@njit(cache=True, nogil=True)
def velocity_rows_many(
    R: np.ndarray, v: np.ndarray, bg: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted z = Rᵀv + r × bg for k lever arms r (k, 3), and the stacked Jacobian (3k, 15)."""
    k = r.shape[0]
    vb = R.T @ v
    Svb = _skew(vb)
    h = np.empty((k, 3))
    H = np.zeros((3 * k, 15))
    for m in range(k):
        rx, ry, rz = r[m, 0], r[m, 1], r[m, 2]
        h[m, 0] = vb[0] + ry * bg[2] - rz * bg[1]
        h[m, 1] = vb[1] + rz * bg[0] - rx * bg[2]
        h[m, 2] = vb[2] + rx * bg[1] - ry * bg[0]
        o = 3 * m
        for i in range(3):
            for j in range(3):
                H[o + i, j] = Svb[i, j]
                H[o + i, 3 + j] = R[j, i]
        H[o + 0, 10], H[o + 0, 11] = -rz, ry
        H[o + 1, 9], H[o + 1, 11] = rz, -rx
        H[o + 2, 9], H[o + 2, 10] = -ry, rx
    return h, H


@njit(cache=True, nogil=True)
def _mahalanobis2_3(S: np.ndarray, r: np.ndarray, o: int) -> float:
    """rᵀ B⁻¹ r of the 3-row block at offset `o` (B = S[o:o+3, o:o+3], symmetric positive definite), in closed
    form (adjugate over determinant: no LAPACK call and no allocation per block); inf for a singular B."""
    a, b, c = S[o, o], S[o, o + 1], S[o, o + 2]
    d, e, f = S[o + 1, o + 1], S[o + 1, o + 2], S[o + 2, o + 2]
    A00, A01, A02 = d * f - e * e, c * e - b * f, b * e - c * d
    A11, A12, A22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A00 + b * A01 + c * A02
    if not det > 0.0:
        return np.inf
    x, y, z = r[o], r[o + 1], r[o + 2]
    q = A00 * x * x + A11 * y * y + A22 * z * z + 2.0 * (A01 * x * y + A02 * x * z + A12 * y * z)
    return q / det


@njit(cache=True, nogil=True)
def update(
    R: np.ndarray,
    v: np.ndarray,
    p: np.ndarray,
    bg: np.ndarray,
    ba: np.ndarray,
    P: np.ndarray,
    residual: np.ndarray,
    H: np.ndarray,
    noise_var: np.ndarray,
    gate_chi2: float,
    hold_heading: bool = False,
) -> np.ndarray:
    """Kalman update with stacked 3-row blocks, folded into the nominal state in place. `gate_chi2` > 0 drops
    each block whose Mahalanobis distance² exceeds it first (a single-row measurement: pass 0, no gate).
    `hold_heading`: the gain's heading row (the rotation error about world z, u = Rᵀe_z) is zeroed, a
    Schmidt (consider) update of heading: the measurement does not turn the heading, and the Joseph form,
    valid for any gain, keeps the covariance that of the filter as run. Returns the kept blocks' mask."""
    m = residual.shape[0]
    PHt = P @ np.ascontiguousarray(H.T)
    S = H @ PHt
    for i in range(m):
        S[i, i] += noise_var[i]
    nb = max(m // 3, 1)
    keep = np.ones(nb, np.bool_)
    if gate_chi2 > 0.0 and m % 3 == 0:
        for b in range(nb):
            keep[b] = _mahalanobis2_3(S, residual, 3 * b) <= gate_chi2
        nk = 0
        for b in range(nb):
            if keep[b]:
                nk += 1
        if nk == 0:
            return keep
        if nk < nb:
            rows = np.empty(3 * nk, np.int64)
            c = 0
            for b in range(nb):
                if keep[b]:
                    for i in range(3):
                        rows[c] = 3 * b + i
                        c += 1
            residual = residual[rows]
            H = np.ascontiguousarray(H[rows])
            noise_var = noise_var[rows]
            PHt = np.ascontiguousarray(PHt[:, rows])
            S2 = np.empty((3 * nk, 3 * nk))
            for i in range(3 * nk):
                for j in range(3 * nk):
                    S2[i, j] = S[rows[i], rows[j]]
            S = S2
    K = np.ascontiguousarray(np.linalg.solve(S, np.ascontiguousarray(PHt.T)).T)  # (15, m)
    if hold_heading:
        for j in range(K.shape[1]):
            s = R[2, 0] * K[0, j] + R[2, 1] * K[1, j] + R[2, 2] * K[2, j]
            for i in range(3):
                K[i, j] -= R[2, i] * s
    dx = K @ residual
    IKH = np.eye(15) - K @ H
    Kn = K * noise_var
    P[:, :] = IKH @ P @ np.ascontiguousarray(IKH.T) + Kn @ np.ascontiguousarray(K.T)
    R[:, :] = R @ so3_exp(np.ascontiguousarray(dx[0:3]))
    for i in range(3):
        v[i] += dx[3 + i]
        p[i] += dx[6 + i]
        bg[i] += dx[9 + i]
        ba[i] += dx[12 + i]
    return keep


@njit(cache=True, nogil=True)
def imu_to_base(
    acc: np.ndarray, gyro: np.ndarray, bg: np.ndarray, w_prev: np.ndarray, r: np.ndarray, dt: float
) -> np.ndarray:
    """The specific force at the base origin from the IMU's at `r` (base frame): f − (ω̇ × r + ω × (ω × r)),
    ω = gyro − bg, ω̇ by difference with `w_prev` (this tick's ω is written back into it)."""
    w = gyro - bg
    wdot = (w - w_prev) / dt
    w_prev[:] = w
    wr = np.array([w[1] * r[2] - w[2] * r[1], w[2] * r[0] - w[0] * r[2], w[0] * r[1] - w[1] * r[0]])
    out = np.empty(3)
    out[0] = acc[0] - (wdot[1] * r[2] - wdot[2] * r[1]) - (w[1] * wr[2] - w[2] * wr[1])
    out[1] = acc[1] - (wdot[2] * r[0] - wdot[0] * r[2]) - (w[2] * wr[0] - w[0] * wr[2])
    out[2] = acc[2] - (wdot[0] * r[1] - wdot[1] * r[0]) - (w[0] * wr[1] - w[1] * wr[0])
    return out


@njit(cache=True, nogil=True)
def gravity_shift2(R: np.ndarray, g: np.ndarray, u0: np.ndarray) -> float:
    """|Rᵀ(−g) − u0|²: how far the specific force of standing still has turned in the base frame since it was
    `u0` (the gyro's g-sensitivity term); numpy's `R.T @ -g` (the same BLAS product) and sum of squares."""
    u = np.dot(np.ascontiguousarray(R.T), -g)
    d0, d1, d2 = u[0] - u0[0], u[1] - u0[1], u[2] - u0[2]
    return (d0 * d0 + d1 * d1) + d2 * d2


@njit(cache=True, nogil=True)
def heading_variance(R: np.ndarray, P: np.ndarray) -> float:
    """uᵀ P_θθ u, u = Rᵀe_z (R's third row): the variance of the rotation about world z [rad²]."""
    s = 0.0
    for i in range(3):
        for j in range(3):
            s += R[2, i] * P[i, j] * R[2, j]
    return s


@njit(cache=True, nogil=True)
def add_heading_variance(R: np.ndarray, P: np.ndarray, q: float) -> None:
    """P_θθ += q·u uᵀ, u = Rᵀe_z, in place."""
    for i in range(3):
        for j in range(3):
            P[i, j] += q * R[2, i] * R[2, j]


@njit(cache=True, nogil=True)
def world_z_rate(R: np.ndarray, gyro: np.ndarray, bg: np.ndarray) -> float:
    """The bias-corrected turn rate about world z: (Rᵀe_z)·(ω − b_g) [rad/s]."""
    return R[2, 0] * (gyro[0] - bg[0]) + R[2, 1] * (gyro[1] - bg[1]) + R[2, 2] * (gyro[2] - bg[2])


@njit(cache=True, nogil=True)
def add_bias_noise(
    P: np.ndarray,
    tempco_sd: np.ndarray,
    d2g: float,
    acc_temp_var: float,
    q_gs: float,
    temp_known: bool,
    two: float,
) -> None:
    """The estimator's bias process noise in place (`StateEstimator._inflate`, the same additions in the same
    order per element): with `temp_known`, the gyro biases' tempco_sd²·d(ΔT²) (`d2g`; raised to a run-time
    `two` = 2.0, as numpy's scalar `**` calls libm's pow) and the accelerometer biases' `acc_temp_var`; then
    the gyro biases' g-sensitivity `q_gs`."""
    for i in range(3):
        if temp_known:
            P[9 + i, 9 + i] += tempco_sd[i] ** two * d2g
            P[12 + i, 12 + i] += acc_temp_var
        P[9 + i, 9 + i] += q_gs


@njit(cache=True, nogil=True)
def inflate(
    R: np.ndarray,
    g: np.ndarray,
    bg: np.ndarray,
    P: np.ndarray,
    gyro: np.ndarray,
    u_zaru: np.ndarray,
    tempco_k: np.ndarray,
    tempco_sd: np.ndarray,
    coef: np.ndarray,
    temp: float,
    speed: float,
    vx: float,
    vy: float,
    dt: float,
    n_rejected: int,
    anchored: bool,
    state: tuple[float, ...],
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]:
    """`StateEstimator._inflate`'s arithmetic in place on P and bg (the same operations in the same order; the
    docstring there says what each term is). `coef`: the squared σ's (g-sensitivity, accelerometer tempco,
    odometry scale, odometry height, gyro scale, slip, odometry crab). `state` (the estimator's `Inflation`) in, and out: temp0, gyro_temp0, dtemp_prev,
    gyro_dtemp_prev, temp_prev, du2_peak, bias_heading_rad, walked_m, turn_net_rad, turn_peak_rad,
    heading_var_prev. `speed` = hypot(vx, vy), from Python's math.hypot (numba's differs in the last bit)."""
    temp0, gyro_temp0, dtemp_prev, gyro_dtemp_prev, temp_prev, du2_peak = state[0:6]
    bias_heading, walked, turn_net, turn_peak, hv_prev = state[6:11]
    gs2, acc2, scale2, height2, gscale2, slip2 = coef[0], coef[1], coef[2], coef[3], coef[4], coef[5]
    crab2 = coef[6]
    d2 = d2g = 0.0
    if temp == temp:
        if temp0 != temp0:
            temp0 = gyro_temp0 = temp
        dtemp = temp - temp0
        d2 = abs(dtemp * dtemp - dtemp_prev * dtemp_prev)
        dtemp_prev = dtemp
        dtemp_g = temp - gyro_temp0
        d2g = abs(dtemp_g * dtemp_g - gyro_dtemp_prev * gyro_dtemp_prev)
        gyro_dtemp_prev = dtemp_g
        if temp_prev == temp_prev and temp != temp_prev:
            step = temp - temp_prev
            for i in range(3):
                bg[i] += tempco_k[i] * step
        temp_prev = temp
    du2 = gravity_shift2(R, g, u_zaru)
    q = gs2 * max(du2 - du2_peak, 0.0)
    du2_peak = max(du2, du2_peak)
    if temp == temp:
        add_bias_noise(P, tempco_sd, d2g, acc2 * d2, q, True, 2.0)
    else:
        add_bias_noise(P, tempco_sd, 0.0, 0.0, q, False, 2.0)
    bias_heading += np.sqrt(P[11, 11]) * dt
    if speed > 1e-3:
        q = 2.0 * scale2 * walked * speed * dt
        ux, uy = vx / speed, vy / speed
        P[6, 6] += q * ux * ux
        P[7, 7] += q * uy * uy
        P[6, 7] += q * ux * uy
        P[7, 6] += q * ux * uy
        if crab2 > 0.0:  # the legs' sideways counterpart: across the velocity
            q = 2.0 * crab2 * walked * speed * dt
            P[6, 6] += q * uy * uy
            P[7, 7] += q * ux * ux
            P[6, 7] -= q * ux * uy
            P[7, 6] -= q * ux * uy
        if anchored:
            P[8, 8] += height2 * speed * dt
        walked += speed * dt
    if heading_variance(R, P) < 0.5 * hv_prev:
        turn_net = turn_peak = 0.0
    turn_net += world_z_rate(R, gyro, bg) * dt
    peak = max(turn_peak, abs(turn_net))
    q = gscale2 * (peak * peak - turn_peak * turn_peak)
    if q > 0.0:
        add_heading_variance(R, P, q)
    turn_peak = peak
    hv_prev = heading_variance(R, P)
    if n_rejected:
        P[6, 6] += n_rejected * slip2
        P[7, 7] += n_rejected * slip2
    return (
        temp0,
        gyro_temp0,
        dtemp_prev,
        gyro_dtemp_prev,
        temp_prev,
        du2_peak,
        bias_heading,
        walked,
        turn_net,
        turn_peak,
        hv_prev,
    )
