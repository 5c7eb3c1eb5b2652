"""Sensor models: their noise is what the config says, and what they report agrees with simulator ground truth."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from scout_agent.loop import SimulatedScout
from scout_agent.onboard.drivers import ContactDetection, ContactDetector
from scout_agent.robot import kinematics as K
from scout_agent.robot.constants import HOME_Q
from scout_agent.robot.statics import leg_forces_from_torques
from scout_agent.sim.sensors import (
    ContactConfig,
    FootContactSensors,
    ImuConfig,
    ImuModel,
    JointSensorConfig,
    JointSensors,
)
from scout_agent.sim.terrain import RampConfig, make_ramps

DT = 0.002


def test_imu_white_noise_matches_the_datasheet_density():
    cfg = ImuConfig(acc_bias_walk=0.0, gyro_bias_walk=0.0)
    imu = ImuModel(cfg, np.random.default_rng(1))
    true = np.tile([0.0, 0.0, 1.62], (20000, 1))
    acc, gyro = imu.sample(true, np.zeros((20000, 3)), DT)
    assert acc.std(axis=0) == pytest.approx(np.full(3, cfg.acc_noise_density / math.sqrt(DT)), rel=0.05)
    assert gyro.std(axis=0) == pytest.approx(np.full(3, cfg.gyro_noise_density / math.sqrt(DT)), rel=0.05)
    # the turn-on bias is constant without a walk, and it is the mean error
    np.testing.assert_allclose(acc.mean(axis=0) - true[0], imu.acc_bias, atol=5e-4)


def test_imu_bias_walks_as_configured():
    cfg = ImuConfig(gyro_bias_walk=1e-3)
    ends = []
    for seed in range(200):
        imu = ImuModel(cfg, np.random.default_rng(seed))
        b0 = imu.gyro_bias.copy()
        imu.sample(np.zeros((500, 3)), np.zeros((500, 3)), DT)  # 1 s
        ends.append(imu.gyro_bias - b0)
    assert np.std(ends) == pytest.approx(1e-3 * math.sqrt(1.0), rel=0.1)


def test_encoders_quantise_and_the_driver_velocity_follows_a_ramp():
    cfg = JointSensorConfig(torque_gain_error=0.0, torque_noise_nm=0.0)
    js = JointSensors(cfg, np.random.default_rng(0), np.zeros(12))
    t = np.arange(1, 501)[:, None] * DT
    q_true = np.tile(0.5 * t, (1, 12))  # 0.5 rad/s on every joint
    q, dq, tau, energy = js.sample(q_true, np.ones((500, 12)), DT)
    steps = q / cfg.encoder_resolution_rad
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    assert np.abs(q - q_true).max() <= cfg.encoder_resolution_rad / 2 + 1e-12
    assert dq[-100:].mean() == pytest.approx(0.5, rel=0.01)
    # energy at every step: ∫ |τ q̇| dt ≈ 12 joints × 1 N·m × 0.5 rad/s × 1 s, less the filter's start-up
    assert energy == pytest.approx(6.0, rel=0.02)


def test_torque_from_current_has_a_gain_error_per_joint_and_noise():
    cfg = JointSensorConfig(torque_gain_error=0.05, torque_noise_nm=0.2)
    js = JointSensors(cfg, np.random.default_rng(3), np.zeros(12))
    _, _, tau, _ = js.sample(np.zeros((4000, 12)), np.full((4000, 12), 10.0), DT)
    np.testing.assert_allclose(tau.mean(axis=0), 10.0 * js.gain, atol=0.02)
    assert tau.std(axis=0).mean() == pytest.approx(0.2, rel=0.1)
    assert np.abs(js.gain - 1.0).max() > 0.005


def test_foot_pressure_contact_has_hysteresis():
    feet = ContactDetector(ContactDetection(on_n=5.0, off_n=2.5))
    assert not feet.flags(np.full(4, 4.0)).any()  # below on: stays off
    assert feet.flags(np.full(4, 6.0)).all()  # above on
    assert feet.flags(np.full(4, 3.0)).all()  # between: stays on
    assert not feet.flags(np.full(4, 2.0)).any()  # below off
    with pytest.raises(ValueError, match="pressure, torques"):
        ContactDetection(source="vision")


def test_ground_forces_from_joint_torques_invert_the_stance_map():
    J = K.jacobians(HOME_Q)
    f = np.array([[1.0, -2.0, 15.0], [0.5, 0.0, 12.0], [0.0, 1.0, 8.0], [-1.0, 0.0, 20.0]])
    tau = -np.einsum("lji,lj->li", J, f).reshape(12)
    np.testing.assert_allclose(leg_forces_from_torques(J, tau, np.zeros(12)), f, atol=1e-9)


@pytest.fixture(scope="module")
def walk():
    sim = SimulatedScout(make_ramps(RampConfig(slope_deg=10.0)))
    rec = []
    for _ in range(int(8.0 / sim.control_dt)):
        s, g = sim.step(0.2, 0.0)
        rec.append((s, g, sim.robot.last_output.stance_forces.copy()))
    return sim, rec


def test_pressure_contact_agrees_with_the_true_contact(walk):
    _, rec = walk
    est = np.array([s.contact for s, _, _ in rec[100:]])
    true = np.array([g.contact for _, g, _ in rec[100:]])
    tp = (est & true).sum()
    assert tp / est.sum() > 0.95  # precision
    assert tp / true.sum() > 0.85  # recall: the sensor needs ≈ 5 N before it says contact


def test_driver_energy_is_within_3_percent_of_the_exact_energy_and_tick_sampling_misses_work(walk):
    sim, rec = walk
    measured = sum(s.joint_energy_j for s, _, _ in rec)
    exact = sum(g.joint_energy_j for _, g, _ in rec)
    assert exact == pytest.approx(sim.hardware.energy_true_j)
    assert measured == pytest.approx(exact, rel=0.03)
    once_per_tick = sum(float(np.abs(g.dq * s.tau).sum()) * sim.control_dt for s, g, _ in rec)
    assert once_per_tick < 0.95 * exact  # the old way: last physics step of each tick only


def test_torque_estimated_ground_forces_match_the_simulator_in_mid_stance(walk):
    _, rec = walk
    errs, norms = [], []
    for s, g, _ in rec[100:]:
        R = _quat_to_mat(g.base.quat)
        f_w = leg_forces_from_torques(K.jacobians(s.q), s.tau, np.zeros(12)) @ R.T
        for i in range(4):
            if g.contact[i] and g.foot_force_world[i, 2] > 10.0:
                errs.append(np.linalg.norm(f_w[i] - g.foot_force_world[i]))
                norms.append(np.linalg.norm(g.foot_force_world[i]))
    assert len(errs) > 200
    assert np.median(errs) / np.median(norms) < 0.25


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    from scout_agent.estimators.pipeline import quat_to_matrix

    return quat_to_matrix(q)


def test_realistic_imu_bias_follows_the_temperature_by_its_drawn_coefficients():
    from scout_agent.sim.sensors import ImuErrors, ImuTemperature

    # no white noise, no bias walk, no quantiser: the drift is the temperature's alone
    cfg = ImuConfig(acc_bias_walk=0.0, gyro_bias_walk=0.0, gyro_noise_density=0.0)
    errs = ImuErrors(
        temperature=ImuTemperature(warmup_k=8.0, warmup_tau_s=60.0, rate_k_per_h=0.0), gyro_lsb=0.0
    )
    imu = ImuModel(cfg, np.random.default_rng(4), errs)
    still = np.tile([0.0, 0.0, 1.62], (500, 1))
    first, _ = imu.sample(still, np.zeros((500, 3)), DT)

    def window() -> np.ndarray:  # 10 s of samples: the white noise averages out
        return np.concatenate([imu.sample(still, np.zeros((500, 3)), DT)[1] for _ in range(10)]).mean(axis=0)

    g0 = window()  # 1–11 s
    for _ in range(279):
        imu.sample(still, np.zeros((500, 3)), DT)
    g1 = window()  # 290–300 s
    t = np.linspace(0.0, 10.0, 101)
    dT = float(np.mean(errs.temperature.delta_k(290.0 + t)) - np.mean(errs.temperature.delta_k(1.0 + t)))
    np.testing.assert_allclose(g1 - g0, imu.gyro_tc * dT, rtol=1e-3)
    assert np.abs(imu.gyro_tc).max() > 1e-5  # drawn, not zero
    assert imu.temperature_c() == pytest.approx(20.0 + 8.0, abs=0.2)
    # quantised to the 16-bit LSB, and some samples were lost
    assert np.allclose(first / errs.acc_lsb, np.round(first / errs.acc_lsb), atol=1e-6)


def test_ideal_imu_errors_leave_the_datasheet_model_unchanged():
    from scout_agent.sim.sensors import ImuErrors

    a = ImuModel(ImuConfig(), np.random.default_rng(9))
    b = ImuModel(ImuConfig(), np.random.default_rng(9), ImuErrors.none())
    acc = np.tile([0.1, 0.2, 1.62], (50, 1))
    for x, y in zip(a.sample(acc, acc, DT), b.sample(acc, acc, DT), strict=True):
        np.testing.assert_array_equal(x, y)


def test_realistic_scale_and_misalignment_show_under_a_known_rate():
    from scout_agent.sim.sensors import ImuErrors

    errs = replace(ImuErrors.none(), gyro_scale=0.01, misalignment_rad=(0.0, 0.0, 0.01))
    imu = ImuModel(
        ImuConfig(gyro_noise_density=0.0, gyro_turn_on_bias=0.0, gyro_bias_walk=0.0),
        np.random.default_rng(2),
        errs,
    )
    _, g = imu.sample(np.zeros((10, 3)), np.tile([1.0, 0.0, 0.0], (10, 1)), DT)
    sx = imu.gyro_M[0, 0] - 1.0
    assert g[0, 0] == pytest.approx(1.0 + sx, abs=1e-4) and abs(sx) > 1e-4
    assert abs(g[0, 1]) > 1e-3  # a rotation about x leaks into y through the yaw misalignment


def test_joint_zero_offsets_and_foot_sensor_drift_and_saturation():
    js = JointSensors(JointSensorConfig(zero_offset_rad=0.005), np.random.default_rng(0), np.zeros(12))
    q, _, _, _ = js.sample(np.zeros((3, 12)), np.zeros((3, 12)), DT)
    np.testing.assert_allclose(q[-1], js.zero_offset, atol=JointSensorConfig().encoder_resolution_rad)
    assert np.abs(js.zero_offset).max() > 1e-3
    feet = FootContactSensors(
        ContactConfig(noise_n=0.0, offset_n=0.0, gain_error=0.0, offset_walk_n=0.1, saturation_n=50.0),
        np.random.default_rng(1),
    )
    r0 = feet.reading(np.full(4, 10.0), 0.0)
    drift = [feet.reading(np.full(4, 10.0), 1.0) - r0 for _ in range(100)]
    assert np.std(drift[-1]) > 0.3  # 100 s at 0.1 N/√s ≈ 1 N
    assert feet.reading(np.full(4, 500.0), 0.0).max() == 50.0


def test_lost_packets_repeat_the_last_reading_and_keep_the_energy():
    from scout_agent.sim.sensors import LinkTiming, SensorConfig, SensorSuite
    from scout_agent.sim.sensors.suite import TrueBlock

    suite = SensorSuite(SensorConfig(timing=LinkTiming(jitter_s=1e-4, packet_drop=0.3)), HOME_Q)
    k = 5
    total, ticks = 0.0, []
    for i in range(200):
        blk = TrueBlock(
            DT,
            np.tile([0, 0, 1.62], (k, 1)),
            np.zeros((k, 3)),
            np.tile(HOME_Q + 1e-3 * i, (k, 1)),
            np.ones((k, 12)),
            np.full(4, 10.0),
        )
        tick = suite.read(blk)
        ticks.append(tick)
        total += tick.joint_energy_j
    stale = [t for t in ticks if not t.fresh]
    assert 30 < len(stale) < 90 and suite.dropped == len(stale)
    for prev, t in zip(ticks, ticks[1:], strict=False):
        if not t.fresh:
            np.testing.assert_array_equal(t.q, prev.q)
    fresh = [t.stamp_s for t in ticks if t.fresh]
    assert np.all(np.diff(fresh) > 0) and np.std(np.diff(fresh)) > 1e-5
    # the energy of lost packets arrives with the next one: nothing is lost but the tail after the last fresh
    assert total > 0.9 * sum(abs(1.0 * t.dq).sum() * DT * k for t in ticks if t.fresh) * 0.5


def test_the_simulated_imu_sits_at_its_mounting_offset():
    """The realistic IMU is mounted off the trunk origin (sensors/suite.py): its accelerometer reads the origin's
    specific force plus ω̇ × r + ω × (ω × r). MuJoCo flags a site compiled at its body's origin as sharing the
    body's frame and then ignores a later `site_pos`; before that was cleared the IMU read at the origin while the
    estimator removed a lever arm that was not there (a 1.3° roll error after one 15° turn, issue 23)."""
    import mujoco

    from scout_agent.sim.aliengo import HardwareConfig, SimulatedAliengo
    from scout_agent.sim.sensors import SensorConfig

    terrain = make_ramps(RampConfig(slope_deg=10.0))
    r = np.array(SensorConfig.realistic().imu_offset_m)
    reads = []
    for offset in ((0.0, 0.0, 0.0), tuple(r)):
        sim = SimulatedAliengo(
            terrain, None, HardwareConfig(sensors=SensorConfig.realistic(imu_offset_m=offset))
        )
        m, d = sim.model, sim.data
        d.qvel[3:6] = [0.3, 0.5, 2.0]  # trunk angular velocity, trunk frame [rad/s]
        mujoco.mj_forward(m, d)
        adr = m.sensor_adr[m.sensor("imu_acc").id]
        reads.append((d.sensordata[adr : adr + 3].copy(), d.qvel[3:6].copy(), d.qacc[3:6].copy()))
    (f0, w, wdot), (f1, _, _) = reads
    expected = f0 + np.cross(wdot, r) + np.cross(w, np.cross(w, r))
    np.testing.assert_allclose(f1, expected, atol=1e-6)
    assert np.linalg.norm(f1 - f0) > 0.2  # the lever arm is felt: here more than an eighth of lunar g
