"""Standstills (state_estimation/standstill.py): the zero-rate update against the sensor model's true gyro bias,
and the heading a standstill-calibrated walk keeps against the estimator without them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scout_agent.loop import SimConfig, SimulatedScout
from scout_agent.run import ScoutRunConfig, run_scout
from scout_agent.sim.sensors import SensorConfig
from scout_agent.sim.sensors.imu import ImuConfig
from scout_agent.sim.terrain import RampConfig, make_ramps
from scout_agent.state_estimation.launch import LaunchSurvey
from scout_agent.state_estimation.standstill import (
    MOON_ROTATION_RAD_S,
    StandstillConfig,
    ZeroRateWindow,
    start_standstill_s,
)

FEET_B = np.array([[0.24, 0.13, -0.33], [0.24, -0.13, -0.33], [-0.24, 0.13, -0.33], [-0.24, -0.13, -0.33]])


def _window(turn: np.ndarray, bias: np.ndarray, span_s: float = 3.0) -> ZeroRateWindow:
    """A window over which the trunk turned by `turn` (rotation vector, base frame) on planted feet, with a gyro
    reading the turn's rate plus `bias`."""
    w = ZeroRateWindow(0.0, FEET_B)
    for _ in range(300):
        w.add(turn / span_s + bias, span_s / 300)
    return w


def test_a_window_separates_the_gyro_bias_from_the_trunk_turning_on_its_feet():
    turn = np.array([4e-4, -3e-4, 1.2e-3])  # the trunk turned (the controller holding a drifting estimate)
    bias = np.array([2e-4, -5e-4, 7e-4])
    feet_after = Rotation.from_rotvec(turn).inv().apply(FEET_B) + [0.01, 0.0, 0.002]  # feet stay in the world
    z = _window(turn, bias).close(feet_after, 0.003, 2e-3)
    assert z is not None
    np.testing.assert_allclose(z, bias, atol=1e-9)
    # without the kinematic term the turn would read as bias: 4e-4 rad/s off about z
    assert abs(turn[2] / 3.0) > 3e-4


def test_a_window_is_refused_when_a_foot_slipped_or_the_trunk_rocked():
    slipped = FEET_B.copy()
    slipped[1, 0] += 0.01
    assert _window(np.zeros(3), np.zeros(3)).close(slipped, 0.003, 2e-3) is None
    rocked = np.array([0.0, 4e-3, 0.0])
    feet = Rotation.from_rotvec(rocked).inv().apply(FEET_B)
    assert _window(rocked, np.zeros(3)).close(feet, 0.003, 2e-3) is None  # 4e-3 rad over the window


def test_the_start_standstill_is_sized_from_the_warm_up_and_the_moon_turns_too_slowly_to_matter():
    t = start_standstill_s()
    assert 15.0 < t < 20.0  # BMI088 on a board warming 8 K with τ 10 min
    assert StandstillConfig().start_s >= t
    assert start_standstill_s(warmup_k=2.0) > 2.0 * t  # a board that warms less: stand longer
    # the Moon's rotation is under a tenth of what a start standstill resolves
    assert MOON_ROTATION_RAD_S < 0.1 * np.sqrt(StandstillConfig().zaru_var(3.0) / 7)


def _true_gyro_bias(sim: SimulatedScout) -> np.ndarray:
    """The sensor model's gyro offset now (test only: the robot never reads it): turn-on bias and its walk, the
    temperature term, and g-sensitivity on the tick's specific force."""
    imu = sim.hardware.sensors.imu
    g = imu.gyro_G if imu.gyro_G is not None else np.zeros((3, 3))
    f_cal = imu._f_cal if imu._f_cal is not None else np.zeros(3)
    dtemp = imu.errors.temperature.delta_k_at(imu.t)
    return imu.gyro_bias + imu.gyro_tc * dtemp + g @ (sim.hardware._blk_acc.mean(axis=0) - f_cal)


