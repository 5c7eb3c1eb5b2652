"""The legs' gravity torques (`robot.statics.leg_gravity_torques`) against MuJoCo's own bias forces; the whole
robot's inverse dynamics (`robot.dynamics`) against MuJoCo's and Pinocchio's."""

from __future__ import annotations

import mujoco
import numpy as np

from scout_agent.robot import constants as C
from scout_agent.robot.dynamics import dynamics_params, inverse_dynamics
from scout_agent.robot.kinematics import LegKinematics
from scout_agent.robot.model import aliengo_mjcf
from scout_agent.robot.statics import leg_gravity_torques


def test_leg_gravity_torques_match_mujocos_bias_forces_at_rest_in_any_pose_and_attitude() -> None:
    m = mujoco.MjModel.from_xml_string(aliengo_mjcf())
    m.opt.gravity[:] = (0.0, 0.0, -C.LUNAR_G)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(4)
    out = np.empty(12)
    largest = 0.0
    for _ in range(20):
        q = C.HOME_Q + rng.normal(0.0, 0.3, 12)
        quat = rng.normal(size=4)
        d.qpos[:] = 0.0
        d.qpos[3:7] = quat / np.linalg.norm(quat)
        d.qpos[7:] = q
        d.qvel[:] = 0.0  # at rest: the bias forces are gravity's alone
        mujoco.mj_forward(m, d)
        g_base = d.xmat[1].reshape(3, 3).T @ m.opt.gravity
        leg_gravity_torques(q, g_base, out)
        np.testing.assert_allclose(out, d.qfrc_bias[6:], atol=1e-8)
        largest = max(largest, float(np.abs(out).max()))
    # not a trivial agreement: the legs' weight loads the joints by tenths of a newton-metre at lunar g
    assert largest > 0.1


def test_a_standing_controller_holds_its_legs_weight_only_when_asked_and_only_standing() -> None:
    """`ControllerConfig.stand_leg_gravity`: once the gait froze on four feet, the joints add exactly the legs'
    gravity torques (the estimate's gravity direction); walking, and with the option off, nothing changes."""
    from dataclasses import replace

    from scout_agent.control.controller import ControllerConfig, RobotState, TrotController

    q = np.array(C.HOME_Q, dtype=float)
    tilt = 0.1  # a trunk pitched by 0.1 rad: gravity has a base-frame x component
    R = np.array([[np.cos(tilt), 0.0, np.sin(tilt)], [0.0, 1.0, 0.0], [-np.sin(tilt), 0.0, np.cos(tilt)]])
    held, plain = (TrotController(replace(ControllerConfig(), stand_leg_gravity=on)) for on in (True, False))
    dt = 0.01
    for k in range(60):
        s = RobotState(k * dt, np.array([0.0, 0.0, 0.33]), R, np.zeros(3), np.zeros(3), q, np.zeros(12),
                       np.ones(4, bool))  # fmt: skip
        both = []
        for ctl in (held, plain):
            ctl.hold = k >= 30
            both.append(ctl.step(s, dt).tau_ff)
        if not held.standing:
            np.testing.assert_array_equal(both[0], both[1])
    assert held.standing and plain.standing
    expected = np.empty(12)
    leg_gravity_torques(q, R.T @ np.array([0.0, 0.0, -ControllerConfig().gravity]), expected)
    np.testing.assert_allclose(both[0] - both[1], expected, atol=1e-9)
    assert np.abs(expected).max() > 0.05


def test_inverse_dynamics_matches_mujocos_and_pinocchios_in_motion() -> None:
    # the simulator's own inverse dynamics (mj_inverse: M·a + bias − passive, no contact: the robot alone, gravity
    # off) and Pinocchio's RNEA on the model it reads, at random poses, rates and accelerations; the trunk at the
    # origin, its linear velocity zero (the forces do not depend on it)
    import pinocchio as pin

    m = mujoco.MjModel.from_xml_string(aliengo_mjcf())
    m.opt.gravity[:] = 0.0
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT  # free of stops, contacts: M·a + h only
    d = mujoco.MjData(m)
    model = LegKinematics().model
    model.gravity.linear = np.zeros(3)
    data = model.createData()
    params = dynamics_params(model)
    damping = np.array(model.damping[6:])
    rng = np.random.default_rng(7)
    out = np.empty(18)
    for _ in range(20):
        q = C.HOME_Q + rng.normal(0.0, 0.4, 12)
        dq, qdd = rng.normal(0.0, 5.0, 12), rng.normal(0.0, 80.0, 12)
        w, dw, acc = rng.normal(0.0, 1.0, 3), rng.normal(0.0, 10.0, 3), rng.normal(0.0, 3.0, 3)
        inverse_dynamics(params, q, dq, w, acc, dw, qdd, out)
        d.qpos[:] = 0.0
        d.qpos[3] = 1.0
        d.qpos[7:] = q
        d.qvel[:] = np.r_[0.0, 0.0, 0.0, w, dq]
        d.qacc[:] = np.r_[acc, dw, qdd]
        mujoco.mj_inverse(m, d)
        expected = d.qfrc_inverse.copy()
        expected[6:] -= damping * dq  # MuJoCo's joint damping is a passive force, not inertia
        np.testing.assert_allclose(out, expected, rtol=1e-9, atol=1e-9)
        q_pin = pin.neutral(model)
        q_pin[7:] = q
        ref = pin.rnea(model, data, q_pin, np.r_[0.0, 0.0, 0.0, w, dq], np.r_[acc, dw, qdd])
        np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-12)
