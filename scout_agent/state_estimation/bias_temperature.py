"""`GyroTempco`: the gyro's zero-rate offset against the IMU thermometer, learnt from the standstills.

A MEMS gyro's offset moves linearly with its temperature, b(T) = b₀ + k·(T − T₀) per axis, by a coefficient k the
datasheet gives only as a spread (BMI088: 0.015 °/s/K, 1σ). Without knowing k the estimator must let its bias
variance grow by that spread times the temperature change since the last zero-rate update (TCO²·ΔT², estimator.py),
which on a warming board (0.3–0.5 K between two pauses of a walk) throws most of what the earlier standstills
measured away: every pause starts nearly afresh, and its 6 s of gyro white noise (≈ 1e-4 rad/s) is the heading
drift of the next minute's walk.

Every zero-rate update is a measurement of the offset at a known temperature, so the standstills themselves
measure k: a Bayesian straight-line fit per axis of the windows' offsets against the thermometer, the slope with
the datasheet's prior N(0, TCO²), the intercept free. The estimator then moves its bias nominal by k̂·dT as the
board warms and widens its variance by σ_k̂²·d(ΔT²) instead of TCO²·d(ΔT²). Each window's variance in the fit is its
zero-rate variance plus what the g-sensitivity may have moved the offset since the first window (the windows stand
on different slopes), so the fit does not mistake a slope's effect for the temperature's.

The fit reads the same windows the filter fuses for the offset's level; it estimates only the slope, which the
filter does not (a two-stage estimate, its cross-correlation with the level neglected; the slope's σ comes from
the windows' noise alone, so it errs to the wide side while few windows span little temperature).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["GyroTempco"]

_FREE_STD = 1.0  # prior σ of the offset's intercept [rad/s]: free


class GyroTempco:
    """Per axis, the posterior of (b₀, k) in z = b₀ + k·ΔT from the zero-rate windows; ΔT from the first one's
    temperature."""

    def __init__(self, tempco_std: float) -> None:
        self.tempco_std = float(tempco_std)
        # information matrix and vector per axis, prior: intercept free, slope N(0, tempco_std²)
        self._info = np.zeros((3, 2, 2))
        self._info[:, 0, 0] = 1.0 / _FREE_STD**2
        self._info[:, 1, 1] = 1.0 / self.tempco_std**2 if self.tempco_std > 0 else math.inf
        self._vec = np.zeros((3, 2))
        self.temp0_c = math.nan
        self.windows = 0

    def add(self, temp_c: float, z: np.ndarray, var: np.ndarray) -> None:
        """One zero-rate window: its offset `z` (3,) [rad/s] with variance `var` (3,) [(rad/s)²] at `temp_c` [°C]."""
        if not (temp_c == temp_c and self.tempco_std > 0):
            return
        if self.temp0_c != self.temp0_c:
            self.temp0_c = temp_c
        h = np.array([1.0, temp_c - self.temp0_c])
        for i in range(3):
            self._info[i] += np.outer(h, h) / var[i]
            self._vec[i] += h * (z[i] / var[i])
        self.windows += 1

    def slope(self) -> tuple[np.ndarray, np.ndarray]:
        """k̂ (3,) [rad/s/K] and its σ (3,) (the prior's 0 and TCO before any window spans a temperature)."""
        k = np.zeros(3)
        sd = np.full(3, self.tempco_std)
        if self.tempco_std <= 0:
            return k, np.zeros(3)
        for i in range(3):
            cov = np.linalg.inv(self._info[i])
            k[i] = (cov @ self._vec[i])[1]
            sd[i] = math.sqrt(cov[1, 1])
        return k, sd
