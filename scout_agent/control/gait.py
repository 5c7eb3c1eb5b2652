"""Periodic gait schedules: each leg's phase runs at `freq_hz` from its offset; stance while phase < duty.

- the trot (`GaitConfig()`): diagonal pairs (FL+RR, FR+RL) half a cycle apart, two feet down at a time;
- the crawl (`CRAWL`): a statically stable walk, one leg at a time in the order RL, FL, RR, FR (each offset a
  quarter cycle below the previous one), with all four feet down between swings (duty > 0.75), so three feet
  always bear the trunk. Every offset lies below the duty: started at phase 0 (`TrotController.set_gait`), all
  four legs begin in stance and the first leg lifts only after (duty − 0.75) / freq_hz.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass(frozen=True)
class GaitConfig:
    freq_hz: float = 1.4  # gait cycles per second
    duty: float = 0.6  # stance share of a cycle
    offsets: tuple[float, float, float, float] = (0.0, 0.5, 0.5, 0.0)  # FL, FR, RL, RR


CRAWL = GaitConfig(freq_hz=0.5, duty=0.85, offsets=(0.5, 0.0, 0.75, 0.25))  # swing 0.3 s, stance 1.7 s


class TrotGait:
    """A periodic gait (the trot by default, or any `GaitConfig` such as `CRAWL`)."""

    def __init__(self, config: GaitConfig = GaitConfig()) -> None:
        self.config = config
        self.offsets = np.asarray(config.offsets)
        self.stance_s = config.duty / config.freq_hz  # stance duration [s]
        self.swing_s = (1.0 - config.duty) / config.freq_hz  # swing duration [s]

    def phase(self, t: float) -> np.ndarray:
        """(4,) phase in [0, 1); stance is [0, duty), swing [duty, 1)."""
        return (t * self.config.freq_hz + self.offsets) % 1.0

    def stance(self, phase: np.ndarray) -> np.ndarray:
        return phase < self.config.duty

    def swing_progress(self, phase: np.ndarray) -> np.ndarray:
        """(4,) progress through swing in [0, 1] (0 for stance legs)."""
        d = self.config.duty
        return _unit_clip(np.asarray(phase, dtype=float), d, 1.0 - d)

    def stance_progress(self, phase: np.ndarray) -> np.ndarray:
        """(4,) progress through stance in [0, 1] (1 for swing legs)."""
        return _unit_clip(np.asarray(phase, dtype=float), 0.0, self.config.duty)

    def mid_stance(self, phase: np.ndarray, stance: np.ndarray, lo: float, hi: float) -> np.ndarray:
        """(4,) legs in `stance` whose `stance_progress` lies in [lo, hi] (compiled: the estimator asks every
        tick which legs' odometry to use)."""
        return _mid_stance(np.asarray(phase, dtype=float), stance, self.config.duty, lo, hi)


@njit(cache=True, nogil=True)
def _unit_clip(phase: np.ndarray, start: float, length: float) -> np.ndarray:
    """(phase − start) / length clipped to [0, 1], each element (np.clip's figures without its per-call cost:
    the run loop asks every tick)."""
    out = np.empty(phase.shape[0])
    for i in range(phase.shape[0]):
        out[i] = min(max((phase[i] - start) / length, 0.0), 1.0)
    return out


@njit(cache=True, nogil=True)
def schedule(
    t: float,
    freq_hz: float,
    duty: float,
    offsets: np.ndarray,
    phase: np.ndarray,
    stance: np.ndarray,
    swing: np.ndarray,
) -> None:
    """`TrotGait.phase`, `stance` and `swing_progress` at time `t` [s] in one compiled pass (the controller's
    tick), into `phase`, `stance` and `swing` (4,)."""
    tf = t * freq_hz
    for i in range(4):
        phase[i] = (tf + offsets[i]) % 1.0
        stance[i] = phase[i] < duty
        swing[i] = min(max((phase[i] - duty) / (1.0 - duty), 0.0), 1.0)


@njit(cache=True, nogil=True)
def _mid_stance(phase: np.ndarray, stance: np.ndarray, duty: float, lo: float, hi: float) -> np.ndarray:
    """`stance & (lo <= stance_progress(phase) <= hi)`, each leg."""
    out = np.empty(phase.shape[0], np.bool_)
    for i in range(phase.shape[0]):
        p = min(max(phase[i] / duty, 0.0), 1.0)
        out[i] = stance[i] and p >= lo and p <= hi
    return out
