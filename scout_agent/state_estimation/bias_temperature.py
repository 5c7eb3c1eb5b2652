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

The stance's creep (standstill.py: the four planted feet turning in the world, which a window reads as offset) is
one draw per standstill, steady over its windows, and so is the g-sensitivity's share (one attitude per
standstill): each standstill gets its own random intercept, N(0, σ_c²) with σ_c² the creep's and the
g-sensitivity's variance, marginalised out in closed form (Sherman–Morrison over the standstill's windows). The
temperature change *within* a standstill then measures k free of both, while the windows' white noise alone
limits it; across standstills they count as what they are, one draw each. The power-on standstill, long and on
a warming board, measures k this way before the walk starts (standstill.py, `start_drift_max`). Before, each
window counted the creep as its own independent error: the slope within a standstill was learnt as slowly as
across them, and a standstill's windows were counted as independent draws of its creep.

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
    """Per axis, the posterior of (b₀, k) in z = b₀ + c_j + k·ΔT from the zero-rate windows, c_j one draw per
    standstill j (module docstring); ΔT from the first window's temperature."""

    def __init__(self, tempco_std: float) -> None:
        self.tempco_std = float(tempco_std)
        # information matrix and vector per axis of the closed standstills, prior: intercept free, slope
        # N(0, tempco_std²)
        self._info = np.zeros((3, 2, 2))
        self._info[:, 0, 0] = 1.0 / _FREE_STD**2
        self._info[:, 1, 1] = 1.0 / self.tempco_std**2 if self.tempco_std > 0 else math.inf
        self._vec = np.zeros((3, 2))
        # the open standstill's weighted sums per axis: Σw hhᵀ, Σw h, Σw, Σw h z, Σw z (w = 1/var)
        self._group: object = None
        self._gvar = np.zeros(3)
        self._A = np.zeros((3, 2, 2))
        self._a = np.zeros((3, 2))
        self._s = np.zeros(3)
        self._y = np.zeros((3, 2))
        self._yz = np.zeros(3)
        self.temp0_c = math.nan
        self.windows = 0

    def _group_info(self) -> tuple[np.ndarray, np.ndarray]:
        """The open standstill's information (3, 2, 2) and vector (3, 2), its intercept draw marginalised:
        Σ⁻¹ = W − W11ᵀW / (1/σ_c² + 1ᵀW1) (Sherman–Morrison)."""
        info, vec = self._A.copy(), self._y.copy()
        for i in range(3):
            if self._s[i] <= 0.0 or self._gvar[i] <= 0.0:
                continue
            d = 1.0 / self._gvar[i] + self._s[i]
            info[i] -= np.outer(self._a[i], self._a[i]) / d
            vec[i] -= self._a[i] * (self._yz[i] / d)
        return info, vec

    def add(
        self,
        temp_c: float,
        z: np.ndarray,
        var: np.ndarray,
        group: object = None,
        group_var: np.ndarray | float = 0.0,
    ) -> None:
        """One zero-rate window: its offset `z` (3,) [rad/s] with variance `var` (3,) [(rad/s)²] at `temp_c`
        [°C], of standstill `group` whose windows share one draw of variance `group_var` [(rad/s)²] (the creep,
        the g-sensitivity at its attitude); `var` is the window's own (white noise, kinematics). A window of
        another group closes the open one."""
        if not (temp_c == temp_c and self.tempco_std > 0):
            return
        if self.temp0_c != self.temp0_c:
            self.temp0_c = temp_c
        if group is None or group != self._group:
            info, vec = self._group_info()
            self._info += info
            self._vec += vec
            self._A[:] = 0.0
            self._a[:] = 0.0
            self._s[:] = 0.0
            self._y[:] = 0.0
            self._yz[:] = 0.0
            self._group = group
        self._gvar = np.broadcast_to(np.asarray(group_var, dtype=float), (3,)).copy()
        h = np.array([1.0, temp_c - self.temp0_c])
        for i in range(3):
            w = 1.0 / var[i]
            self._A[i] += w * np.outer(h, h)
            self._a[i] += w * h
            self._s[i] += w
            self._y[i] += w * z[i] * h
            self._yz[i] += w * z[i]
        self.windows += 1

    def slope(self) -> tuple[np.ndarray, np.ndarray]:
        """k̂ (3,) [rad/s/K] and its σ (3,) (the prior's 0 and TCO before any window spans a temperature)."""
        k = np.zeros(3)
        sd = np.full(3, self.tempco_std)
        if self.tempco_std <= 0:
            return k, np.zeros(3)
        ginfo, gvec = self._group_info()
        for i in range(3):
            cov = np.linalg.inv(self._info[i] + ginfo[i])
            k[i] = (cov @ (self._vec[i] + gvec[i]))[1]
            sd[i] = math.sqrt(cov[1, 1])
        return k, sd