def test_standing_still_the_estimated_gyro_bias_converges_to_the_sensor_models_truth():
    # a unit whose power-on offset is 1.5e-3 rad/s per axis (3σ of what the filter assumes): only the
    # standstill can find it
    sensors = SensorConfig(seed=3, imu=ImuConfig(gyro_turn_on_bias=1.5e-3))
    sim = SimulatedScout(
        make_ramps(RampConfig(slope_deg=0.0)), None, SimConfig(sensors=sensors, launch=LaunchSurvey("exact"))
    )
    sim.robot.controller.hold = True
    err0 = np.abs(sim.robot.estimator.ekf.bg - _true_gyro_bias(sim))
    for _ in range(int(25.0 / sim.control_dt)):
        sim.step(0.0, 0.0)
    e = sim.robot.estimator
    assert sim.robot.controller.standing and not sim.fell
    assert e.zaru_updates >= 6
    err = np.abs(e.ekf.bg - _true_gyro_bias(sim))
    sd = np.sqrt(np.diag(e.ekf.P)[9:12])
    assert err0.max() > 1e-3
    assert np.all(err < 3.0 * sd + 2e-5), (err, sd)  # the covariance holds the error
    assert err[2] < 2.5e-4 and np.all(err < 0.3 * err0)
    assert sd[2] < 1.5e-4


@pytest.fixture(scope="module")
def calibrated_and_not():
    """One straight 10 m walk from the exact launch pose with a gyro whose power-on offset was not removed
    (σ 3e-3 rad/s per axis, 0.17 °/s: a sixth of the BMI088's ±1 °/s zero-rate offset), with and without
    standstills."""
    sensors = SensorConfig(imu=ImuConfig(gyro_turn_on_bias=3e-3))
    sim = SimConfig(sensors=sensors, launch=LaunchSurvey("exact"))
    off = replace(sim, estimator=replace(sim.estimator, standstill=StandstillConfig(enabled=False)))
    cfg = ScoutRunConfig(scene="ramps", slope_deg=0.0, seed=2, localize="off", sim=sim, standstills="on")
    return run_scout(cfg, progress=False), run_scout(replace(cfg, sim=off), progress=False)


def test_a_standstill_calibrated_walk_keeps_its_heading_where_the_estimator_before_did_not(
    calibrated_and_not,
):
    on, off = calibrated_and_not
    assert on["reached_goal"] and off["reached_goal"] and not on["fell"]
    assert on["standstills"]["start_s"] >= StandstillConfig().start_s
    assert on["zaru"]["updates"] >= 7 and off["zaru"]["updates"] == 0
    assert on["yaw_error_max_deg"] < 1.2 < off["yaw_error_max_deg"]  # measured 0.82 and 1.80
    assert on["inside_3sigma_frac"] >= 0.95


def test_auto_standstills_follow_the_route_length_and_bad_modes_are_named():
    from scout_agent.errors import ScoutConfigError
    from scout_agent.run import ScoutRunConfig, run_scout, use_standstills

    short, long = np.array([[0.0, 0.0], [20.0, 0.0]]), np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 30.0]])
    auto = ScoutRunConfig()
    assert auto.standstills == "auto"
    assert not use_standstills(auto, short) and use_standstills(auto, long)  # 20 m: walk at once; 70 m: stand
    assert use_standstills(ScoutRunConfig(standstills="on"), short)
    assert not use_standstills(ScoutRunConfig(standstills="off"), long)
    with pytest.raises(ScoutConfigError, match="valid: auto, on, off"):
        run_scout(ScoutRunConfig(standstills="yes", sim_seconds=0.1), progress=False)


