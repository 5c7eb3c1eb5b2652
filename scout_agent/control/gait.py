"""Periodic gait schedules: each leg's phase runs at `freq_hz` from its offset; stance while phase < duty.

- the trot (`GaitConfig()`): diagonal pairs (FL+RR, FR+RL) half a cycle apart, two feet down at a time;
- the crawl (`CRAWL`): a statically stable walk, one leg at a time in the order RL, FL, RR, FR (each offset a
  quarter cycle below the previous one), with all four feet down between swings (duty > 0.75), so three feet
  always bear the trunk. Every offset lies below the duty: started at phase 0 (`TrotController.set_gait`), all
  four legs begin in stance and the first leg lifts only after (duty − 0.75) / freq_hz;
- the sway crawl (`SWAY_CRAWL`): the crawl slowed to a 4 s cycle, the two left legs (RL, FL) swinging one after
  the other, then the two right ones (RR, FR), with a quarter cycle on four feet between the sides, while the trunk
  sways `sway_m` away from the side that lifts (`TrotGait.sway`). A crawl that does not sway keeps its centre of
  mass on the diagonal between the two feet beside the lifted one — on the edge of its support triangle, as
  balanced as a trot — and the trot's balance about that diagonal asks the feet for tangential force (ratios up
  to 0.5) that slippery ground does not give (docs/results.md, issue 24). Swaying 3 cm puts it 2.6 cm inside the
  triangle (the Aliengo's feet stand 0.48 × 0.27 m). At lunar g the ground holds a sideways acceleration of only
  g·(μ − tan θ) (≈ 0.1–0.3 m/s² on a slippery patch): the sway turns over a whole second on four feet.
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
    sway_m: float = 0.0  # the trunk's sideways sway away from the legs that swing [m] (0: none)


CRAWL = GaitConfig(freq_hz=0.5, duty=0.85, offsets=(0.5, 0.0, 0.75, 0.25))  # swing 0.3 s, stance 1.7 s
# swings (cycle share): RL 0.125–0.225, FL 0.275–0.375, RR 0.625–0.725, FR 0.775–0.875 (swing 0.4 s, stance
# 3.6 s); the sway is 0 at phase 0, so switched in (`TrotController.set_gait`) the trunk starts centred
SWAY_CRAWL = GaitConfig(freq_hz=0.25, duty=0.9, offsets=(0.625, 0.125, 0.775, 0.275), sway_m=0.03)
_LEFT = np.array([1.0, -1.0, 1.0, -1.0])  # FL, FR, RL, RR: +1 on the base's left (+y)


class TrotGait:
    """A periodic gait (the trot by default, or any `GaitConfig` such as `CRAWL`)."""

    def __init__(self, config: GaitConfig = GaitConfig()) -> None:
        self.config = config
        self.offsets = np.asarray(config.offsets)
        self.stance_s = config.duty / config.freq_hz  # stance duration [s]
        self.swing_s = (1.0 - config.duty) / config.freq_hz  # swing duration [s]

    def sway(self, t: float) -> float:
        """The trunk's sideways offset [m] along the base's +y at gait time `t` [s]: `sway_m` away from the side
        whose legs swing around then — each leg pushes the trunk away from itself with a cos² bump a half cycle
        wide centred on its swing, the sum clipped to ±1 — so it is full during each swing and turns smoothly
        in the four-foot quarter between the sides."""
        c = self.config
        if c.sway_m <= 0.0:
            return 0.0
        centre = (c.duty + 0.5 * (1.0 - c.duty) - self.offsets) % 1.0  # each leg's mid-swing, cycle share
        d = (t * c.freq_hz - centre + 0.5) % 1.0 - 0.5  # from it, in (−0.5, 0.5]
        bump = np.where(np.abs(d) < 0.25, np.cos(2.0 * np.pi * d) ** 2, 0.0)
        return -c.sway_m * float(np.clip(np.sum(_LEFT * bump), -1.0, 1.0))

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
