"""The whole robot's inverse dynamics (trunk and legs, rotor inertia included), compiled for the estimators' tick.

`inverse_dynamics` is the recursive Newton–Euler algorithm (Featherstone's RNEA) on the model Pinocchio builds from
the MJCF the simulator runs (`kinematics.LegKinematics`): the same links, masses, inertias, joint axes and
rotor inertias (armature), read from that model once (`dynamics_params`). It equals `pinocchio.rnea` with gravity
off and the trunk's linear velocity zero to ≈ 1e-13 relative (tests/scout_agent/test_statics.py); where Pinocchio's
call costs ≈ 3.5 µs from Python, this one is a few hundred nanoseconds inside a compiled caller, which lets the
non-foot contact detector (`estimators.nonfoot`) run its whole tick in one compiled call.

Conventions: the trunk (body 0) at the origin, its angular velocity `omega` and acceleration in the trunk frame; its
linear velocity zero and its linear acceleration `acc` (a uniform gravity field is an accelerated frame: passing
the specific force there folds gravity in); the forces do not depend on the trunk's linear velocity (Galilean
invariance). Bodies 1–12 are the legs' links, joint j = body j + 1, revolute about their own x or y axis, the joint
placements pure translations (the Aliengo's MJCF: asserted when the parameters are read).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from numba import njit

__all__ = ["dynamics_params", "inverse_dynamics"]

# a body's row in the parameter table: parent, joint axis (0 x, 1 y, 2 z), placement (3), mass, CoM (3),
# rotational inertia about the CoM (9, row-major), joint armature
_ROW = 19


def dynamics_params(model: pin.Model) -> np.ndarray:
    """The (13, 19) parameter table of a free-flyer robot whose other joints are revolute about x, y or z with
    translation-only placements (bodies in Pinocchio's joint order, parents first)."""
    axes = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}
    n = model.njoints - 1
    out = np.zeros((n, _ROW))
    for b in range(n):
        j = b + 1
        joint = model.joints[j]
        if b == 0:
            if joint.shortname() != "JointModelFreeFlyer":
                raise ValueError(f"body 0 must hang on a free flyer, not {joint.shortname()}")
        else:
            if joint.shortname() not in axes:
                raise ValueError(f"joint {model.names[j]}: {joint.shortname()} is not a revolute x/y/z joint")
            out[b, 0] = model.parents[j] - 1
            out[b, 1] = axes[joint.shortname()]
            out[b, 18] = model.armature[joint.idx_v]
        placement = model.jointPlacements[j]
        if not np.allclose(placement.rotation, np.eye(3)):
            raise ValueError(f"joint {model.names[j]}: placements with a rotation are not handled")
        out[b, 2:5] = placement.translation
        inertia = model.inertias[j]
        out[b, 5] = inertia.mass
        out[b, 6:9] = inertia.lever
        out[b, 9:18] = np.asarray(inertia.inertia).reshape(9)
    return out