def test_the_gyro_tempco_is_learnt_from_windows_at_different_temperatures():
    from scout_agent.state_estimation.bias_temperature import GyroTempco

    tco = np.radians(0.015)
    rng = np.random.default_rng(4)
    k_true = np.array([-1.7, 0.5, 1.0]) * tco  # a unit 1.7σ off on x (as the seed-23 run's part)
    b0 = rng.normal(0.0, 1e-4, 3)
    model = GyroTempco(tco)
    k, sd = model.slope()
    assert np.all(k == 0.0) and np.allclose(sd, tco)  # the datasheet before any window
    model.add(20.0, b0, np.full(3, (1.5e-4) ** 2))
    assert np.allclose(model.slope()[1], tco)  # one temperature says nothing of a slope
    # a warming board: windows over 4 K, each with the gyro's 1.5e-4 rad/s of white noise
    temps = 20.0 + 8.0 * (1.0 - np.exp(-np.linspace(20.0, 500.0, 14) / 600.0))
    errs = []
    for t in temps:
        model.add(t, b0 + k_true * (t - 20.0) + rng.normal(0.0, 1.5e-4, 3), np.full(3, (1.5e-4) ** 2))
        k, sd = model.slope()
        errs.append(np.abs(k - k_true) / sd)
    assert np.all(sd < 0.25 * tco)  # learnt: a quarter of the datasheet's spread
    assert np.all(np.abs(k - k_true) < 3.0 * sd)
    assert np.mean(np.concatenate(errs) ** 2) < 3.0  # its σ holds the error along the way (χ²₁ mean 1)
    off = GyroTempco(0.0)  # an ideal IMU: nothing to learn, no slope
    off.add(20.0, b0, np.ones(3))
    assert np.all(off.slope()[0] == 0.0) and np.all(off.slope()[1] == 0.0)


def _warming_standstills(rng: np.random.Generator, k_true: float, start_windows: int, creep: float):
    """(temperature, offset, standstill) of each window: a power-on standstill of `start_windows` 3 s
    windows, then 15 pauses of 2 every 45 s, on a board warming 8 K with τ 600 s; each standstill one creep
    draw N(0, creep²) shared by its windows, each window the gyro's white noise (1.4e-4 rad/s)."""
    rows, t = [], 0.0
    for j, n in enumerate([start_windows] + [2] * 15):
        c = rng.normal(0.0, creep)
        for _ in range(n):
            t += 3.0
            temp = 20.0 + 8.0 * (1.0 - np.exp(-t / 600.0))
            rows.append((temp, 2e-4 + k_true * (temp - 20.0) + c + rng.normal(0.0, 1.4e-4), j))
        t += 45.0
    return rows


def test_the_tempco_fit_takes_each_standstills_creep_as_one_draw_and_learns_the_slope_within_it():
    """The stance's creep is one draw per standstill (standstill.py). Fitted with a random intercept per
    standstill, a long power-on standstill on a warming board measures k from the temperature change within
    it, where the creep cancels: its σ is honest over many walks (normalised error² ≈ 1), and its error smaller
    than the fit that counts the creep in every window as an independent error (the build before), which is
    also overconfident: the power-on standstill's windows share one draw it counted forty times (measured:
    normalised error² 1.0 against 5.6, rms error 2.5e-5 against 3.7e-5 rad/s/K)."""
    from scout_agent.state_estimation.bias_temperature import GyroTempco

    tco, creep, white = np.radians(0.015), 1.6e-4, 1.4e-4
    rng = np.random.default_rng(7)
    z_grouped, z_old, sd_start, err_g, err_o = [], [], [], [], []
    for _ in range(150):
        k_true = rng.normal(0.0, tco)
        rows = _warming_standstills(rng, k_true, start_windows=40, creep=creep)
        grouped, old = GyroTempco(tco), GyroTempco(tco)
        for i, (temp, z, j) in enumerate(rows):
            zz = np.full(3, z)
            grouped.add(temp, zz, np.full(3, white**2), j, creep**2)
            old.add(temp, zz, np.full(3, white**2 + 2 * creep**2))
            if i == 39:  # the power-on standstill alone
                sd_start.append(grouped.slope()[1][2])
        (kg, sg), (ko, so) = grouped.slope(), old.slope()
        z_grouped.append((kg[2] - k_true) / sg[2])
        z_old.append((ko[2] - k_true) / so[2])
        err_g.append(kg[2] - k_true)
        err_o.append(ko[2] - k_true)
    assert 0.7 < np.mean(np.square(z_grouped)) < 1.4  # honest σ
    assert np.median(sd_start) < 0.3 * tco  # learnt before the walk: under a third of the datasheet's spread
    assert np.mean(np.square(z_old)) > 3.0  # the fit before: overconfident
    assert np.sqrt(np.mean(np.square(err_g))) < 0.8 * np.sqrt(np.mean(np.square(err_o)))
    # without a group (None) every window is its own draw: the fit before
    a, b = GyroTempco(tco), GyroTempco(tco)
    for temp, z, _ in _warming_standstills(rng, 0.5 * tco, 10, creep):
        a.add(temp, np.full(3, z), np.full(3, white**2 + creep**2))
        b.add(temp, np.full(3, z), np.full(3, white**2), None, creep**2)
    assert np.allclose(a.slope()[0], b.slope()[0]) and np.allclose(a.slope()[1], b.slope()[1])


