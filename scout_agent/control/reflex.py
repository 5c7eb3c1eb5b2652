"""The hazard reflex's senses: when does the scout feel ground it cannot hold?

Four triggers, each from the scout's own estimates (`estimators.TickEstimates`) and sensors only:

- **slip**, any of:
  - a foot lost its hold (its slip grew past creep, `friction_estimate`) *and* the ground's margin
    μ̂ − tan θ̂ (`adaptation.GaitSetting.margin`) is below `lost_hold_margin` — react with the first foot
    that loses its hold, before the others walk onto the ground (that margin is wide because the estimate a
    lost hold gives, the largest force ratio the stance bore, read 0.07–0.11 above the patch's μ on 15–25°
    ramps);
  - at least `slip_events` slip events within `slip_window_s` with the margin below `slip_hold_margin`, or
    (when set, off by default) `slip_events_many` with it below `slip_many_margin`: on the lunar matrix 9 of 15
    falls came after a stop that had waited for 6–16 slips in 3 s; 6 slips below 0.15 cut the lunar falls
    from 15 to 10 of 30 but stopped 8 more holdable ramp walks (goal reached 13 → 5 of 20; docs/results.md);
  - one slip event when the margin is below `slip_sure_margin` (clearly unholdable);
  - `slip_events_alone` events in the window whatever the margin;
  - (`front_slip_margin`, None switches it off) a front foot's slip event, or a lost hold, with the felt
    μ̂ minus the tangent of the front feet's own slope (`foot_slope.FootTracks`, not the four-foot plane)
    below `front_slip_margin`: the front feet feel the patch first, and the foothold plane through all four
    reads the flat the rear feet still stand on. At 0.06 the falls matrices read lunar 8 → 7 of 30, ramps
    8 → 6 of 50, goal reached and slip precision / recall unchanged; at 0.12 lunar 5 of 30 but the ramps' goal
    15 → 7 (front slips on holdable 25° ramps with μ̂ at the prior) (docs/results.md).
  Slippery ground the scout can still hold (the paper's patches) makes slips too; there the adaptive gait
  slows down and walks on.
- **margin**: GIIM below `min_giim_rad` or GIAM below `min_giam` on at least `margin_share` of the ticks
  of the last `margin_window_s` (single ticks dip to zero: the IMU's GIA sees the trunk's own jolts).
- **contact**: the legs met an obstacle they cannot walk over, either of:
  - a non-foot contact flagged by the estimators on `contact_ticks` consecutive ticks;
  - (`face_rise_m`, None switches it off) a foot touched down at least `face_rise_m` above where its swing
    lifted off and steeper than `face_tan` from there: its swing ran into a face (a step or a rock's side) it cannot
    step onto, and the next feet climb the face until the trunk pitches over them. Against truth on a 20 cm
    step across the path (`tests/scout_agent/test_hazard.py`) the front feet touched the face at 7–10 cm with
    0.02–0.04 m of progress (tan 2–3.5) 0.9 s before the trot flipped over them; the steepest such rise on
    lunar seeds 3 and 5 east and a 25° ramp was tan 0.54 (≥ 0.06 m rises only with 0.13–0.16 m of stride).
    Felt at the foothold on the face.
- **attitude**: the estimated trunk tilt from vertical beyond `max_tilt_deg`.

`Senses.feel(...)` returns the triggers that fired this tick (empty when none) and where: the slip
trigger at the mean of the recent slip footholds, the others at the CoM.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from scout_agent.estimators import TickEstimates

__all__ = ["Felt", "ReflexConfig", "Senses"]


@dataclass(frozen=True)
class ReflexConfig:
    slip_events: int = 3
    slip_events_many: int | None = None  # e.g. 6 (see above)
    slip_many_margin: float = 0.15
    slip_events_alone: int = 20  # the paper's holdable 10° patch (μ 0.25) made 8 in 3 s: not a hazard
    slip_window_s: float = 3.0
    slip_hold_margin: float = 0.02  # μ̂ − tan θ̂ below which repeated slips mean "cannot hold" (walking
    # needs more than standing: on a 5° ramp the fixed trot fell on μ = tan 5° exactly)
    lost_hold_margin: float = 0.08  # μ̂ − tan θ̂ below which one lost hold is enough
    slip_sure_margin: float = -0.05  # ... below which one slip is enough (the first foot on the patch)
    front_slip_margin: float | None = 0.06  # μ̂ − tan θ̂_front below which a front foot's slip is enough
    min_giim_rad: float = 0.087  # 5°: the planner's hard limit; GIIM fell below it 0.5–1 s before falls
    min_giam: float = -math.inf  # [m/s²]
    margin_window_s: float = 0.5
    margin_share: float = 0.6
    contact_ticks: int = 5
    face_rise_m: float | None = 0.06  # a touchdown this far above its swing's liftoff point [m] ...
    face_tan: float = 1.5  # ... and this steep from it (56°): the swing met a face, not walkable ground
    max_tilt_deg: float = 40.0


@dataclass(frozen=True)
class Felt:
    """What fired: `reasons` (subset of protocol.layers.HAZARD_REASONS), where (x, y) [m, map frame,
    estimated], at scout time t [s], and the slip events in the window."""

    t: float
    x: float
    y: float
    reasons: tuple[str, ...]
    slips: int


class Senses:
    def __init__(self, config: ReflexConfig = ReflexConfig()) -> None:
        self.config = config
        self._slips: deque[tuple[float, float, float]] = deque()  # t, x, y of recent slip events
        self._margin: deque[tuple[float, bool]] = deque()
        self._margin_low = 0  # ticks in `_margin` whose margin was low
        self._contact_run = 0
        self._footholds = np.full((4, 3), np.nan)  # each foot's last foothold (map frame, estimated) [m]
        self._footholds_key = b""

    def reset(self) -> None:
        """Forget the recent history (after a stop: what follows is a new walk)."""
        self._slips.clear()
        self._margin.clear()
        self._margin_low = 0
        self._contact_run = 0
        self._footholds[:] = np.nan
        self._footholds_key = b""

    def forget_slips(self) -> None:
        """Forget the recent slip events only (slips already accounted for: the pilot walking out of a hazard)."""
        self._slips.clear()

    def _face(self, footholds: np.ndarray, liftoff: np.ndarray) -> tuple[float, float] | None:
        """Where a foot's new foothold rose onto a face from where its swing lifted off (`face_rise_m`,
        `face_tan`), else None. From the liftoff, not the previous foothold: a foot that slid down its stance
        would otherwise 'rise' by the slide."""
        c = self.config
        prev = self._footholds
        key = footholds.tobytes()  # (a bytes compare: 0.06 µs a tick, np.array_equal 1.3 µs)
        if key == self._footholds_key:
            return None
        self._footholds_key = key
        hit = None
        for i in range(4):
            p, q = footholds[i], prev[i]
            if p[0] == q[0] and p[1] == q[1] and p[2] == q[2]:
                continue
            prev[i] = p
            if q[0] != q[0]:  # the first foothold seen since a reset: no swing to judge yet
                continue
            o = liftoff[i]
            rise = float(p[2] - o[2])
            if c.face_rise_m is not None and rise >= c.face_rise_m and hit is None:
                if rise >= c.face_tan * math.hypot(float(p[0] - o[0]), float(p[1] - o[1])):
                    hit = (float(p[0]), float(p[1]))
        return hit

    def first_slip_t(self) -> float | None:
        return self._slips[0][0] if self._slips else None

    def feel(
        self,
        t: float,
        est: TickEstimates | None,
        R: np.ndarray,
        ground_margin: float,
        hold_lost: bool = False,
        front_margin: float = math.inf,
        footholds: np.ndarray | None = None,
        liftoff: np.ndarray | None = None,
    ) -> Felt | None:
        """`hold_lost`: a stance foot lost its hold this tick (`FrictionEstimate.update` returned True);
        `front_margin`: μ̂ − tan of the front feet's own slope (inf: unknown); `footholds`, `liftoff`: the
        controller's (4, 3) footholds and its swings' liftoff points (map frame, estimated), for the face trigger."""
        c = self.config
        reasons: list[str] = []
        x = y = math.nan
        if est is not None:
            for fx, fy in est.slip_xy.tolist():
                self._slips.append((t, fx, fy))
            while self._slips and self._slips[0][0] < t - c.slip_window_s:
                self._slips.popleft()
            n = len(self._slips)
            if (
                (hold_lost and ground_margin < c.lost_hold_margin)
                or n >= c.slip_events_alone
                or (n >= c.slip_events and ground_margin < c.slip_hold_margin)
                or (
                    c.slip_events_many is not None
                    and n >= c.slip_events_many
                    and ground_margin < c.slip_many_margin
                )
                or (n >= 1 and ground_margin < c.slip_sure_margin)
                or (
                    c.front_slip_margin is not None
                    and front_margin < c.front_slip_margin
                    and (hold_lost or est.slip.event[0] or est.slip.event[1])
                )
            ):
                reasons.append("slip")
                if n:
                    x = float(np.mean([s[1] for s in self._slips]))
                    y = float(np.mean([s[2] for s in self._slips]))
            low = (est.giim == est.giim and est.giim < c.min_giim_rad) or (
                est.giam == est.giam and est.giam < c.min_giam
            )
            self._margin.append((t, bool(low)))
            self._margin_low += bool(low)
            while self._margin and self._margin[0][0] < t - c.margin_window_s:
                self._margin_low -= self._margin.popleft()[1]
            full = self._margin[-1][0] - self._margin[0][0] >= 0.8 * c.margin_window_s
            if full and self._margin_low >= c.margin_share * len(self._margin):
                reasons.append("margin")
            self._contact_run = self._contact_run + 1 if est.nonfoot else 0
            face = self._face(footholds, liftoff) if footholds is not None and liftoff is not None else None
            if self._contact_run >= c.contact_ticks or face is not None:
                reasons.append("contact")
                if face is not None and x != x:
                    x, y = face
            cx, cy = est.com_xy
        else:
            cx = cy = math.nan
        if math.degrees(math.acos(max(-1.0, min(1.0, float(R[2, 2]))))) > c.max_tilt_deg:
            reasons.append("attitude")
        if not reasons:
            return None
        if x != x:
            x, y = cx, cy
        return Felt(t, x, y, tuple(reasons), len(self._slips))
