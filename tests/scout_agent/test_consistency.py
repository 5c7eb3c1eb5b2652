"""The consistency figures: NEES and 3σ containment of the position and the heading, against known errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scout_agent.state_estimation.consistency import ConsistencyTracker


def _quat(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def test_heading_nees_and_containment_follow_the_errors_and_the_variance() -> None:
    tr = ConsistencyTracker()
    sigma = math.radians(1.0)
    errors_deg = [0.5, -1.0, 2.0, -4.0]  # 0.25, 1, 4 and 16 in NEES; the last is outside 3σ
    for k, e in enumerate(errors_deg):
        true_yaw = 3.1 if k % 2 else -3.1  # across ±π: the error wraps
        tr.add(
            np.zeros(3), _quat(true_yaw), np.zeros(3), _quat(true_yaw + math.radians(e)), np.eye(2), sigma**2
        )
    s = tr.summary()
    assert s["nees_yaw_mean"] == pytest.approx((0.25 + 1 + 4 + 16) / 4, rel=1e-3)
    assert s["yaw_inside_3sigma_frac"] == pytest.approx(0.75)
    assert s["yaw_error_max_deg"] == pytest.approx(4.0, abs=1e-6)
    # with no heading variance given (the exact state) the heading figures are absent, not zero
    bare = ConsistencyTracker()
    bare.add(np.zeros(3), _quat(0.0), np.zeros(3), _quat(0.1), None)
    assert bare.summary()["nees_yaw_mean"] is None and bare.summary()["yaw_inside_3sigma_frac"] is None


def test_the_start_error_and_the_growth_after_it_are_apart() -> None:
    """A launch 0.3 m off in x, then a walk that adds 0.4 m in y: the error is 0.5 m, of which the walk added
    0.4 m (its largest growth, 0.4 m, at the end) — the survey's error and the drift reported apart."""
    tr = ConsistencyTracker()
    q = _quat(0.0)
    for k in range(5):
        truth = np.array([float(k), 0.0, 0.0])
        est = truth + np.array([0.3, 0.1 * k, 0.0])
        tr.add(truth, q, est, q, np.eye(2))
    s = tr.summary()
    assert s["pos_error_start_m"] == pytest.approx(0.3)
    assert s["pos_error_final_m"] == pytest.approx(0.5)
    assert s["pos_error_growth_final_m"] == pytest.approx(0.4)
    assert s["pos_error_growth_max_m"] == pytest.approx(0.4)


def test_the_surveys_heading_draw_and_what_the_walk_added_are_apart() -> None:
    """A launch heading 1.5° off, then the walk turns the error to −0.5° (back through zero) and on to +2.0°:
    the largest error is 2.0°, the start's 1.5°, and the most the walk moved it is 2.0° (from +1.5 to −0.5),
    across ±π as well."""
    tr = ConsistencyTracker()
    for e in (1.5, 0.5, -0.5, 1.0, 2.0):
        true_yaw = math.pi - 0.001
        tr.add(np.zeros(3), _quat(true_yaw), np.zeros(3), _quat(true_yaw + math.radians(e)), np.eye(2))
    s = tr.summary()
    assert s["yaw_error_start_deg"] == pytest.approx(1.5, abs=1e-6)
    assert s["yaw_error_max_deg"] == pytest.approx(2.0, abs=1e-6)
    assert s["yaw_error_growth_max_deg"] == pytest.approx(2.0, abs=1e-6)


def test_height_nees_and_containment_follow_the_errors_and_the_variance() -> None:
    """With a 3×3 position covariance the height is judged too: errors 0.1, −0.2, 0.4 m at σ 0.1 m give NEES
    1, 4, 16 (the last outside 3σ); a 2×2 covariance judges no height."""
    tr = ConsistencyTracker()
    q = _quat(0.0)
    for ez in (0.1, -0.2, 0.4):
        tr.add(np.zeros(3), q, np.array([0.0, 0.0, -ez]), q, np.diag([1.0, 1.0, 0.01]))
    s = tr.summary()
    assert s["nees_height_mean"] == pytest.approx(7.0, rel=1e-6)
    assert s["height_inside_3sigma_frac"] == pytest.approx(2 / 3, abs=1e-4)
    assert s["height_error_max_m"] == pytest.approx(0.4)
    flat = ConsistencyTracker()
    flat.add(np.zeros(3), q, np.array([0.0, 0.0, 0.3]), q, np.eye(2))
    assert flat.summary()["nees_height_mean"] is None and flat.summary()[
        "height_error_max_m"
    ] == pytest.approx(0.3)
