"""Leg odometry's climb bias, calibrated against the robot's own footholds: a hind foot steps where a front foot stood.

The legs' kinematics carry the residuals of the robot's calibration (joint zero offsets, link lengths; realistic
sensors: 0.3° and 1 mm, sensors/joints.py and sensors/suite.py). Each leg's odometry then turns the base's
velocity a little about the base's y axis, and the fused velocity climbs or sinks by their mean: −0.5…+0.8 % of
the distance on the ramps' noise seeds (docs/results.md, "The ramps' heights with realistic sensors"). Nothing the
IMU or a standstill sees tells that mean apart from a sloping ground: the feet-plane's tilt at rest is a different
combination of the same errors (the thigh offsets move the feet fore and aft, not up), and gravity fixes only the
trunk's tilt.

What does show it is the ground itself, walked twice. In a trot the hind foot lands within a few centimetres of
where the front foot on its side stood about a body length earlier. The ground has not moved, so the two footholds'
estimated heights differ only by (1) the height the odometry gained over the base's travel s between them, c·s,
c the climb bias; (2) the ground's rise over their small horizontal offset, which the local ground plane gives;
(3) the two legs' static height errors, a bias of ±0.1–0.3 % of s here. The trunk's tilt error cancels: it lowers
the front foothold and raises the hind one by as much as it tilts the path between them (a body length ≈ s).
Each such pair is a sample of c; their running estimate (a scalar Kalman filter, gated) is removed from every
stance foot's velocity measurement (leg_odometry.odometry_rows turns it back about the base y axis).

`ClimbCalibration.stance_tick` takes the estimator's feet in use each tick; a foot's foothold is the mean over
the ticks it was in use, compared when that window closes with the other same-side leg's earlier ones (the front
foot's when walking forward, the hind foot's when backing). Everything here is the robot's own estimate.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["ClimbCalibration", "ClimbCalibrationConfig"]

_SAME_SIDE = (2, 3, 0, 1)  # FL↔RL, FR↔RR (constants.LEG_NAMES order)


@dataclass(frozen=True)
class ClimbCalibrationConfig:
    enabled: bool = True
    # prior σ of the bias: the legs' mean climb from 0.3° zero offsets and 1 mm links is ≈ 0.4 % (σ) per metre
    prior_std: float = 0.006
    # one pair's scatter: foothold noise (sinking, the contact point on the ball) over a body length; measured
    # 0.6–1.2 % on the ramps' walks (simulator truth, docs/results.md)
    sample_std: float = 0.012
    max_offset_m: float = 0.04  # the two footholds at most this far apart horizontally [m]
    min_travel_m: float = 0.25  # the base travelled at least this far between them, along its x axis [m]
    max_slope: float = (
        0.6  # ground steeper than this (tan, ≈ 31°): no sample (the plane is not trusted there)
    )
    gate_sigma: float = 3.0  # samples beyond this many σ of the estimate are refused (a kink, a slip)
    history: int = 16  # footholds kept per leg (≈ 3 s of trot: a body length at 0.2 m/s)


class _Window:
    """A foot's current use window: sums of its world foothold and of the base position."""

    __slots__ = ("n", "foot", "base")

    def __init__(self) -> None:
        self.n = 0
        self.foot = np.zeros(3)
        self.base = np.zeros(3)


class ClimbCalibration:
    """The legs' climb bias c [m of height per m of base travel along its x axis] and its variance."""

    def __init__(self, config: ClimbCalibrationConfig = ClimbCalibrationConfig()) -> None:
        self.config = config
        self.bias = 0.0
        self.var = config.prior_std**2
        self.samples = 0  # pairs fused
        self.refused = 0  # pairs gated out
        self._win = [_Window() for _ in range(4)]
        # per leg: (foothold (3,), base position (3,)) of its closed windows, newest last
        self._hist: list[deque[tuple[np.ndarray, np.ndarray]]] = [
            deque(maxlen=config.history) for _ in range(4)
        ]

    def stance_tick(
        self, use: np.ndarray, feet_b: np.ndarray, R: np.ndarray, p: np.ndarray, normal_w: np.ndarray
    ) -> None:
        """One fresh tick: `use` (4,) the feet whose odometry the estimator used, `feet_b` (4, 3) the feet in the
        base frame, `R`, `p` the estimate, `normal_w` (3,) the ground normal under the feet (world)."""
        if not self.config.enabled:
            return
        for leg in range(4):
            w = self._win[leg]
            if use[leg]:
                w.n += 1
                w.foot += R @ feet_b[leg] + p
                w.base += p
            elif w.n:
                foot, base = w.foot / w.n, w.base / w.n
                w.n, w.foot[:], w.base[:] = 0, 0.0, 0.0
                self._pair(leg, foot, base, R[:, 0], normal_w)
                self._hist[leg].append((foot, base))

    def _pair(self, leg: int, foot: np.ndarray, base: np.ndarray, x_body: np.ndarray, n: np.ndarray) -> None:
        """A closed foothold of `leg` against the nearest earlier one of its same-side leg."""
        c = self.config
        other = self._hist[_SAME_SIDE[leg]]
        if not other or n[2] < 1.0 / math.sqrt(1.0 + c.max_slope**2):
            return
        best, best_d = None, c.max_offset_m
        for f0, b0 in other:
            d = math.hypot(foot[0] - f0[0], foot[1] - f0[1])
            if d <= best_d:
                best, best_d = (f0, b0), d
        if best is None:
            return
        f0, b0 = best
        travel = float(np.dot(base - b0, x_body))
        if abs(travel) < c.min_travel_m:
            return
        dx, dy = foot[0] - f0[0], foot[1] - f0[1]
        rise = -(n[0] * dx + n[1] * dy) / n[2]  # the ground's rise from the earlier foothold to this one
        # the height the odometry gained over the travel, with the bias now applied added back (the pair spans a
        # few seconds, over which the estimate moves little)
        sample = (foot[2] - f0[2] - rise) / travel + self.bias
        s2 = self.var + c.sample_std**2
        if (sample - self.bias) ** 2 > c.gate_sigma**2 * s2:
            self.refused += 1
            return
        k = self.var / s2
        self.bias += k * (sample - self.bias)
        self.var *= 1.0 - k
        self.samples += 1

    @property
    def std(self) -> float:
        return math.sqrt(self.var)
