"""Foot contact: Aliengo's 1-D foot pressure sensors, thresholded with hysteresis — or, as an option, contact
estimated from joint torques (no foot sensor at all).

An Aliengo has one pressure value per foot (Unitree low-level state `footForce`), not a 3-axis force sensor.
The model reports the normal ground force on the foot sphere scaled by a per-foot gain error, plus an offset and
white noise, as an uncalibrated resistive/piezo sensor in a rubber foot would: defaults are a ± 10 % gain spread
(σ `gain_error`), a 0.5 N offset spread and 1.0 N noise per reading (assumed values for such sensors; Unitree
publishes none). Realistic profile: the offset also drifts (a random walk of `offset_walk_n` N/√s: rubber
creep and temperature; assumed 0.03 N/√s, ≈ 0.4 N after 3 min) and the reading saturates at `saturation_n`
(Aliengo `footForce` is a raw int16 of an uncalibrated sensor; 120 N assumed as the sensor's linear range: a
trotting Aliengo's foot carries 8–16 N at lunar g, impacts a few times that). Contact turns on above `on_n` and off below `off_n` (hysteresis keeps noise from flickering).

Contact from joint torques (`source="torques"`): the ground force on each stance foot is estimated as
f = −J⁻ᵀ (τ − τ_g) (`leg_forces_from_torques`), and its component along the base's −z axis is thresholded with
the same hysteresis. It ignores the leg's own inertia (small legs, slow trot), so swing accelerations can leave
a few newtons of phantom force.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from scout_agent.errors import ScoutConfigError

CONTACT_SOURCES = ("pressure", "torques")


@dataclass(frozen=True)
class ContactConfig:
    source: str = "pressure"  # one of CONTACT_SOURCES
    gain_error: float = 0.10  # σ of each foot sensor's gain error (fraction)
    offset_n: float = 0.5  # σ of each foot sensor's offset [N]
    noise_n: float = 1.0  # σ of the reading's noise [N]
    on_n: float = 5.0  # contact turns on above this reading [N]
    off_n: float = 2.5  # ... and off below this one [N]
    offset_walk_n: float = 0.0  # offset drift [N/√s] (realistic: 0.03)
    saturation_n: float = math.inf  # readings clip here [N] (realistic: 120)

    def __post_init__(self) -> None:
        if self.source not in CONTACT_SOURCES:
            raise ScoutConfigError(
                f"contact source {self.source!r} unknown; sources: {', '.join(CONTACT_SOURCES)}"
            )
        if not self.off_n < self.on_n:
            raise ScoutConfigError(f"contact thresholds need off_n < on_n (got {self.off_n}, {self.on_n})")


@njit(cache=True, nogil=True)
def leg_forces_from_torques(jacobians: np.ndarray, tau: np.ndarray, tau_gravity: np.ndarray) -> np.ndarray:
    """Ground forces on the feet (4, 3), base frame [N], from leg Jacobians (4, 3, 3) (d foot / d leg joints,
    base frame), joint torques (12,) and the joints' gravity torques (12,): f = −J⁻ᵀ (τ − τ_g).
    Near-singular legs (a straight knee) give zeros rather than huge forces. Compiled (the estimators call it
    every tick); the same LAPACK solve per leg as numpy's, so the same figures."""
    out = np.zeros((4, 3))
    for i in range(4):
        Jt = np.ascontiguousarray(jacobians[i].T)
        if not abs(np.linalg.det(Jt)) > 1e-5:
            continue
        x = np.linalg.solve(Jt, tau[3 * i : 3 * i + 3] - tau_gravity[3 * i : 3 * i + 3])
        for j in range(3):
            out[i, j] = -x[j]
    return out


class FootContactSensors:
    """`reading(normal_force_n)` → the 4 pressure readings [N]; `flags(readings)` → contact with hysteresis."""

    def __init__(self, config: ContactConfig, rng: np.random.Generator) -> None:
        self.config = c = config
        self.rng = rng
        self.gain = 1.0 + rng.normal(0.0, c.gain_error, 4)
        self.offset = rng.normal(0.0, c.offset_n, 4)
        self.contact = np.zeros(4, bool)

    def reading(self, normal_force_n: np.ndarray, dt: float = 0.0) -> np.ndarray:
        """Readings [N] for the true normal forces; `dt` [s] since the last reading drives the offset drift."""
        c = self.config
        if c.offset_walk_n and dt > 0:
            self.offset = self.offset + self.rng.normal(0.0, c.offset_walk_n * math.sqrt(dt), 4)
        noise = self.rng.normal(0.0, c.noise_n, 4)
        return _readings(
            np.asarray(normal_force_n, dtype=float), self.gain, self.offset, noise, c.saturation_n
        )

    def flags(self, force_n: np.ndarray) -> np.ndarray:
        c = self.config
        _hysteresis(np.asarray(force_n, dtype=float), c.off_n, c.on_n, self.contact)
        return self.contact.copy()


@njit(cache=True, nogil=True)
def _readings(
    normal_force_n: np.ndarray, gain: np.ndarray, offset: np.ndarray, noise: np.ndarray, saturation_n: float
) -> np.ndarray:
    """gain · max(f, 0) + offset + noise, saturated (compiled: every control tick)."""
    r = np.empty(4)
    for i in range(4):
        r[i] = min(gain[i] * max(normal_force_n[i], 0.0) + offset[i] + noise[i], saturation_n)
    return r


@njit(cache=True, nogil=True)
def _hysteresis(force_n: np.ndarray, off_n: float, on_n: float, contact: np.ndarray) -> None:
    """Contact flags in place: stay on above `off_n`, turn on above `on_n`."""
    for i in range(contact.shape[0]):
        contact[i] = force_n[i] > off_n if contact[i] else force_n[i] > on_n
