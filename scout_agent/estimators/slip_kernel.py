"""The slip detector's per-tick step, compiled (numba): the four feet in one call, state in place.

`SlipDetector.update` (slip.py) ran as scalar Python (≈ 20 µs a tick in the scout loop); this kernel does the
same arithmetic, term for term and in the same order (IEEE results identical, no fast-math), on the detector's
state arrays. slip.py documents what is computed and why; this module only says how the state is laid out.

State (owned by `SlipDetector`, updated in place):
- `flags` (7, 4) bool, rows `PLANNED_PREV`, `CONTACT_PREV`, `TOUCHED`, `VFLAG`, `PRE`, `SLIPPED`, `ERR_NEW`;
- `pb` (3,) base position integrated from the (bias-corrected) known velocity [m]; `bias` (3,) the known base
  velocity's estimated bias, world [m/s];
- `t_td` (4,) touchdown times [s]; `p_td`, `p_pre` (4, 3) touchdown and late-swing foot points, integration
  frame [m]; `err` (4, 3) low-passed foot velocity error, base frame [m/s]; `ap_sum` (4, 3) the stance's
  summed apparent planted-foot velocity (world);
- `stance_dv` (4, cap) each leg's ΔV this stance, circular (the last `cap` values; `cap` ≥ the ring);
  `ring` (n,) ΔV of finished stances;
- `counts` (10,) int: per leg the ticks summed in `ap_sum` (`AP_N` + leg) and the ΔV values this stance
  (`STANCE_N` + leg), then the ring's next index (`RING_NEXT`) and filled count (`RING_FILLED`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "AP_N",
    "CONTACT_PREV",
    "ERR_NEW",
    "PLANNED_PREV",
    "PRE",
    "RING_FILLED",
    "RING_NEXT",
    "SLIPPED",
    "STANCE_N",
    "TOUCHED",
    "VFLAG",
    "slip_step",
]

# rows of the (7, 4) per-leg flag state
PLANNED_PREV, CONTACT_PREV, TOUCHED, VFLAG, PRE, SLIPPED, ERR_NEW = range(7)
# offsets in the (10,) int counts
AP_N, STANCE_N, RING_NEXT, RING_FILLED = 0, 4, 8, 9
# rows of the (5, 4) per-leg flag output: touchdown, event, stance_end, slipped, settled; (2, 4) values: dv, dp
_TD, _EV, _END, _SLIP, _SETTLED = range(5)


@njit(cache=True, nogil=True)
def _commit(
    i: int,
    slipped: bool,
    paper: bool,
    dt_last: float,
    bias_tau_s: float,
    bias: np.ndarray,
    ap_sum: np.ndarray,
    stance_dv: np.ndarray,
    ring: np.ndarray,
    counts: np.ndarray,
) -> bool:
    """A stance of leg i is over (slip.py `_commit`); returns whether the ΔV ring took values (ε_v is then
    recomputed by the caller)."""
    n_ap = counts[AP_N + i]
    if n_ap:
        if not slipped:
            w = min(1.0, n_ap * dt_last / bias_tau_s)
            for k in range(3):
                bias[k] += w * (ap_sum[i, k] / n_ap)
        for k in range(3):
            ap_sum[i, k] = 0.0
        counts[AP_N + i] = 0
    cnt = counts[STANCE_N + i]
    if cnt == 0:
        return False
    counts[STANCE_N + i] = 0
    n = ring.shape[0]
    if n == 0 or (slipped and not paper):
        return False
    cap = stance_dv.shape[1]
    m = min(cnt, n, cap)
    ri = counts[RING_NEXT]
    for j in range(cnt - m, cnt):  # the stance's last m values, oldest first
        ring[ri] = stance_dv[i, j % cap]
        ri = (ri + 1) % n
    counts[RING_NEXT] = ri
    counts[RING_FILLED] = min(n, counts[RING_FILLED] + cnt)
    return True


@njit(cache=True, nogil=True)
def slip_step(
    t: float,
    dt: float,
    dt_last: float,
    a_v: float,
    params: np.ndarray,
    paper: bool,
    use_bias: bool,
    planned: np.ndarray,
    contact: np.ndarray,
    foot_pos: np.ndarray,
    foot_vel: np.ndarray,
    rot: np.ndarray,
    base_vel_world: np.ndarray,
    base_omega: np.ndarray,
    foot_omega: np.ndarray,
    has_foot_omega: bool,
    flags: np.ndarray,
    pb: np.ndarray,
    bias: np.ndarray,
    t_td: np.ndarray,
    p_td: np.ndarray,
    p_pre: np.ndarray,
    err: np.ndarray,
    ap_sum: np.ndarray,
    stance_dv: np.ndarray,
    ring: np.ndarray,
    counts: np.ndarray,
    out_flags: np.ndarray,
    out_vals: np.ndarray,
) -> bool:
    """One tick of the detector for the 4 legs (slip.py `SlipDetector.update`). `params` = (ε_v, ε_p,
    eps_p_alone_m, h, settle_s, bias_settle_s, bias_gate², foot radius, bias_tau_s, 2.0). Writes `out_flags`
    (5, 4) = touchdown, event, stance_end, slipped, settled and `out_vals` (2, 4) = ΔV, ΔP (NaN where not
    settled); returns whether a finished stance fed the ε_v ring."""
    eps_v, eps_p, eps_p_alone, h = params[0], params[1], params[2], params[3]
    settle_s, bias_settle_s, gate2, foot_r, bias_tau_s = params[4], params[5], params[6], params[7], params[8]
    # ΔP squares as libm's pow(x, 2), which Python's `x ** 2` calls and which is not always x·x in the last
    # bit; a run-time exponent keeps LLVM from turning it into a multiply
    sq = params[9]
    vx, vy, vz = base_vel_world[0], base_vel_world[1], base_vel_world[2]
    if use_bias:
        vx, vy, vz = vx - bias[0], vy - bias[1], vz - bias[2]
    pb[0] += vx * dt
    pb[1] += vy * dt
    pb[2] += vz * dt
    # R^T v, base frame
    vb0 = rot[0, 0] * vx + rot[1, 0] * vy + rot[2, 0] * vz
    vb1 = rot[0, 1] * vx + rot[1, 1] * vy + rot[2, 1] * vz
    vb2 = rot[0, 2] * vx + rot[1, 2] * vy + rot[2, 2] * vz
    wx, wy, wz = base_omega[0], base_omega[1], base_omega[2]
    fed = False
    for i in range(4):
        for r in range(5):
            out_flags[r, i] = False
        out_vals[0, i] = math.nan
        out_vals[1, i] = math.nan
        p = planned[i]
        if p != flags[PLANNED_PREV, i]:  # a planned stance starts or ends: clear the per-stance state
            if not p and flags[TOUCHED, i]:
                out_flags[_END, i] = True
                out_flags[_SLIP, i] = flags[SLIPPED, i]
            if _commit(
                i, flags[SLIPPED, i], paper, dt_last, bias_tau_s, bias, ap_sum, stance_dv, ring, counts
            ):
                fed = True
            flags[TOUCHED, i] = False
            flags[VFLAG, i] = False
            flags[SLIPPED, i] = False
        ci = contact[i]
        f0, f1, f2 = foot_pos[i, 0], foot_pos[i, 1], foot_pos[i, 2]
        if not p:
            if ci and not paper:  # in contact before the planned stance (early touchdown): remember where
                for k in range(3):
                    p_pre[i, k] = pb[k] + rot[k, 0] * f0 + rot[k, 1] * f1 + rot[k, 2] * f2
            flags[PRE, i] = ci
            continue
        if ci and ((not flags[CONTACT_PREV, i]) if paper else (not flags[TOUCHED, i])):
            out_flags[_TD, i] = True
            flags[TOUCHED, i] = True
            if paper:
                flags[VFLAG, i] = False
            flags[ERR_NEW, i] = True
            t_td[i] = t
            # the foot landed in late swing: the reference is its point then (as in the ground truth)
            if flags[PRE, i] and not paper:
                for k in range(3):
                    p_td[i, k] = p_pre[i, k]
            else:
                for k in range(3):
                    p_td[i, k] = pb[k] + rot[k, 0] * f0 + rot[k, 1] * f1 + rot[k, 2] * f2
        if not (ci and flags[TOUCHED, i]) or (not paper and t - t_td[i] < settle_s - 1e-9):
            out_flags[_SLIP, i] = out_flags[_SLIP, i] or flags[SLIPPED, i]
            continue
        out_flags[_SETTLED, i] = True
        # ΔV (eq. 1): ẋ_des = −(R^T v + ω × x)
        e0 = -(vb0 + wy * f2 - wz * f1)
        e1 = -(vb1 + wz * f0 - wx * f2)
        e2 = -(vb2 + wx * f1 - wy * f0)
        fv0, fv1, fv2 = foot_vel[i, 0], foot_vel[i, 1], foot_vel[i, 2]
        q0, q1, q2 = e0 - fv0, e1 - fv1, e2 - fv2  # −(apparent foot velocity in the world)
        if a_v < 1.0:  # low-pass within the stance (default form)
            if flags[ERR_NEW, i]:
                err[i, 0], err[i, 1], err[i, 2] = q0, q1, q2
                flags[ERR_NEW, i] = False
            else:
                err[i, 0] += a_v * (q0 - err[i, 0])
                err[i, 1] += a_v * (q1 - err[i, 1])
                err[i, 2] += a_v * (q2 - err[i, 2])
            q0, q1, q2 = err[i, 0], err[i, 1], err[i, 2]
        r0 = q0 / (abs(e0) + h)
        r1 = q1 / (abs(e1) + h)
        r2 = q2 / (abs(e2) + h)
        dvi = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        out_vals[0, i] = dvi
        cap = stance_dv.shape[1]
        stance_dv[i, counts[STANCE_N + i] % cap] = dvi
        counts[STANCE_N + i] += 1
        # x_des = R^T (p_td − p_base): the touchdown point in the base frame now
        d0, d1, d2 = p_td[i, 0] - pb[0], p_td[i, 1] - pb[1], p_td[i, 2] - pb[2]
        xd0 = rot[0, 0] * d0 + rot[1, 0] * d1 + rot[2, 0] * d2
        xd1 = rot[0, 1] * d0 + rot[1, 1] * d1 + rot[2, 1] * d2
        xd2 = rot[0, 2] * d0 + rot[1, 2] * d1 + rot[2, 2] * d2
        if paper:  # eq. 2: | ‖x_des‖ − ‖x‖ |
            dpi = abs(math.sqrt(xd0**sq + xd1**sq + xd2**sq) - math.sqrt(f0**sq + f1**sq + f2**sq))
            hit = dvi > eps_v and dpi > eps_p
        else:  # ‖x_des − x‖, ΔV flag held within the stance
            dpi = math.sqrt((xd0 - f0) ** sq + (xd1 - f1) ** sq + (xd2 - f2) ** sq)
            if dvi > eps_v:
                flags[VFLAG, i] = True
            hit = dpi > eps_p and (flags[VFLAG, i] or dpi > eps_p_alone)
        if use_bias and t - t_td[i] >= bias_settle_s - 1e-9:
            # a planted ball foot moves only by rolling, ω_foot × r·n̂ (slip.py); the rest of its apparent
            # velocity is the base velocity's error, summed for the end of the stance
            ap0, ap1, ap2 = -(e0 - fv0), -(e1 - fv1), -(e2 - fv2)
            if has_foot_omega:
                o0, o1, o2 = foot_omega[i, 0] + wx, foot_omega[i, 1] + wy, foot_omega[i, 2] + wz
                n0, n1, n2 = rot[2, 0] * foot_r, rot[2, 1] * foot_r, rot[2, 2] * foot_r
                ap0 -= o1 * n2 - o2 * n1
                ap1 -= o2 * n0 - o0 * n2
                ap2 -= o0 * n1 - o1 * n0
            if ap0 * ap0 + ap1 * ap1 + ap2 * ap2 < gate2:
                for k in range(3):
                    ap_sum[i, k] += rot[k, 0] * ap0 + rot[k, 1] * ap1 + rot[k, 2] * ap2
                counts[AP_N + i] += 1
        out_vals[1, i] = dpi
        if hit and not flags[SLIPPED, i]:
            out_flags[_EV, i] = True
            flags[SLIPPED, i] = True
        out_flags[_SLIP, i] = flags[SLIPPED, i]
    for i in range(4):
        flags[PLANNED_PREV, i] = planned[i]
        flags[CONTACT_PREV, i] = contact[i]
    return fed
