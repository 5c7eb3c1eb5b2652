"""Aliengo's 1-D foot pressure sensors: what each reads for the true normal ground force on its foot.

An Aliengo has one pressure value per foot (Unitree low-level state `footForce`), not a 3-axis force sensor.
The model reports the normal ground force on the foot sphere scaled by a per-foot gain error, plus an offset and
white noise, as an uncalibrated resistive/piezo sensor in a rubber foot would: defaults are a ± 10 % gain spread
(σ `gain_error`), a 0.5 N offset spread and 1.0 N noise per reading (assumed values for such sensors; Unitree
publishes none). Realistic profile: the offset also drifts (a random walk of `offset_walk_n` N/√s: rubber
creep and temperature; assumed 0.03 N/√s, ≈ 0.4 N after 3 min) and the reading saturates at `saturation_n`
(Aliengo `footForce` is a raw int16 of an uncalibrated sensor; 120 N assumed as the sensor's linear range: a
trotting Aliengo's foot carries 8–16 N at lunar g, impacts a few times that).

Turning these readings into contact flags (a threshold with hysteresis, or contact from joint torques) is the
robot's software: `scout_agent.onboard.drivers.ContactDetector`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass(frozen=True)
class ContactConfig:
    """The foot pressure sensors' errors (the contact thresholds are `onboard.drivers.ContactDetection`)."""

    gain_error: float = 0.10  # σ of each foot sensor's gain error (fraction)
    offset_n: float = 0.5  # σ of each foot sensor's offset [N]
    noise_n: float = 1.0  # σ of the reading's noise [N]
    offset_walk_n: float = 0.0  # offset drift [N/√s] (realistic: 0.03)
    saturation_n: float = math.inf  # readings clip here [N] (realistic: 120)


class FootContactSensors:
    """`reading(normal_force_n)` → the 4 pressure readings [N]."""

    def __init__(self, config: ContactConfig, rng: np.random.Generator) -> None:
        self.config = c = config
        self.rng = rng
        self.gain = 1.0 + rng.normal(0.0, c.gain_error, 4)
        self.offset = rng.normal(0.0, c.offset_n, 4)

    def reading(self, normal_force_n: np.ndarray, dt: float = 0.0) -> np.ndarray:
        """Readings [N] for the true normal forces; `dt` [s] since the last reading drives the offset drift."""
        return _readings(*self.reading_args(normal_force_n, dt))

    def reading_args(self, normal_force_n: np.ndarray, dt: float = 0.0) -> tuple:
        """`reading`'s draws and state as `_readings`' arguments (the suite's one compiled call a tick)."""
        c = self.config
        walk = c.offset_walk_n * math.sqrt(dt) if c.offset_walk_n and dt > 0 else 0.0
        # one draw for both: the offset walk's four normals, then the noise's (the order of two draws)
        z = self.rng.standard_normal(8 if walk else 4)
        return (
            np.asarray(normal_force_n, dtype=float),
            self.gain,
            self.offset,
            z,
            walk,
            c.noise_n,
            c.saturation_n,
        )


@njit(cache=True, nogil=True)
def _readings(
    normal_force_n: np.ndarray,
    gain: np.ndarray,
    offset: np.ndarray,
    z: np.ndarray,
    walk_n: float,
    noise_n: float,
    saturation_n: float,
) -> np.ndarray:
    """gain · max(f, 0) + offset + noise, saturated (compiled: every control tick). `z`: standard normals, the
    offset's walk (σ `walk_n`, in place; only when `walk_n` > 0) first, then the noise's (σ `noise_n`)."""
    o = 0
    if walk_n > 0.0:
        for i in range(4):
            offset[i] = offset[i] + walk_n * z[i]
        o = 4
    r = np.empty(4)
    for i in range(4):
        r[i] = min(gain[i] * max(normal_force_n[i], 0.0) + offset[i] + noise_n * z[o + i], saturation_n)
    return r
