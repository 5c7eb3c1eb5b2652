"""The one Aliengo description: MuJoCo and Pinocchio (and the closed form) agree on feet and Jacobians."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from scout_agent.robot import constants as C
from scout_agent.robot import kinematics as K
from scout_agent.robot.model import build_aliengo_spec


@pytest.fixture(scope="module")
def mj():
    m = build_aliengo_spec().compile()
    return m, mujoco.MjData(m)


@pytest.fixture(scope="module")
def lk():
    return K.LegKinematics()


def _random_q(rng):
    return C.HOME_Q + rng.uniform(-0.4, 0.4, 12)


def test_mass_is_the_published_aliengo(mj, lk):
    m, _ = mj
    assert C.TOTAL_MASS == pytest.approx(20.637, abs=1e-3)
    assert m.body_subtreemass[1] == pytest.approx(C.TOTAL_MASS)
    import pinocchio as pin

    assert pin.computeTotalMass(lk.model) == pytest.approx(C.TOTAL_MASS)


def test_mujoco_and_pinocchio_feet_and_jacobians_agree(mj, lk):
    m, d = mj
    rng = np.random.default_rng(0)
    feet = [m.body(n).id for n in C.FOOT_BODIES]
    for _ in range(20):
        q = _random_q(rng)
        d.qpos[:] = 0
        d.qpos[3] = 1
        d.qpos[7:] = q
        mujoco.mj_forward(m, d)
        mj_feet = d.xpos[feet] - d.xpos[1]
        np.testing.assert_allclose(lk.feet_base(q), mj_feet, atol=1e-10)
        J_pin = lk.foot_jacobians_base(q)
        for i, body in enumerate(feet):
            jacp = np.zeros((3, m.nv))
            mujoco.mj_jacBody(m, d, jacp, None, body)
            np.testing.assert_allclose(J_pin[i], jacp[:, 6 + 3 * i : 9 + 3 * i], atol=1e-10)


def test_closed_form_matches_pinocchio_and_inverts(lk):
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = _random_q(rng)
        np.testing.assert_allclose(K.fk(q), lk.feet_base(q), atol=1e-12)
        np.testing.assert_allclose(K.jacobians(q), lk.foot_jacobians_base(q), atol=1e-12)
        np.testing.assert_allclose(K.ik(K.fk(q)), q, atol=1e-9)
        dq = rng.normal(size=12)
        np.testing.assert_allclose(
            lk.feet_vel_base(q, dq), np.einsum("lij,lj->li", K.jacobians(q), dq.reshape(4, 3))
        )


def test_closed_form_foot_motion_matches_pinocchio_frame_velocities(lk):
    """The estimators' per-tick feet (compiled closed form) against Pinocchio's foot frames (base fixed)."""
    import pinocchio as pin

    m, d = lk.model, lk.model.createData()
    rng = np.random.default_rng(2)
    feet, vel, omega, J = np.empty((4, 3)), np.empty((4, 3)), np.empty((4, 3)), np.empty((4, 3, 3))
    for _ in range(20):
        q, dq = _random_q(rng), rng.normal(size=12)
        K.leg_motion(q, dq, feet, vel, omega, J)
        qf, vf = pin.neutral(m), np.zeros(m.nv)
        qf[7:], vf[6:] = q, dq
        pin.forwardKinematics(m, d, qf, vf)
        for i, name in enumerate(C.FOOT_BODIES):
            f = m.getFrameId(name)
            v = pin.getFrameVelocity(m, d, f, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(feet[i], pin.updateFramePlacement(m, d, f).translation, atol=1e-12)
            np.testing.assert_allclose(vel[i], v.linear, atol=1e-12)
            np.testing.assert_allclose(omega[i], v.angular, atol=1e-12)


def test_home_posture_stands_about_034_m():
    feet = K.fk(C.HOME_Q)
    assert -feet[:, 2].mean() + C.FOOT_RADIUS == pytest.approx(0.337, abs=0.005)
    np.testing.assert_allclose(np.abs(feet[:, 1]), C.HIP_Y + C.THIGH_OFFSET)
