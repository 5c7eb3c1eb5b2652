"""The legs' along-track excess and crab, calibrated, and the covariance terms for what the calibration leaves:
the odometry update takes the calibration off the legs' velocity, the filter's horizontal variance grows along
the velocity by the excess's σ and across it by the crab's, and the replay's `split` finds a known excess and
crab in a synthetic walk."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scout_agent.robot import constants as C
from scout_agent.state_estimation import StateEstimator
from scout_agent.state_estimation.estimator import EstimatorConfig
from scout_agent.state_estimation.launch import LaunchPose
from scout_agent.state_estimation.leg_odometry import odometry_rows

FEET = np.array([[0.24, 0.13, -0.35], [0.24, -0.13, -0.35], [-0.24, 0.13, -0.35], [-0.24, -0.13, -0.35]])


def _rows(v_legs: np.ndarray, excess: float, crab: float) -> np.ndarray:
    """The odometry's measured base velocity (base frame, level, no rotation) of two feet reporting `v_legs`."""
    use = np.array([True, False, False, True])
    args = (
        use,
        np.eye(3),
        np.zeros(3),
        np.zeros(3),
        (FEET, np.tile(-v_legs, (4, 1)), np.zeros((4, 3))),
        np.zeros(3),
    )
    z, _ = odometry_rows(*args, np.array([0.0, 0.0, 1.0]), 0.0, 0.0, excess, crab)
    return z.reshape(2, 3)  # the predicted measurement is 0 (v = 0): the residual is the measurement


def test_the_odometry_takes_the_calibrated_excess_and_crab_off_the_legs_velocity() -> None:
    """Legs that run 0.4 % long and 0.3° to the right of the base's true motion measure the true velocity once
    the calibration is applied; without it (0, 0) they measure what they report; the height is left alone."""
    excess, crab = 0.004, math.radians(0.3)
    v_true = np.array([0.2, 0.01, 0.03])
    c, s = math.cos(-crab), math.sin(-crab)
    legs_h = np.array([[c, -s], [s, c]]) @ v_true[:2] / (1.0 - excess)  # what the legs report
    legs = np.r_[legs_h, v_true[2]]
    assert np.allclose(_rows(legs, 0.0, 0.0), legs)
    fixed = _rows(legs, excess, crab)
    assert np.allclose(fixed, v_true, atol=1e-9)
    assert not np.allclose(legs[:2], v_true[:2], atol=1e-4)  # the calibration was not a no-op


def _walk_covariance(config: EstimatorConfig, metres: float, heading_rad: float) -> np.ndarray:
    """The (x, y) covariance an estimator adds by its process and consistency terms over `metres` walked at
    0.2 m/s along `heading_rad` (no contacts: no measurements; the base's velocity is set each tick)."""
    from scout_agent.onboard.drivers import SensorTick

    est = StateEstimator(LaunchPose(0.0, 0.0, heading_rad, 0.0), C.HOME_Q, config)
    P0 = est.ekf.P[6:8, 6:8].copy()
    dt, v = 0.01, 0.2
    u = np.array([math.cos(heading_rad), math.sin(heading_rad), 0.0])
    f = np.array([0.0, 0.0, C.LUNAR_G])
    for k in range(round(metres / v / dt)):
        est.ekf.v[:] = v * u
        tick = SensorTick(
            f, np.zeros(3), C.HOME_Q, np.zeros(12), np.zeros(12), 0.0, np.zeros(4), np.zeros(4, bool)
        )
        est.update((k + 1) * dt, tick, dt)
    return est.ekf.P[6:8, 6:8] - P0


