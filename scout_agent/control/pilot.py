"""The pilot: what the scout does with what it feels — adapt the gait, stop, back off, go around.

`Pilot.command(state)` gives the (forward speed, yaw rate) command each tick; `Pilot.feel(sample, est)`
takes that tick's sensors and estimates (`estimators.TickEstimates`, None when the scout maps nothing) and
returns a `Felt` when the hazard reflex fires. Everything it reads is the robot's own: the state estimate,
the sensors, the estimators, the controller's foothold plane — never the simulator's truth.

Modes:

- `walk`: follow the route (`follower.PathFollower`); the friction estimate (`friction_estimate`) feeds the
  stance QP's cone and the adaptive gait (`adaptation`) scales the speed and lowers the trunk.
- a standstill, asked for by `hold` (the state estimator's planner): stand on four feet, gait frozen, until it
  says walk on (the gyro's zero-rate updates, `state_estimation/standstill.py`).
- `stop`: the reflex (`reflex.Senses`) fired — report the hazard; with `stop_stand` (off by default) and where the
  foothold plane is at most `stand_max_slope_deg` steep, stand on four planted feet for `stand_s` (the controller's frozen gait, as in a
  standstill) so the trunk's momentum is spent on four feet before the back-off turns it round; elsewhere trot
  in place for `stop_s` only. `pilot_modes` in the summary lists each mode change (t, mode).
- `back`: trot backwards (`back_speed`, turning at most `back_max_yaw_rate`, no velocity loop) — or with
  `back_forward` (off by default) stand as `stop_stand` does, turn round in place and trot forwards — along its own
  estimated trail (with `back_off` False: no back-off; stand, then plan the detour from where it stands) to the last place it held: the trail point from
  `held_before_s` before the first slip of the episode (or before the trigger) that also lies `clear_m`
  outside the detour's hazard radius, at least `backoff_min_m` and at most `backoff_max_m` back along
  the trail. The trail is the way it walked: a back-off cuts it back to where the back-off ends and adds
  nothing, so after a detour the next back-off retraces the detour and then the way in, never the previous
  back-off toward the previous hazard (100 m field, seed 33: with the old trail, which kept the back-offs,
  2.5 m back along it led from the detour back onto the previous back-off's way, next to both hazards, and
  the scout stopped again there 1.7 s later).
- `slide` (on by default; `slide_mps` None switches it off): go with the ground, never against it. After a stop, while the estimated trunk
  still moves forward (toward the hazard), and during a back-off once it speeds up forward again, the speed
  command follows the trunk's forward speed less a gentle brake (`slide_brake_mps2` through the trunk
  controller's velocity gain), with no turn, until the trunk rests; then it backs off from there, or, if the
  ground carried it beyond the hazard's keep-out radius, it plans the detour from where it came to rest.
  Reversing the command while the trunk slid on asked the feet for ≈ 2 m/s² the patch could not give: the
  ramps matrix's 25° walks slid the whole patch down trotting backwards and fell where the ramp meets the
  flat, 0.75 m/s fast (docs/results.md, "Going with the slide").
- then plan a detour (`detour.plan_detour`) from there to the goal around every hazard it has felt (and the
  hazards and slips of a known map, when given) and `walk` it; with no detour, `stopped` with `gave_up` saying
  why. The stop policy scales with the route: it gives up after `max_stops` stops at one place (within
  `same_place_m` of the newest: the detours did not get it past), or when all its stops reach the route's
  budget, `stops_per_100m` per 100 m of route and never fewer than `max_stops` (a 25 m route: 3, as before;
  a 137 m corner-to-corner walk of the 100 m field: 11). A detour keeps `hazard_radius_m` (the detour's) times
  the number of stops felt within `same_place_m` of a hazard away from it: a second stop at the same crater
  wall means the first detour hugged it, so the next one swings wider (and the back-off clears that radius).

A standstill makes one long stance of four planted feet (6 s and more); the slip detector's ΔP of those feet
integrates the base velocity's error over it and read 5 cm on all four feet at once — "lost holds" at 0.01 m
of true displacement (ground truth, 100 m field seed 33: two of its three stops). So the feet whose stance
overlapped a standstill give the friction estimate and the reflex no slip observations until that stance
ends (`_standstill_stances`).

With `max_accel_mps2` set, the speed command changes by at most that in every mode (off by default: see the
field). `stops` lists each hazard stop as {x, y, t, reason} (map frame, estimated); `detour_m` sums, per stop, the
back-off walked plus the detour planned minus what was left of the route it abandoned.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from psrmap_mapcore import LayerGrid
from scout_agent.control.adaptation import GaitAdaptation, GaitAdaptationConfig, GaitSetting
from scout_agent.control.controller import RobotState, TrotController
from scout_agent.control.detour import DetourConfig, plan_detour
from scout_agent.control.follower import FollowerConfig, PathFollower
from scout_agent.control.foot_slope import FootTracks
from scout_agent.control.friction_estimate import FrictionEstimate, FrictionEstimateConfig
from scout_agent.control.gait import CRAWL, SWAY_CRAWL, GaitConfig
from scout_agent.control.reflex import Felt, ReflexConfig, Senses
from scout_agent.estimators import TickEstimates
from scout_agent.estimators.pipeline import quat_to_matrix
from scout_agent.robot import constants as C
from scout_agent.signals import ProprioSample

__all__ = ["Pilot", "PilotConfig"]

MODES = ("walk", "stop", "slide", "back", "stopped")


@dataclass(frozen=True)
class PilotConfig:
    follower: FollowerConfig = field(default_factory=FollowerConfig)
    adaptive: bool = True  # friction estimate → stance QP cone, adaptive gait
    reflex: bool = True  # hazard reflex, back-off and detour
    friction: FrictionEstimateConfig = field(default_factory=FrictionEstimateConfig)
    gait: GaitAdaptationConfig = field(default_factory=GaitAdaptationConfig)
    senses: ReflexConfig = field(default_factory=ReflexConfig)
    detour: DetourConfig = field(default_factory=DetourConfig)
    stop_s: float = 0.05  # barely: a robot trotting in place on ground it cannot hold slides on
    # stand on four planted feet (the standstill's frozen gait) for `stand_s` at a stop, instead of trotting in
    # place for stop_s, where the foothold plane is at most `stand_max_slope_deg` steep: the trunk's momentum
    # spent on four feet before the back-off turns it round. Off: lunar matrix 8 falls of 30 with it, 7
    # without; the short 10° ramp with a μ 0.126 patch fell with it (seed 0), the 20° one with μ 0.26 in 1 of 2
    # seeds without the slope limit (felt margin +0.075 there: the estimate cannot tell) (docs/results.md)
    stop_stand: bool = False
    stand_s: float = 1.0
    stand_max_slope_deg: float = 15.0
    # with a stand at the stop: stand on beyond `stand_s` until the estimated trunk roll and pitch rates have stayed
    # below `settle_rate_rps` for `settle_quiet_s`, at most `stand_max_s` in all (None: `stand_s` only). A back-off
    # that starts while the trunk still rocks on its feet starts a trot on a moving base
    settle_rate_rps: float | None = None
    settle_quiet_s: float = 0.5
    stand_max_s: float = 4.0
    # back off straight backwards along the heading it stands at, as far as the trail's back-off would go, instead of
    # along the trail itself: after a slide the trail lies to the side, and the reverse follower turned the trot at
    # its full yaw rate on the patch to reach it (lunar seed 9 direct: a stand, then 0.5 rad/s, fell in 0.9 s)
    back_straight: bool = False
    # back off facing forward: stand at the stop as `stop_stand` does (where the plane is gentle), then turn in
    # place (the follower's speed falls to 0 while the heading error exceeds 90°, turning at most
    # back_max_yaw_rate) and walk the back-off path forward, as the trot is built to, instead of reversing the
    # trot with the trunk still moving toward the hazard: every lunar-matrix fall of the build before came
    # while trotting backwards after a stop (docs/results.md, issue 24)
    back_forward: bool = False
    # False: no back-off — stand at the stop as `stop_stand` does (where the plane is gentle), then plan the
    # detour from where it stands (the detour keeps out of the felt hazard, shrunk to just short of the scout
    # when it stands inside the hazard's radius: it may walk out, never further in)
    back_off: bool = True
    # after a hazard stop (modes stop and back) the speed command changes by at most what the ground was felt to
    # hold: brake_share · g · (μ̂ − tan θ̂) [m/s²], at least brake_min_mps2 (None: no limit). A step from walking
    # to backing off asked the trunk controller for ≈ 2 m/s², 5× what a μ 0.23 patch holds at lunar g
    brake_share: float | None = None  # e.g. 0.7 (off: see docs/results.md, issue 24)
    brake_min_mps2: float = 0.1
    # the stance QP's cone from where the ground was felt, not from which leg felt it: a foot standing within
    # this of a place where a foot lost its hold gets qp_share × the μ̂ felt there, any other foot the
    # controller's constant (None: each leg's own μ̂, which moves with the leg — onto the patch at the prior,
    # and the QP then loads the unslipped feet standing on the same patch the more)
    cone_radius_m: float | None = None  # e.g. 0.35 (off: see docs/results.md, issue 24)
    max_accel_mps2: float | None = None  # a rate limit on the speed command [m/s²] (None: none; 0.25 fell
    # more on the ramp matrix, 15 of 50 against 8: it kept the front feet walking onto the patch longer)
    trot: GaitConfig = field(default_factory=GaitConfig)  # the gait where the ground holds
    crawl: GaitConfig = CRAWL  # one leg at a time (three feet down), near hazards when crawl_near_m is set
    crawl_near_m: float | None = None  # crawl while within this of a hazard felt, beyond the detour's hazard
    # radius (None: trot everywhere)
    crawl_speed: float = 0.1  # the most a crawl is asked to walk [m/s] (its feet reach 0.15 m from the hips)
    # the gait where the trot's diagonal pair cannot hold: the sway crawl keeps three feet down with the trunk
    # inside their triangle, so a foot that slides does not roll the trunk over a diagonal pair as the trot does
    # (the lunar falls: diagonal-pair rolls on patches, docs/results.md issue 24). It walks at no more than
    # `slip_gait_speed`, and the speed command falls to that no faster than `slip_gait_brake_mps2`
    slip_gait: GaitConfig = SWAY_CRAWL
    slip_gait_speed: float = 0.03  # [m/s] (the sway crawl's 4 s cycle steps ≈ 0.12 m)
    slip_gait_brake_mps2: float = 0.2  # ≈ what μ 0.16 holds on level ground at lunar g, with a margin
    # the switch into `slip_gait` waits, trotting, until the trunk is slower than this [m/s] or `slip_gait_wait_s`
    # after the speed command reached `slip_gait_speed` (crawl steps under a trunk still moving at 0.2 m/s fell
    # in 23 of 30 lunar walks, docs/results.md)
    slip_gait_enter_mps: float = 0.06
    slip_gait_wait_s: float = 2.0
    # from a hazard stop to the end of the back-off, walk `slip_gait` (off: lunar matrix 23 falls of 30 with the
    # crawl switched in at the stop, under a trunk still moving; braking first as here, 22 of 30; 7 without)
    back_crawl: bool = False
    back_max_yaw_rate: float = FollowerConfig.max_yaw_rate  # [rad/s] while backing off
    # ... and where the felt margin m = μ̂ − tan θ̂ is below the adaptive gait's `margin_full`, at most
    # `back_min_yaw_rate` + (back_max_yaw_rate − back_min_yaw_rate) · m / margin_full (None: the full rate
    # everywhere). Turning a trot asks its feet for sideways force the ground it just slipped on does not give:
    # on lunar seed 3 east (μ 0.235 on 21–26°) the reverse follower swung the heading ±40° at 0.5 rad/s for
    # 25 s, the trunk sliding forward at each swing, and fell in the third slide (docs/results.md, issue 24)
    back_min_yaw_rate: float | None = 0.1
    back_speed: float = 0.1  # [m/s], trotting (a crawl back-off fell in 4 of 4 ramp walks where this one fell in 2); no velocity loop: on ground that slips, pushing harder slides
    held_before_s: float = 1.0
    backoff_min_m: float = 0.4
    backoff_max_m: float = 2.5
    back_timeout_s: float = 25.0
    trail_step_m: float = 0.05
    clear_m: float = 0.2  # back off until this far outside the detour's hazard radius (or backoff_max_m)
    max_stops: int = 3  # hazard stops at one place (within same_place_m of the newest) before giving up
    same_place_m: float = 4.0  # stops this close count as one place (and widen each other's detour radius)
    stops_per_100m: float = 8.0  # all stops of a walk: at most this per 100 m of route (at least max_stops)
    # go with the ground, never against it (mode `slide`; None: off): after a stop, while the estimated trunk
    # still moves forward (toward the hazard) faster than `slide_end_mps`, and during a back-off once it speeds up
    # forward again (faster than `slide_mps` and `slide_rise_mps` above the slowest it went in that back-off, for
    # `slide_s`), trot with it — the speed command at the trunk's forward speed less what brakes it by
    # `slide_brake_mps2` through the trunk controller's velocity gain, no turn — until its forward speed stayed
    # below `slide_end_mps` for `slide_s`. Then back off from there, or, if the ground carried it past the
    # hazard's keep-out radius, plan the detour from where it came to rest. Reversing the command while the
    # trunk slid on toward the hazard asked the feet for ≈ 2 m/s² that ground cannot give (every fall of the
    # matrices came while backing off; on main 7b0290f the ramps matrix fell 2 of 50 with it against 6 without, the
    # lunar matrix 7 of 30 against 11, docs/results.md "Going with the slide")
    slide_mps: float | None = 0.05
    slide_rise_mps: float = 0.05
    slide_s: float = 0.2
    slide_brake_mps2: float = 0.2
    slide_end_mps: float = 0.05
    max_slides: int = 3  # slides after one stop before the scout goes around from where it rests
    # a slide that comes to rest with the fore feet on ground that holds and the hind feet on ground that does not
    # (both fore feet's μ̂ at least `ahead_gap` above both hind feet's) rests at the far
    # edge of what it slid on: the held ground is ahead, so it goes around from there instead of backing off
    # across the patch again (None: always back off inside the hazard's radius). Lunar seed 3 east slid 3.5 s
    # through a μ 0.235 patch on 21–26° until its fore feet stood on μ 0.7 (μ̂ 0.41 / 0.44, hind 0.13 / 0.17),
    # then backed off up the patch for 25 s and fell (docs/results.md, issue 24)
    ahead_gap: float | None = 0.15


def _forward(s: RobotState, yaw: float) -> float:
    """The trunk's estimated horizontal speed along its heading `yaw` [m/s]."""
    return float(s.vel[0]) * math.cos(yaw) + float(s.vel[1]) * math.sin(yaw)


