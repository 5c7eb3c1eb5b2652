"""The legs' climb bias from revisited footholds (state_estimation/climb_calibration.py)."""

from __future__ import annotations

import math

import numpy as np

from scout_agent.state_estimation.climb_calibration import ClimbCalibration, ClimbCalibrationConfig

# a trot's geometry: hips ±0.24 m along the base, feet below them; a diagonal pair in stance for half a period
HIP_X = (0.24, 0.24, -0.24, -0.24)
HIP_Y = (0.13, -0.13, 0.13, -0.13)


def _walk(cal: ClimbCalibration, climb: float, slope: float, tilt: float, rng, metres: float = 6.0) -> None:
    """A base walking +x at 0.2 m/s over ground rising `slope` (tan) with a trot of 0.1 m strides. The estimate's
    height gains `climb` per metre more than the truth (the legs' bias) less the calibration's correction as the
    estimator applies it, and its trunk is pitched `tilt` [rad] nose-up wrong: the path sinks `tilt` per metre
    and a foothold x_b ahead of the base is −tilt·x_b off. Footholds get 2 mm noise."""
    dt, v, half_period = 0.01, 0.2, 0.25
    n_ticks = int(metres / v / dt)
    normal = np.array([-slope, 0.0, 1.0]) / math.hypot(slope, 1.0)
    R = np.eye(3)
    foot_x = {leg: HIP_X[leg] for leg in range(4)}  # world x of each foot's current foothold
    err = 0.0  # the estimate's height error [m]
    for k in range(n_ticks):
        err += (climb - cal.bias - tilt) * v * dt  # the tilt error tilts the path too
        t = k * dt
        xb = v * t
        phase = int(t / half_period) % 2
        in_stance = np.array([phase == 0, phase == 1, phase == 1, phase == 0])
        mid = (t % half_period) / half_period
        use = in_stance & (0.3 <= mid <= 0.8)
        p = np.array([xb, 0.0, slope * xb + 0.35 + err])  # the estimate: the true height + its error
        feet_b = np.zeros((4, 3))
        for leg in range(4):
            if in_stance[leg] and mid < 0.02:  # touchdown: the foot lands a half stride ahead of its hip
                foot_x[leg] = xb + HIP_X[leg] + 0.05
            fx = foot_x[leg]
            noise = rng.normal(0.0, 0.002)
            true_z = slope * fx
            # the estimate's foothold: true height + the base's height error + the tilt error's lever
            est_z = true_z + err - tilt * (fx - xb) + noise
            feet_b[leg] = (fx - xb, HIP_Y[leg], est_z - p[2])
        cal.stance_tick(use, feet_b, R, p, normal)


def test_the_climb_bias_is_recovered_from_revisited_footholds_whatever_the_slope_and_tilt():
    for climb, slope, tilt in (
        (0.008, 0.0, 0.0),
        (-0.006, math.tan(math.radians(15)), 0.0),
        (0.005, 0.2, 0.006),
    ):
        cal = ClimbCalibration()
        _walk(cal, climb, slope, tilt, np.random.default_rng(1))
        assert cal.samples >= 20
        # the trunk's tilt error moves the front foothold down and the hind one up by a body length's worth: it
        # cancels against the travel between them (0.48 m here against 0.5 m of travel)
        assert abs(cal.bias - climb) < 0.0015 + 0.04 * abs(tilt), (climb, slope, tilt, cal.bias)
        assert cal.std < 0.003


def test_without_revisits_or_when_disabled_the_bias_stays_at_zero():
    cal = ClimbCalibration(ClimbCalibrationConfig(enabled=False))
    _walk(cal, 0.01, 0.0, 0.0, np.random.default_rng(2))
    assert cal.bias == 0.0 and cal.samples == 0
    # footholds never closer than the offset limit: no pair, no sample
    cal = ClimbCalibration(ClimbCalibrationConfig(max_offset_m=0.001))
    _walk(cal, 0.01, 0.0, 0.0, np.random.default_rng(3))
    assert cal.samples <= 2 and abs(cal.bias) < 0.004


def test_an_outlier_pair_is_refused():
    cal = ClimbCalibration()
    _walk(cal, 0.004, 0.0, 0.0, np.random.default_rng(4), metres=3.0)
    before, refused = cal.bias, cal.refused
    # a hind foot that sank 5 cm (a slip into soft ground) where a front foot stood: 10 % over a body length
    R, n = np.eye(3), np.array([0.0, 0.0, 1.0])
    front = np.array([10.0, 0.13, 0.0])
    cal._hist[0].append((front, np.array([9.76, 0.0, 0.35])))
    cal._pair(2, front + np.array([0.01, 0.0, -0.05]), np.array([10.25, 0.0, 0.35]), R[:, 0], n)
    assert cal.refused == refused + 1 and cal.bias == before


def test_the_odometry_update_turns_the_calibrated_climb_back():
    """A leg whose odometry climbs 1 % of the base's forward speed measures no climb once the bias is removed."""
    from scout_agent.state_estimation.leg_odometry import odometry_rows

    v_true = np.array([0.2, 0.0, 0.0])
    climb = 0.01
    feet = np.array([[0.24, 0.13, -0.35], [0.24, -0.13, -0.35], [-0.24, 0.13, -0.35], [-0.24, -0.13, -0.35]])
    # no rotation: the foot moves back against the base; the legs' bias adds `climb`·v_x to the base's climb
    feet_vel = np.tile(-(v_true + np.array([0.0, 0.0, climb * v_true[0]])), (4, 1))
    use = np.array([True, False, False, True])
    args = (use, np.eye(3), v_true, np.zeros(3), (feet, feet_vel, np.zeros((4, 3))), np.zeros(3))
    raw, _ = odometry_rows(*args, np.array([0.0, 0.0, 1.0]), 0.0)
    fixed, _ = odometry_rows(*args, np.array([0.0, 0.0, 1.0]), 0.0, climb)
    assert np.allclose(raw.reshape(2, 3)[:, 2], climb * v_true[0])  # without the calibration: the bias
    assert np.abs(fixed).max() < 1e-5  # with it: what the base did