@pytest.mark.parametrize("heading_deg", [0.0, 37.0])
def test_the_odometry_terms_grow_along_and_across_the_walk_by_their_sigmas(heading_deg: float) -> None:
    """σ = k·d along the velocity (the excess's spread) and across it (the crab's), each on its own axis: the
    variance each adds is the difference of two walks with and without it, so the IMU's own growth cancels."""
    h = math.radians(heading_deg)
    u, n = np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)])
    d = 20.0
    base = EstimatorConfig(odometry_scale_std=0.0, odometry_crab_std=0.0)
    P_none = _walk_covariance(base, d, h)
    P_along = (
        _walk_covariance(EstimatorConfig(odometry_scale_std=0.005, odometry_crab_std=0.0), d, h) - P_none
    )
    P_across = (
        _walk_covariance(EstimatorConfig(odometry_scale_std=0.0, odometry_crab_std=0.003), d, h) - P_none
    )
    assert u @ P_along @ u == pytest.approx((0.005 * d) ** 2, rel=0.03)
    assert abs(n @ P_along @ n) < 1e-9
    assert n @ P_across @ n == pytest.approx((0.003 * d) ** 2, rel=0.03)
    assert abs(u @ P_across @ u) < 1e-9


def test_split_finds_a_known_excess_and_crab_and_the_heading_share(tmp_path) -> None:
    """A synthetic recorded walk: the truth walks a curved route; the estimate's steps run 0.4 % long and are
    turned 0.3° right of the truth's, and its heading drifts to 2°, which turns its steps too. `split` finds the
    excess and the crab within a tenth of them, and a perfect-heading error that is the legs' part alone."""
    import benchmarks.dem_place_replay as replay

    n = 700
    s = np.linspace(0.0, 140.0, n)
    psi = 0.78 + 0.3 * np.sin(s / 40.0)  # the route's direction
    steps_true = np.column_stack([np.cos(psi), np.sin(psi)]) * np.gradient(s)[:, None]
    true_xy = np.cumsum(steps_true, 0)
    yaw_err = np.radians(2.0) * s / s[-1]  # the estimate's heading minus the truth's
    excess, crab = 0.004, math.radians(-0.3)
    a = yaw_err + crab
    est_steps = (1 + excess) * np.column_stack([np.cos(a) * steps_true[:, 0] - np.sin(a) * steps_true[:, 1],
                                                np.sin(a) * steps_true[:, 0] + np.cos(a) * steps_true[:, 1]])  # fmt: skip
    est_xy = true_xy[0] + np.vstack([np.zeros((1, 2)), np.cumsum(est_steps[:-1], 0)])
    true_yaw = psi
    P = np.tile(np.diag([1.0, 1.0, 0.01]).ravel(), (n, 1))
    poses = np.column_stack([s, s, est_xy, true_yaw + yaw_err, true_xy, true_yaw, P])
    path = tmp_path / "walk.npz"
    np.savez(path, feet=np.zeros((0, 8)), poses=poses, seed=0, field_m=100.0)
    out = replay.split(str(path))
    assert out["odometry_excess_pct"] == pytest.approx(100 * excess, abs=0.04)
    assert out["odometry_crab_deg"] == pytest.approx(-math.degrees(crab), abs=0.03)
    # the legs' part alone: 0.4 % and 0.3° of the 140 m route's ends (the heading's 2° is not in it)
    legs_m = math.hypot(excess * 140.0, crab * 140.0)
    assert out["perfect_heading_error_max_m"] == pytest.approx(legs_m, rel=0.1)
    assert out["pos_error_max_m"] > 1.5 * legs_m


def test_the_replays_along_track_term_is_k_squared_d_squared_along_the_walk() -> None:
    """`replay --along-k` rebuilds the filter's along-track term from the recorded poses: on a straight walk at
    37° its variance is d² along the walk (k = 1) and nothing across, so a recorded covariance can be re-weighed."""
    import benchmarks.dem_place_replay as replay

    h = math.radians(37.0)
    u, n = np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)])
    w = np.linspace(0.0, 50.0, 251)
    Q = replay._along_term(w[:, None] * u, w)
    assert u @ Q[-1, :2, :2] @ u == pytest.approx(50.0**2, rel=0.01)
    assert abs(n @ Q[-1, :2, :2] @ n) < 1e-9 and np.all(Q[:, 2, :] == 0.0)