def _length(points: np.ndarray) -> float:
    return float(np.sum(np.hypot(*np.diff(points, axis=0).T))) if len(points) > 1 else 0.0


class Pilot:
    def __init__(
        self,
        waypoints: np.ndarray,
        controller: TrotController,
        bounds: tuple[float, float, float, float],
        config: PilotConfig = PilotConfig(),
        known: Callable[[], LayerGrid | None] | None = None,
        hold: Callable[[float], bool] | None = None,
    ) -> None:
        self.config = config
        self.hold = hold  # the state estimator's standstill planner: stand still now (time [s])
        self.controller = controller
        self.bounds = bounds
        self.known = known
        self.route = np.asarray(waypoints, dtype=float)[:, :2]
        self.follower = PathFollower(self.route, config.follower)
        self.goal = self.route[-1]
        self.friction = FrictionEstimate(config.friction)
        self.adaptation = GaitAdaptation(config.gait)
        self.senses = Senses(config.senses)
        # the front feet's own slope (read unless `senses.front_slip_margin` is None)
        self.tracks = FootTracks()
        self.setting: GaitSetting | None = None
        self.mode = "walk"
        self.reached = False
        self.gave_up: str | None = None
        self.stops: list[dict] = []
        self.hazards: list[tuple[float, float]] = []
        self.detour_m = 0.0
        self.trail: list[tuple[float, float, float]] = []  # t, x, y of the estimate, every trail_step_m
        self.route_m = _length(self.route)
        self.stop_budget = max(config.max_stops, math.ceil(self.route_m * config.stops_per_100m / 100.0))
        self.stops_here = 0  # stops within same_place_m of the newest (itself included)
        self._standstill_feet = np.zeros(4, dtype=bool)  # feet whose current stance overlapped a standstill
        self._t_mode = 0.0
        self.mode_log: list[tuple[float, str]] = [(0.0, "walk")]  # (t [s], mode) at each change
        self._back: PathFollower | None = None
        self._back_len = 0.0
        self._left_of_route = 0.0
        self._t_prev: float | None = None
        self._v = 0.0  # the last speed command [m/s]
        self._normal_key: tuple[float, float] | None = None
        self._normal = np.array([0.0, 0.0, 1.0])
        self._stand_stop = False  # this stop stands on four feet (`stop_stand`)
        self._quiet_since: float | None = (
            None  # the trunk's roll and pitch rates low since then [s] (settling)
        )
        self.lost_spots: list[tuple[float, float, float]] = []  # x, y [m], μ̂ where a foot lost its hold
        self._wish = config.trot  # the gait to walk (`_shift_gait` switches the controller to it)
        self._slow_since: float | None = None  # the speed command reached slip_gait_speed then [s]
        self._slide_since: float | None = None  # carried forward since (back) / at rest since (slide) [s]
        self._fwd_min = math.inf  # the slowest forward speed of this back-off [m/s]
        self._slides = 0  # slides since the last stop
        # walking out of a hazard it slid through to ground that holds (`ahead_gap`): (x, y, radius) of that
        # hazard; inside that radius a slip alone (the hind feet still on it) does not stop the scout again
        self._walk_out: tuple[float, float, float] | None = None

    @property
    def done(self) -> bool:
        return self.reached or self.mode == "stopped"

    # ------------------------------------------------------------------ command
    def command(self, s: RobotState, dt: float) -> tuple[float, float]:
        """(forward speed, yaw rate) for the controller; with `max_accel_mps2` set, the speed changes by at most
        that (the trunk controller turns a step in the command into a braking force of kd·Δv·m, ≈ 0.9 g for a
        stop from 0.2 m/s)."""
        c = self.config
        v, w = self._command(s, dt)
        if not (c.adaptive or c.reflex):
            return v, w
        limits = [] if c.max_accel_mps2 is None else [c.max_accel_mps2]
        if c.brake_share is not None and self.mode in ("stop", "back"):
            limits.append(self.brake_mps2())
        if self._wish == c.slip_gait:
            limits.append(c.slip_gait_brake_mps2)
        if not limits:
            self._v = v
        else:
            a = min(limits) * dt
            self._v = self._v + min(a, max(-a, v - self._v))
        self._shift_gait(s)
        return self._v, w

    def _shift_gait(self, s: RobotState) -> None:
        """Walk the gait wished for (`_wish`): at once, except into `slip_gait`, which waits (trotting, the speed
        command falling to `slip_gait_speed`) until the trunk is slow enough to crawl under."""
        c, current = self.config, self.controller.gait.config
        if self._wish == current:
            self._slow_since = None
            return
        if self._wish != c.slip_gait:
            self.controller.set_gait(self._wish, s.t)
            return
        if abs(self._v) > c.slip_gait_speed + 1e-9:
            return
        if self._slow_since is None:
            self._slow_since = s.t
        slow = math.hypot(float(s.vel[0]), float(s.vel[1])) < c.slip_gait_enter_mps
        if slow or s.t - self._slow_since >= c.slip_gait_wait_s:
            self.controller.set_gait(c.slip_gait, s.t)
            self._slow_since = None

    def brake_mps2(self) -> float:
        """The most the speed command may change per second after a hazard stop [m/s²]: a share of what the
        ground's felt margin holds against gravity along the slope."""
        c = self.config
        margin = self.setting.margin if self.setting is not None else math.inf
        return max(c.brake_min_mps2, c.brake_share * C.LUNAR_G * margin) if c.brake_share else math.inf

    def turn_limit(self) -> float:
        """The most the back-off (or a walk out of a hazard it slid through) may turn [rad/s]: the full
        `back_max_yaw_rate` where the felt margin is at least the adaptive gait's `margin_full`, falling linearly
        to `back_min_yaw_rate` at no margin."""
        c = self.config
        if c.back_min_yaw_rate is None or self.setting is None:
            return c.back_max_yaw_rate
        u = min(1.0, max(0.0, self.setting.margin / c.gait.margin_full))
        lo = min(c.back_min_yaw_rate, c.back_max_yaw_rate)
        return lo + (c.back_max_yaw_rate - lo) * u

    def _settled(self, s: RobotState) -> bool:
        """A stand at a stop has lasted long enough: `stand_s`, and with `settle_rate_rps` set, until the trunk's
        estimated roll and pitch rates stayed below it for `settle_quiet_s` (or `stand_max_s` passed)."""
        c = self.config
        t = s.t - self._t_mode
        quiet = math.hypot(float(s.omega[0]), float(s.omega[1])) < (c.settle_rate_rps or math.inf)
        if not quiet:
            self._quiet_since = None
        elif self._quiet_since is None:
            self._quiet_since = s.t
        if t < c.stand_s:
            return False
        if c.settle_rate_rps is None or t >= c.stand_max_s:
            return True
        return self._quiet_since is not None and s.t - self._quiet_since >= c.settle_quiet_s

    def _command(self, s: RobotState, dt: float) -> tuple[float, float]:
        yaw = float(np.arctan2(s.R[1, 0], s.R[0, 0]))
        stand = self.mode == "walk" and self.hold is not None and not self.reached and self.hold(s.t)
        stand = stand or (self.mode == "stop" and self._stand_stop)
        self.controller.hold = (
            stand  # on four feet, gait frozen: a standstill (state_estimation/standstill.py)
        )
        if stand and self.mode == "stop" and self._settled(s):
            self.controller.hold = False
            self._start_back(s.pos[:2], s.t, yaw)
            return 0.0, 0.0
        if stand:
            return 0.0, 0.0
        if self.mode == "walk":
            v, w = self.follower.command(s.pos[:2], yaw, s.vel[:2], dt)
            self.reached = self.follower.reached
            if self.setting is not None:
                v *= self.setting.speed_scale
            if self._walk_out is not None:  # still on the hazard it slid through: turn as a back-off does
                lim = self.turn_limit()
                w = min(lim, max(-lim, w))
            if self.controller.gait.config == self.config.crawl:
                v = min(v, self.config.crawl_speed)
            elif self._wish == self.config.slip_gait:
                v = min(v, self.config.slip_gait_speed)
            return v, w
        if self.mode == "slide":
            return self._slide(s, yaw), 0.0
        if self.mode == "back" and self._back is not None:
            if self._carried(s, yaw):
                self._set_mode("slide", s.t)
                return self._slide(s, yaw), 0.0
            v, w = self._back.command(s.pos[:2], yaw, s.vel[:2], dt)
            lim = self.turn_limit()
            w = min(lim, max(-lim, w))
            if self._wish == self.config.slip_gait:
                v = max(v, -self.config.slip_gait_speed)
            if self._back.reached or s.t - self._t_mode > self.config.back_timeout_s:
                self._go_around(s.pos[:2], s.t)
            return v, w
        if self.mode == "stop" and s.t - self._t_mode >= self.config.stop_s:
            if self.config.slide_mps is not None and _forward(s, yaw) >= self.config.slide_end_mps:
                self._set_mode("slide", s.t)
                return self._slide(s, yaw), 0.0
            self._start_back(s.pos[:2], s.t, yaw)
        return 0.0, 0.0

    # ------------------------------------------------------------------ feel
    def feel(self, sample: ProprioSample, est: TickEstimates | None) -> Felt | None:
        c = self.config
        t = sample.t
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        R = quat_to_matrix(sample.base.quat)
        x, y = float(sample.base.pos[0]), float(sample.base.pos[1])
        far = not self.trail or math.hypot(x - self.trail[-1][1], y - self.trail[-1][2]) >= c.trail_step_m
        if far and self.mode == "walk":  # the way it came: a back-off retraces it, it does not extend it
            self.trail.append((t, x, y))
        grad, _ = self.controller.plane()
        lost = False
        if est is not None:
            est = self._standstill_stances(sample, est)
        if c.adaptive and est is not None:
            sl = est.slip
            mu_before = self.friction.mu.copy()
            lost = self.friction.update(
                sample.q,
                sample.tau,
                R,
                sample.contact,
                self._plane_normal(grad),
                sl.event,
                sl.stance_end,
                sl.slipped,
                sl.dp,
                dt,
                est.foot_force_w,
                self._cone_now(),
                sample.imu_acc,
            )
            if lost:
                f = self.controller.footholds
                for i in np.flatnonzero(self.friction.mu < mu_before):
                    self.lost_spots.append((float(f[i, 0]), float(f[i, 1]), float(self.friction.mu[i])))
            setting = self.adaptation.setting(self.friction.mu, grad, self.friction.proven)
            if setting is not self.setting:
                self.setting = setting
                if c.cone_radius_m is None:
                    self.controller.set_friction(setting.qp_mu)
                self.controller.height_offset = setting.height_offset_m
                self.controller.accel_limit = setting.accel_limit_mps2
            if c.cone_radius_m is not None and self.lost_spots:
                self.controller.set_friction(self._cone())
        if self._walk_out is not None:
            hx, hy, r = self._walk_out
            if self.mode != "walk" or math.hypot(x - hx, y - hy) > r:
                self._walk_out = None  # out of it
        if not c.reflex or self.mode != "walk" or self.reached:
            return None
        self._wish = c.crawl if self._near_hazard(x, y) else c.trot
        margin = self.setting.margin if self.setting is not None else math.inf
        front = math.inf
        if c.senses.front_slip_margin is not None:
            self.tracks.update(self.controller.footholds)
            tan_front = self.tracks.front_tan()
            if tan_front == tan_front:
                front = self.friction.area_mu - tan_front
        felt = self.senses.feel(
            t, est, R, margin, lost, front, self.controller.footholds, self.controller.liftoff
        )
        if felt is None:
            return None
        if self._walk_out is not None and felt.reasons == ("slip",):
            # walking out of a hazard it slid through (`ahead_gap`): the hind feet still on it slip, as felt
            self.senses.forget_slips()
            return None
        self._stop(felt, x, y)
        return felt

    def _standstill_stances(self, sample: ProprioSample, est: TickEstimates) -> TickEstimates:
        """`est` without the slip observations of feet whose current stance overlapped a standstill (their ΔP
        holds the base velocity's error integrated over it), until that stance ends."""
        held = self._standstill_feet
        # (the common case first, in Python: numpy's any and | cost ~1 µs each on 4 flags, every tick)
        if not self.controller.hold and True not in held.tolist():
            return est
        planted = np.asarray(sample.stance_planned, dtype=bool) | np.asarray(sample.contact, dtype=bool)
        if self.controller.hold:
            held |= planted
        if True not in held.tolist():
            return est
        sl = est.slip
        out = est
        if any(e and h for e, h in zip(sl.event, held, strict=True)):
            rows = [i for i in range(4) if sl.event[i]]  # slip_xy: one row per event, in leg order
            keep = [k for k, i in enumerate(rows) if not held[i]]
            out = out._replace(slip_xy=est.slip_xy[keep])
        masked = sl._replace(
            event=tuple(e and not h for e, h in zip(sl.event, held, strict=True)),
            slipped=tuple(s and not h for s, h in zip(sl.slipped, held, strict=True)),
            dp=tuple(math.nan if h else d for d, h in zip(sl.dp, held, strict=True)),
        )
        # the stance ends (or the foot leaves its planned stance): its next stance is a walking one again
        held &= ~np.asarray(sl.stance_end, dtype=bool) & planted
        if self.controller.hold:
            held |= planted
        return out._replace(slip=masked)

    def _cone_now(self) -> np.ndarray:
        """(4,) the friction the stance QP gives each foot now."""
        mu = self.controller.mu_feet
        return mu if mu is not None else np.full(4, self.controller.qp.config.mu)

    def _cone(self) -> np.ndarray:
        """(4,) each foot's friction for the stance QP from the holds lost within `cone_radius_m` of its foothold."""
        c, g = self.config, self.config.gait
        spots = np.asarray(self.lost_spots)
        f = self.controller.footholds
        d = np.hypot(f[:, 0, None] - spots[None, :, 0], f[:, 1, None] - spots[None, :, 1])  # (4, n)
        near = np.where(d <= c.cone_radius_m, spots[None, :, 2], np.inf).min(axis=1)
        return np.minimum(g.qp_mu_max, np.where(np.isfinite(near), g.qp_share * near, g.qp_mu_max))

    def _plane_normal(self, grad: np.ndarray) -> np.ndarray:
        """Unit upward normal of the foothold plane z = g·(x, y) + c (kept while the plane does not change:
        it moves only when a foot lands)."""
        key = (float(grad[0]), float(grad[1]))
        if key != self._normal_key:
            n = np.array([-key[0], -key[1], 1.0])
            n /= np.linalg.norm(n)
            self._normal_key, self._normal = key, n
        return self._normal

    # ------------------------------------------------------------------ modes
    def _near_hazard(self, x: float, y: float) -> bool:
        if self.config.crawl_near_m is None:
            return False
        near = self.config.detour.hazard_radius_m + self.config.crawl_near_m
        return any(math.hypot(x - hx, y - hy) < near for hx, hy in self.hazards)

    def _stop(self, felt: Felt, x: float, y: float) -> None:
        if not (math.isfinite(felt.x) and math.isfinite(felt.y)):
            # felt with no estimates to place it (attitude alone, no slip or margin this tick): where the base is
            felt = replace(felt, x=x, y=y)
        self.stops.append(
            {
                "x": round(felt.x, 3),
                "y": round(felt.y, 3),
                "t": round(felt.t, 3),
                "reason": ",".join(felt.reasons),
                "slips": felt.slips,
                "mu_felt": round(self.friction.area_mu, 3),
                "margin_felt": round(self.setting.margin, 3) if self.setting is not None else None,
            }
        )
        self.hazards.append((felt.x, felt.y))
        self.stops_here = self._stops_near(felt.x, felt.y)
        f = self.follower
        nxt = min(f.segment + 1, len(f.points) - 1)
        self._left_of_route = math.hypot(*(f.points[nxt] - (x, y))) + _length(f.points[nxt:])
        t0 = self.senses.first_slip_t() if "slip" in felt.reasons else None
        self._t_held = (t0 if t0 is not None else felt.t) - self.config.held_before_s
        self.senses.reset()
        self.tracks.reset()
        self._walk_out = None
        c = self.config
        grad, _ = self.controller.plane()
        steep = math.degrees(math.atan(math.hypot(float(grad[0]), float(grad[1]))))
        stand = c.stop_stand or c.back_forward or not c.back_off
        self._stand_stop = stand and steep <= c.stand_max_slope_deg
        if c.back_crawl:
            self._wish = c.slip_gait
        self._quiet_since = None
        self._slides, self._slide_since = 0, None
        self._set_mode("stop", felt.t)

    def _carried(self, s: RobotState, yaw: float) -> bool:
        """Backing off, the trunk has sped up forward again: faster than `slide_mps` and `slide_rise_mps` above
        the slowest it went in this back-off, for `slide_s` (estimated)."""
        c = self.config
        if c.slide_mps is None or self._slides >= c.max_slides:
            return False
        fwd = _forward(s, yaw)
        self._fwd_min = min(self._fwd_min, fwd)
        if fwd <= c.slide_mps or fwd <= self._fwd_min + c.slide_rise_mps:
            self._slide_since = None
            return False
        if self._slide_since is None:
            self._slide_since = s.t
        return s.t - self._slide_since >= c.slide_s

    def _slide(self, s: RobotState, yaw: float) -> float:
        """The speed command while the ground carries the trunk forward: its own forward speed, braking gently;
        once at rest, back off from here or (carried past the hazard's radius) go around from here."""
        c = self.config
        fwd = _forward(s, yaw)
        if fwd >= c.slide_end_mps:
            self._slide_since = None
            return max(0.0, fwd - c.slide_brake_mps2 / self.controller.config.kd_pos[0])
        if self._slide_since is None:
            self._slide_since = s.t
        if s.t - self._slide_since < c.slide_s:
            return 0.0
        self._slides += 1
        self._slide_since = None
        hx, hy = self.hazards[-1]
        x, y = float(s.pos[0]), float(s.pos[1])
        past = math.hypot(x - hx, y - hy) > self._radius(hx, hy)
        ahead = not past and self.held_ahead()
        if past or self._slides >= c.max_slides or ahead:
            self._back_len = 0.0
            if ahead:
                self._walk_out = (hx, hy, self._radius(hx, hy))
            self._go_around(s.pos[:2], s.t)
        else:
            self._start_back(s.pos[:2], s.t, yaw)
        return 0.0

    def held_ahead(self) -> bool:
        """The fore feet stand on ground that holds and the hind feet on ground that does not (`ahead_gap`)."""
        gap = self.config.ahead_gap
        if gap is None:
            return False
        mu = self.friction.mu
        return bool(min(mu[0], mu[1]) >= max(mu[2], mu[3]) + gap)

    def _start_back(self, pos: np.ndarray, t: float, yaw: float = math.nan) -> None:
        c = self.config
        if not c.back_off:
            self._back_len = 0.0
            self._go_around(pos, t)
            return
        back = [(float(pos[0]), float(pos[1]))]
        hx, hy = self.hazards[-1]
        clear = self._radius(hx, hy) + c.clear_m
        walked = 0.0
        keep = len(self.trail)
        for k in range(len(self.trail) - 1, -1, -1):  # newest first
            p = self.trail[k]
            q = (p[1], p[2])
            step = math.hypot(q[0] - back[-1][0], q[1] - back[-1][1])
            keep = k + 1
            if step < 0.01:
                continue
            walked += step
            back.append(q)
            held = p[0] <= self._t_held and math.hypot(q[0] - hx, q[1] - hy) >= clear
            if walked >= c.backoff_max_m or (walked >= c.backoff_min_m and held):
                break
        self._back_len = walked
        if c.back_straight and yaw == yaw and walked >= 0.05:
            # straight back along the heading it stands at, as far (the trail told how far, not where)
            back = [back[0], (back[0][0] - walked * math.cos(yaw), back[0][1] - walked * math.sin(yaw))]
        if len(back) < 2 or walked < 0.05:
            self._go_around(pos, t)
            return
        # the trail ends where the back-off will: the detour continues it from there, so a later back-off
        # retraces the detour and then the way in before this place, not this back-off into the hazard
        del self.trail[keep:]
        back_cfg = FollowerConfig(
            speed=c.back_speed,
            goal_tolerance_m=0.1,
            ki=0.0,
            max_boost=0.0,
            max_yaw_rate=c.back_max_yaw_rate,
        )
        self._back = PathFollower(np.array(back), back_cfg, reverse=not c.back_forward)
        self._fwd_min, self._slide_since = math.inf, None
        self._set_mode("back", t)

    def _go_around(self, pos: np.ndarray, t: float) -> None:
        c = self.config
        self._back = None
        if self.stops_here >= c.max_stops:
            self._give_up(
                f"{self.stops_here} hazard stops at one place (within {c.same_place_m:g} m; max_stops "
                f"{c.max_stops})",
                t,
            )
            return
        if len(self.stops) >= self.stop_budget:
            self._give_up(
                f"{len(self.stops)} hazard stops: the route's budget ({self.stop_budget} for "
                f"{self.route_m:.0f} m, stops_per_100m {c.stops_per_100m:g}, at least max_stops {c.max_stops})",
                t,
            )
            return
        known = self.known() if self.known is not None else None
        hazards = [(hx, hy, self._radius(hx, hy)) for hx, hy in self.hazards]
        way = plan_detour(pos, self.goal, hazards, self.bounds, c.detour, known)
        if way is None or len(way) < 2:
            self._give_up(f"no path to the goal around the {len(self.hazards)} hazard(s) felt", t)
            return
        self.detour_m += self._back_len + _length(way) - self._left_of_route
        self.follower = PathFollower(way, c.follower)
        self._set_mode("walk", t)

    def _stops_near(self, x: float, y: float) -> int:
        d = self.config.same_place_m
        return sum(math.hypot(x - hx, y - hy) <= d for hx, hy in self.hazards)

    def _radius(self, x: float, y: float) -> float:
        """The detour's keep-out radius around a hazard felt at (x, y) [m]: wider for each stop felt there."""
        return self.config.detour.hazard_radius_m * min(self._stops_near(x, y), self.config.max_stops)

    def _give_up(self, why: str, t: float) -> None:
        self.gave_up = why
        self._set_mode("stopped", t)

    def _set_mode(self, mode: str, t: float) -> None:
        self.mode, self._t_mode = mode, t
        self.mode_log.append((round(t, 3), mode))

    def summary(self) -> dict:
        return {
            "hazard_stops": self.stops,
            "detour_m": round(self.detour_m, 3),
            "gave_up": self.gave_up,
            "friction_estimate": [round(float(m), 3) for m in self.friction.mu],
            "pilot_modes": [[t, m] for t, m in self.mode_log],
        }
