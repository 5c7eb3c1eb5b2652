"""The low-level interface on its own: the simulated Aliengo driven by plain `LowCmd`s with no robot software,
and the robot's software run on plain `LowState`s with no simulator."""

from __future__ import annotations

import numpy as np
import pytest

from scout_agent.lowlevel import LowCmd, LowState
from scout_agent.onboard.software import OnboardSoftware
from scout_agent.robot import constants as C
from scout_agent.sim.aliengo import SimulatedAliengo
from scout_agent.sim.terrain import RampConfig, make_ramps
from scout_agent.state_estimation.launch import LaunchPose

Z12 = np.zeros(12)


def _hold(kp: float = 40.0, kd: float = 1.0) -> LowCmd:
    return LowCmd(C.HOME_Q.copy(), Z12, np.full(12, kp), np.full(12, kd), Z12)


def test_the_simulated_aliengo_stands_under_a_plain_joint_pd_command():
    hw = SimulatedAliengo(make_ramps(RampConfig(slope_deg=0.0)))
    with pytest.raises(RuntimeError, match="first write"):
        hw.read()  # no packet before the first control tick
    for _ in range(200):  # 2 s
        hw.write(_hold())
    reading, truth = hw.read(), hw.truth(np.ones(4, bool))
    assert not hw.fell and truth.contact.all()
    assert hw.t == pytest.approx(2.0)
    assert np.abs(reading.q - C.HOME_Q).max() < 0.1  # the PD holds the posture (sag, zero offsets)
    weight = C.TOTAL_MASS * C.LUNAR_G
    assert reading.foot_force.sum() == pytest.approx(weight, rel=0.3)  # 1-D sensors with gain errors
    assert truth.foot_force_world[:, 2].sum() == pytest.approx(weight, rel=0.05)  # standing still


def test_dq_des_acts_through_the_velocity_gain_as_a_motor_driver_applies_it():
    """τ = τ_ff + Kp (q_des − q) + Kd (dq_des − dq): a command with dq_des is the same physics as one with
    Kd·dq_des added to τ_ff."""
    terrain = make_ramps(RampConfig(slope_deg=0.0))
    a, b = SimulatedAliengo(terrain), SimulatedAliengo(terrain)
    dq_des = np.tile([0.2, -0.3, 0.4], 4)
    with_dq = _hold()._replace(dq_des=dq_des)
    folded = _hold()._replace(tau_ff=1.0 * dq_des)  # kd = 1
    for _ in range(30):
        a.write(with_dq)
        b.write(folded)
    np.testing.assert_array_equal(a.data.qpos, b.data.qpos)
    c = SimulatedAliengo(terrain)
    for _ in range(30):
        c.write(_hold())
    assert np.abs(c.data.qpos - a.data.qpos).max() > 1e-4  # and dq_des did act


def test_the_robot_software_runs_on_readings_alone():
    """Fed the readings of a robot standing still (gravity on the accelerometer, the home posture, loaded feet),
    the software keeps its launch pose, finds its feet on the ground and commands finite joint targets."""
    robot = OnboardSoftware(LaunchPose(1.0, 2.0, 0.3, 0.0), control_dt=0.01)
    for _ in range(300):
        cmd = robot.command(0.0, 0.0)
        assert all(np.shape(v) == (12,) and np.isfinite(v).all() for v in cmd)
        sample = robot.sense(
            LowState(
                np.array([0.0, 0.0, C.LUNAR_G]), np.zeros(3), C.HOME_Q.copy(), Z12, Z12, 0.0, np.full(4, 30.0)
            )
        )
    assert sample.contact.all() and robot.estimator.anchored
    np.testing.assert_allclose(sample.base.pos[:2], [1.0, 2.0], atol=1e-6)
    assert sample.t == pytest.approx(3.0)
    with pytest.raises(RuntimeError, match="before command"):
        OnboardSoftware(LaunchPose(0, 0, 0, 0), 0.01).sense(_reading())


def _reading() -> LowState:
    return LowState(np.zeros(3), np.zeros(3), C.HOME_Q.copy(), Z12, Z12, 0.0, np.zeros(4))