def test_a_pauses_windows_share_one_creep_draw_and_their_average_keeps_its_variance():
    # the stance creeps as a whole over a pause (one draw, 1.6e-4 rad/s rms measured per pause on the 100 m
    # field): fusing a pause's windows must not shrink that draw's variance as if each had its own
    c = StandstillConfig()
    n = c.creep_windows
    fused = 1.0 / (n / c.zaru_var(3.0))  # n windows fused as independent measurements
    assert fused >= c.creep_std_rad_s**2
    assert fused == pytest.approx(c.zaru_var(3.0, 0.0) / n)
    one = replace(c, creep_windows=1).zaru_var(3.0)
    assert c.zaru_var(3.0) - one == pytest.approx((n - 1) * c.creep_std_rad_s**2)

    # and synthetic pauses: each window reads bias + the pause's creep draw + its own white noise and kinematic
    # error; the filter's variance after the pause must hold the error (normalised error² near 1), where
    # counting the creep once per window (as before) is overconfident
    def nees(cfg: StandstillConfig) -> float:
        rng = np.random.default_rng(7)
        own = np.sqrt(cfg.gyro_density**2 / 3.0 + 2.0 * cfg.kin_std_rad**2 / 9.0)  # per window, 3 s
        out = []
        for _ in range(2000):
            b, bh, P = rng.normal(0.0, 5e-4), 0.0, (5e-4) ** 2  # the prior holds the bias
            creep = rng.normal(0.0, cfg.creep_std_rad_s)
            for _k in range(n):
                k = P / (P + cfg.zaru_var(3.0))
                bh += k * (b + creep + rng.normal(0.0, own) - bh)
                P *= 1.0 - k
            out.append((bh - b) ** 2 / P)
        return float(np.mean(out))

    assert 0.85 < nees(c) < 1.15
    assert nees(replace(c, creep_windows=1)) > 1.25


def test_a_zero_rate_window_corrects_the_offset_and_leaves_the_heading_as_it_was() -> None:
    """`StandstillConfig.zaru_holds_heading` (off by default): after a minute of walking with an offset error the filter's heading
    and z offset are correlated; the window's update (as the estimator makes it) moves the offset toward the
    window and shrinks its variance, but turns neither the heading nor its variance (the window's innovation is
    mostly the pause's creep, which the walk never integrated)."""
    from scout_agent.state_estimation.ekf import ErrorStateEKF

    ss = replace(StandstillConfig(), zaru_holds_heading=True)
    g = np.array([0.0, 0.0, -1.62])
    ekf = ErrorStateEKF(np.eye(3), np.zeros(3), np.zeros(3), g)
    for _ in range(6000):  # 60 s at 100 Hz, still: heading and the z offset become correlated
        ekf.propagate(np.zeros(3), -g, 0.01)
    cross = ekf.P[2, 11] / np.sqrt(ekf.P[2, 2] * ekf.P[11, 11])
    assert cross < -0.5  # the heading's error is the offset's integral: strongly correlated
    yaw0, var_h0, var_b0 = np.arctan2(ekf.R[1, 0], ekf.R[0, 0]), ekf.heading_variance(), ekf.P[11, 11]
    z = np.array([0.0, 0.0, 2e-4])  # the window read 2e-4 rad/s more than the filter's offset
    H = np.zeros((3, 15))
    H[:, 9:12] = np.eye(3)
    var = ss.zaru_var(3.0)
    ekf.update(z - ekf.bg, H, np.full(3, var), hold_heading=ss.zaru_holds_heading)
    assert 0.0 < ekf.bg[2] < 2e-4 and ekf.P[11, 11] < 0.9 * var_b0
    assert np.arctan2(ekf.R[1, 0], ekf.R[0, 0]) == pytest.approx(yaw0, abs=1e-9)
    assert ekf.heading_variance() == pytest.approx(var_h0, rel=1e-6)
    # the plain update would have turned the heading by the correlation's share of the innovation
    plain = ErrorStateEKF(np.eye(3), np.zeros(3), np.zeros(3), g)
    for _ in range(6000):
        plain.propagate(np.zeros(3), -g, 0.01)
    plain.update(z - plain.bg, H, np.full(3, var))
    assert abs(np.arctan2(plain.R[1, 0], plain.R[0, 0]) - yaw0) > 1e-3


