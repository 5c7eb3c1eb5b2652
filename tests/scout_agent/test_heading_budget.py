"""benchmarks/heading_budget.py's report: the terms add up to the error, and each turn and standstill is
booked with what it added (synthetic rows; the hooks themselves run in the benchmark's walks)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.heading_budget import HeadingBudget


def _rows(dt: float = 0.1) -> list[dict]:
    """A 60 s record: the start 0.5° off; a 90° left turn over 10–20 s through a +1 % scale error; an offset
    error of 1e-4 rad/s integrated while walking; a standstill at 30–36 s whose zero-rate update turned the
    heading −0.2° at its end; a pose fix of +0.3° at 45 s."""
    rows, yaw, err = [], 0.0, math.radians(0.5)
    for k in range(600):
        t = k * dt
        rate = math.radians(9.0) if 10.0 <= t < 20.0 else 0.0
        stand = 30.0 <= t < 36.0
        yaw += rate * dt
        bias = 0.0 if stand else 1e-4 * dt
        scale = 0.01 * rate * dt
        zaru = math.radians(-0.2) if abs(t - 35.9) < 1e-6 else 0.0
        other = math.radians(0.3) if abs(t - 45.0) < 1e-6 else 0.0
        err += bias + scale + zaru + other
        rows.append(
            {
                "t": t,
                "yaw_true": (yaw + math.pi) % (2 * math.pi) - math.pi,
                "err": err,
                "sigma": 0.02,
                "prop": bias + scale,
                "bias": bias,
                "scale": scale,
                "zaru": zaru,
                "grav": 0.0,
                "odo": 0.0,
                "other": other,
                "stand": stand,
                "bz_true": 1e-4,
                "bz_est": 0.0,
                "walked": 0.2 * t,
            }  # fmt: skip
        )
    return rows


def test_the_budget_closes_and_books_turns_standstills_and_fixes() -> None:
    b = HeadingBudget()
    b.rows = _rows()
    rep = b.report()
    end = rep["at_end"]
    terms = ("bias", "scale", "resid", "zaru", "grav", "odo", "other")
    assert end["start_deg"] + sum(end[f"{k}_deg"] for k in terms) == pytest.approx(end["error_deg"], abs=0.02)
    assert end["resid_deg"] == pytest.approx(0.0, abs=1e-9)
    (turn,) = rep["turns"]
    assert turn["net_turn_deg"] == pytest.approx(90.0, abs=1.0)
    assert turn["scale_added_deg"] == pytest.approx(0.9, abs=0.02)  # 1 % of 90°
    (pause,) = rep["standstills_bz_error_1e-4_rad_s"]
    assert pause["t_s"] == pytest.approx(30.0, abs=0.11)
    assert pause["zaru_turned_deg"] == pytest.approx(-0.2, abs=1e-6)
    # walking 0–30 s added 30 s × 1e-4 rad/s (0.17°) and the turn's 0.9°
    assert pause["walk_added_deg"] == pytest.approx(math.degrees(30 * 1e-4) + 0.9, abs=0.02)
    (fix,) = rep["pose_fixes"]
    assert fix["turned_deg"] == pytest.approx(0.3, abs=1e-6)
    assert np.isfinite(fix["sigma_before_deg"])