@njit(cache=True, nogil=True)
def _cross(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> tuple[float, float, float]:
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, nogil=True)
def inverse_dynamics(
    params: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    omega: np.ndarray,
    acc: np.ndarray,
    omega_dot: np.ndarray,
    qdd: np.ndarray,
    out: np.ndarray,
) -> None:
    """The generalized forces (18,) into `out` — the trunk's force (3) and moment (3) about its origin, trunk
    frame, then the 12 joint torques — that move the robot at joint angles `q`, rates `dq` and accelerations
    `qdd` (12,), the trunk turning at `omega` with `omega_dot` and accelerating at `acc` (3,) (module docstring)."""
    n = params.shape[0]
    W = np.empty((n, 3))  # angular velocity, body frame
    V = np.empty((n, 3))  # linear velocity of the body origin
    AW = np.empty((n, 3))  # spatial acceleration: angular, linear
    AV = np.empty((n, 3))
    FL = np.empty((n, 3))  # force, moment about the body origin (body frame)
    FA = np.empty((n, 3))
    R = np.empty((n, 3, 3))  # body in its parent
    for k in range(3):
        W[0, k], V[0, k], AW[0, k], AV[0, k] = omega[k], 0.0, omega_dot[k], acc[k]
    for b in range(1, n):
        p, ax, j = int(params[b, 0]), int(params[b, 1]), b - 1
        tx, ty, tz = params[b, 2], params[b, 3], params[b, 4]
        c, s = np.cos(q[j]), np.sin(q[j])
        Rb = R[b]
        for r in range(3):
            for k in range(3):
                Rb[r, k] = 0.0
        a1, a2 = (ax + 1) % 3, (ax + 2) % 3  # rotation about axis ax
        Rb[ax, ax] = 1.0
        Rb[a1, a1], Rb[a1, a2] = c, -s
        Rb[a2, a1], Rb[a2, a2] = s, c
        # the parent's motion at this body's origin, then into this body's frame (Rᵀ)
        w0, w1, w2 = W[p, 0], W[p, 1], W[p, 2]
        c0, c1, c2 = _cross(w0, w1, w2, tx, ty, tz)
        v0, v1, v2 = V[p, 0] + c0, V[p, 1] + c1, V[p, 2] + c2
        d0, d1, d2 = _cross(AW[p, 0], AW[p, 1], AW[p, 2], tx, ty, tz)
        l0, l1, l2 = AV[p, 0] + d0, AV[p, 1] + d1, AV[p, 2] + d2
        for k in range(3):
            W[b, k] = Rb[0, k] * w0 + Rb[1, k] * w1 + Rb[2, k] * w2
            V[b, k] = Rb[0, k] * v0 + Rb[1, k] * v1 + Rb[2, k] * v2
            AW[b, k] = Rb[0, k] * AW[p, 0] + Rb[1, k] * AW[p, 1] + Rb[2, k] * AW[p, 2]
            AV[b, k] = Rb[0, k] * l0 + Rb[1, k] * l1 + Rb[2, k] * l2
        W[b, ax] += dq[j]
        AW[b, ax] += qdd[j]
        # the joint's own motion S·q̇ (along axis ax); the acceleration adds v × S·q̇
        e0, e1, e2 = (dq[j] if ax == 0 else 0.0), (dq[j] if ax == 1 else 0.0), (dq[j] if ax == 2 else 0.0)
        x0, x1, x2 = _cross(W[b, 0], W[b, 1], W[b, 2], e0, e1, e2)
        y0, y1, y2 = _cross(V[b, 0], V[b, 1], V[b, 2], e0, e1, e2)
        AW[b, 0] += x0
        AW[b, 1] += x1
        AW[b, 2] += x2
        AV[b, 0] += y0
        AV[b, 1] += y1
        AV[b, 2] += y2
    for b in range(n):  # each body's I·a + v ×* I·v
        m, cx, cy, cz = params[b, 5], params[b, 6], params[b, 7], params[b, 8]
        w0, w1, w2 = W[b, 0], W[b, 1], W[b, 2]
        u0, u1, u2 = _cross(w0, w1, w2, cx, cy, cz)
        h0, h1, h2 = m * (V[b, 0] + u0), m * (V[b, 1] + u1), m * (V[b, 2] + u2)  # momentum
        i = params[b, 9:18]
        k0 = i[0] * w0 + i[1] * w1 + i[2] * w2
        k1 = i[3] * w0 + i[4] * w1 + i[5] * w2
        k2 = i[6] * w0 + i[7] * w1 + i[8] * w2
        z0, z1, z2 = _cross(cx, cy, cz, h0, h1, h2)
        k0, k1, k2 = k0 + z0, k1 + z1, k2 + z2  # angular momentum about the body origin
        g0, g1, g2 = _cross(AW[b, 0], AW[b, 1], AW[b, 2], cx, cy, cz)
        f0, f1, f2 = m * (AV[b, 0] + g0), m * (AV[b, 1] + g1), m * (AV[b, 2] + g2)
        aw0, aw1, aw2 = AW[b, 0], AW[b, 1], AW[b, 2]
        n0 = i[0] * aw0 + i[1] * aw1 + i[2] * aw2
        n1 = i[3] * aw0 + i[4] * aw1 + i[5] * aw2
        n2 = i[6] * aw0 + i[7] * aw1 + i[8] * aw2
        z0, z1, z2 = _cross(cx, cy, cz, f0, f1, f2)
        p0, p1, p2 = _cross(w0, w1, w2, h0, h1, h2)
        r0, r1, r2 = _cross(w0, w1, w2, k0, k1, k2)
        s0, s1, s2 = _cross(V[b, 0], V[b, 1], V[b, 2], h0, h1, h2)
        FL[b, 0], FL[b, 1], FL[b, 2] = f0 + p0, f1 + p1, f2 + p2
        FA[b, 0], FA[b, 1], FA[b, 2] = n0 + z0 + r0 + s0, n1 + z1 + r1 + s1, n2 + z2 + r2 + s2
    for b in range(n - 1, 0, -1):  # to the parents, the joint's share on the way
        p, ax, j = int(params[b, 0]), int(params[b, 1]), b - 1
        out[6 + j] = FA[b, ax] + params[b, 18] * qdd[j]
        Rb = R[b]
        tx, ty, tz = params[b, 2], params[b, 3], params[b, 4]
        fl0 = Rb[0, 0] * FL[b, 0] + Rb[0, 1] * FL[b, 1] + Rb[0, 2] * FL[b, 2]
        fl1 = Rb[1, 0] * FL[b, 0] + Rb[1, 1] * FL[b, 1] + Rb[1, 2] * FL[b, 2]
        fl2 = Rb[2, 0] * FL[b, 0] + Rb[2, 1] * FL[b, 1] + Rb[2, 2] * FL[b, 2]
        z0, z1, z2 = _cross(tx, ty, tz, fl0, fl1, fl2)
        for k in range(3):
            FL[p, k] += Rb[k, 0] * FL[b, 0] + Rb[k, 1] * FL[b, 1] + Rb[k, 2] * FL[b, 2]
            FA[p, k] += Rb[k, 0] * FA[b, 0] + Rb[k, 1] * FA[b, 1] + Rb[k, 2] * FA[b, 2]
        FA[p, 0] += z0
        FA[p, 1] += z1
        FA[p, 2] += z2
    for k in range(3):
        out[k] = FL[0, k]
        out[3 + k] = FA[0, k]