class _Board:
    """A stand-in for the estimator the planner reads (unit test): fused windows every 3 s while held, a
    thermometer warming at `rate` K/s, the tempco's σ shrinking as 1/√windows from the datasheet's."""

    def __init__(self, rate: float, learns: bool) -> None:
        self.rate, self.learns = rate, learns
        self.standstill_s, self.zaru_updates, self.t = 0.0, 0, 0.0
        self.bias_heading_rad = 0.0

    @property
    def gyro_tempco_sd_z(self) -> float:
        sd = np.radians(0.015)
        return sd / np.sqrt(1.0 + self.zaru_updates) if self.learns else sd

    @property
    def imu_temp_c(self) -> float:  # no reading before the first tick (the estimator's NaN)
        return 20.0 + self.rate * self.t if self.t > 0 else float("nan")

    def tick(self, held: bool, dt: float = 0.5) -> None:
        self.t += dt
        if held:
            self.standstill_s += dt
            self.zaru_updates = int(self.standstill_s // 3.0)


def _start_length(board: _Board, config: StandstillConfig) -> float:
    from scout_agent.state_estimation.standstill import StandstillPlanner

    planner = StandstillPlanner(board, config)
    while planner.hold(board.t):
        board.tick(True)
        assert board.t < 1000.0
    return planner.stands[0]["s"]


def test_the_power_on_standstill_stands_on_while_the_warming_boards_tempco_is_unknown():
    """On a board warming 0.013 K/s (8 K, τ 600 s) the power-on standstill lasts until σ_k̂z·dT/dt is under
    `start_drift_max`, and no longer; a board that does not warm, or the option off, stands `start_s`; a
    tempco that is never learnt stands `start_max_s`."""
    c = StandstillConfig()
    warming = _start_length(_Board(8.0 / 600.0, learns=True), c)
    # σ_k/√(1+n)·0.0133 ≤ 1e-6 → n ≥ 11.0 windows: 36 s (the windows fuse every 3 s)
    assert 33.0 <= warming <= 40.0
    assert _start_length(_Board(0.0, learns=True), c) == pytest.approx(c.start_s, abs=1.5)
    assert _start_length(_Board(8.0 / 600.0, learns=True), replace(c, start_drift_max=0.0)) == pytest.approx(
        c.start_s, abs=1.5
    )
    assert _start_length(_Board(8.0 / 600.0, learns=False), c) == pytest.approx(c.start_max_s, abs=1.5)
    # a walk's time limit allows the extension (run.py), and none when it is off
    from scout_agent.state_estimation.standstill import StandstillPlanner

    assert StandstillPlanner(_Board(0.0, True), c).start_extension_s == c.start_max_s - c.start_s
    assert StandstillPlanner(_Board(0.0, True), replace(c, start_drift_max=0.0)).start_extension_s == 0.0
