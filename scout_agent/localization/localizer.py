"""`Localizer`: in the scout's loop, collect footholds, match them every few metres walked against the
references it has (an orbital DEM, the shared map), and fuse an accepted match into the state estimate.

Per tick (`on_tick`, after the estimator's update and before the mapper turns the tick into map statistics,
so what the scout publishes next is placed with the corrected pose): a foot whose contact has been on for
`settle_s` adds its ground point, as the estimate places it, to the `FootholdTrack`. Each reference has its
own cadence (`SourceConfig`): every `every_m` walked (by the estimate), the last `track_m` of footholds are
matched (`match_track`) over a window sized by the filter's own position σ (a DEM's 5 m pixels need a long
track; the shared map's 0.4 m cells a short one); an accepted match is fused as a pose measurement
(`state_estimation.pose_update.update_pose`, χ²-gated at p = 0.001), and the track moves with the
correction. Consecutive matches share track_m / every_m of their footholds, so their covariance is inflated
by that factor (the filter must not count the same footholds twice as new evidence).

`LocalizerReport` counts what happened: attempts, fused, refused per reason (few, edge, flat, ambiguous,
gate), the last σ, and the matcher's cost.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit
from scipy.stats import chi2

from scout_agent.estimators.feet import PinocchioFeet
from scout_agent.robot import constants as C
from scout_agent.signals import ProprioSample
from scout_agent.state_estimation import StateEstimator
from scout_agent.state_estimation.pose_update import heading, heading_row, update_pose

from .fleet_ties import FleetTieConfig, fleet_ties
from .height_track import HeightTrack, HeightTrackConfig
from .matcher import HeightFix, MatchConfig, MatchResult, match_height, match_track
from .reference import DemReference, GridReference, HeightReference
from .track import FootholdTrack
from .trail import TrailConfig, TrailFix, match_trail

__all__ = [
    "LOCALIZE_MODES",
    "Localizer",
    "LocalizerConfig",
    "LocalizerReport",
    "MapSource",
    "SourceConfig",
    "search_config",
]

LOCALIZE_MODES = ("on", "off")

# the shared map around (x, y) within `radius` [m] as a reference, or None (no server, no data yet)
MapSource = Callable[[float, float, float], "HeightReference | None"]


@dataclass(frozen=True)
class SourceConfig:
    """How one reference is matched: cadence, track length, search, and the σ of its vertical datum."""

    every_m: float  # a match every this much walked [m]
    track_m: float  # footholds of the last this much walked [m]
    match: MatchConfig
    datum_m: float  # σ of the reference's vertical datum [m]
    # where the place is not found (`height_fix_on`), fuse the height alone (`match_height`): a DEM's stated
    # noise and bias bound the height long before its 5 m pixels bound the place; the shared map's heights
    # carry the other scouts' own height error, which their height layer states per cell (`datum_sigma`)
    height_fix: bool = False
    first_m: float | None = None  # the first match once this much is walked (default: `track_m`)
    # a height fix fits the datum along the track as a line in the distance walked and fuses its value at the
    # newest foothold (`match_height`), the line's slope with this prior σ [m/m] (0: the track's mean datum,
    # which lags a drifting estimate by half the track's drift): the estimate's height drifts 1–3 cm per metre
    # walked on the 100 m field (docs/results.md, "The map's heights at mission scale")
    height_rate_sigma: float = 0.0
    # the match's refusals after which the height alone is tried, and at most one height fix per this much
    # walked [m] (a reference's datum error is common to the fixes in between: they must not count it twice)
    height_fix_on: tuple[str, ...] = ("flat", "ambiguous", "edge")
    height_every_m: float = 0.0
    # σ of the reference frame's heading [°]: a match against the others' cells turns the scout into the frame
    # their own estimates drew them in, whose local orientation is off by their heading error (1.5–4.3° on the
    # default mission, 1.4–4.8° on 100 m walks; docs/results.md); the map states their horizontal σ per cell
    # (the placement layer, added whole to a place fix) but not their heading's, so this prior stands for it
    frame_yaw_sigma_deg: float = 0.0


@dataclass(frozen=True)
class LocalizerConfig:
    settle_s: float = 0.15  # a stance's foothold is taken once its contact has lasted this long [s]
    gate_p: float = 0.001  # χ² gate's false-rejection probability
    window_sigmas: float = 3.0  # the search window covers this many σ of the filter's position and heading
    # the robot's own height drift per metre walked, learnt from the DEM height fixes' slopes along the track
    # and taken off the estimate's height as it walks: prior σ [m/m] (0: not learnt, the default). A
    # calibration error of the legs' kinematics tilts leg odometry's velocity by a constant angle, so the
    # height would drift at a constant rate per metre; on the 100 m mission (seed 33) the learnt rate was
    # 0.006–0.018 m/m after one fix with a σ of a few mm/m, the later fixes' contrary slopes fell outside the
    # gate, and the height ran away (−1.8 m on one scout; docs/results.md, "The map's heights at mission
    # scale"): the slope of one DEM track carries the horizontal misplacement too, which its σ does not state
    drift_rate_sigma: float = 0.0
    # the DEM's height from every foothold since launch, each DEM pixel's error counted once, the datum and its
    # drift per metre walked fitted together (height_track.py), at every DEM attempt; the filter's height is
    # set to that estimate (it holds all the DEM said so far, and the shared map's height fixes). None: the
    # height alone from the last `track_m` where the place is not found (`match_height`), as before
    height_track: HeightTrackConfig | None = field(default_factory=HeightTrackConfig)
    # with a DEM's whole-walk fit and the shared map: before each whole-walk fit (and at the walk's end), the
    # other scouts' cells under the stretch the scout still holds, as measurements of its datum there
    # (fleet_ties.py); None: off
    fleet_tie: FleetTieConfig | None = field(default_factory=FleetTieConfig)
    yaw_steps: int = 3  # yaw candidates each side of the estimate's heading
    # the orbital DEM's place and heading fix (`trail.match_trail`): the footholds walked since the last fused
    # fix, read against the DEM with the last `dem_trail_m` of trail fixing the datum line, the filter's own
    # (x, y, heading) covariance as the prior, fused as the posterior divided by it (each foothold once)
    dem_trail: TrailConfig = field(default_factory=TrailConfig)
    dem_trail_m: float = 60.0
    # a DEM: 5 m pixels with 0.3 m noise: a place and heading fix (`dem_trail`) every 25 m from 30 m; the
    # height alone (`match_height`, over the last 100 m) at every attempt; `match` holds the height fix's
    # settings (its search grid step, footholds, Huber k); datum σ: the DEM's vertical bias (OrbitalDemConfig,
    # LOLA).
    dem: SourceConfig = field(
        default_factory=lambda: SourceConfig(
            25.0,
            100.0,
            MatchConfig(
                window_m=8.0,
                step_m=0.5,
                yaw_window_deg=6.0,
                max_sigma_m=2.5,
                method="moments",
                max_points=200,
            ),
            0.03,
            height_fix=True,
            first_m=30.0,
            height_rate_sigma=0.02,
        )
    )
    # the shared map: 0.4 m cells with cm-level scatter
    map: SourceConfig = field(
        default_factory=lambda: SourceConfig(
            3.0,
            10.0,
            # another scout's track covers part of ours where they cross or run alongside: a quarter will do
            MatchConfig(window_m=1.0, step_m=0.1, yaw_window_deg=3.0, max_sigma_m=0.3, min_coverage=0.25),
            0.01,
            # where the place is not found, the height against the others' cells under ≥ 5 m of the track
            # (`min_points` footholds), their vertical σ added whole; one per 20 m: an other scout's datum
            # error changes at its own fixes, 25 m apart, so fixes closer than that would share it
            height_fix=True,
            height_fix_on=("few", "flat", "ambiguous", "edge"),
            height_every_m=20.0,
            frame_yaw_sigma_deg=3.0,
        )
    )


@dataclass
class LocalizerReport:
    sources: tuple[str, ...] = ()  # the references it had: "dem", "map"
    attempts: int = 0
    fused: Counter = field(default_factory=Counter)  # per source
    refused: Counter = field(default_factory=Counter)  # per source and reason, e.g. "dem_flat", "map_gate"
    last_sigma_m: float | None = None
    match_seconds: float = 0.0  # wall time spent matching and fusing [s]
    corrections_m: list[float] = field(default_factory=list)  # horizontal size of each fused correction
    height_corrections_m: list[float] = field(default_factory=list)  # each fused height-only correction [m]
    heading_corrections_deg: list[float] = field(default_factory=list)  # each fused fix's heading change [°]
    drift_rate_m_per_m: float = 0.0  # the height drift per metre walked learnt and taken off (Localizer)
    fleet_ties: int = 0  # pieces of the held walk tied to the other scouts' cells (fleet_ties.py)

    @staticmethod
    def _largest(values: list[float]) -> float | None:
        """The value of largest magnitude, rounded (None when there is none)."""
        return round(float(max(values, key=abs)), 4) if values else None

    @property
    def fixes(self) -> int:
        """Fixes fused so far, of every kind."""
        return sum(self.fused.values())

    @property
    def used(self) -> str:
        """What localization used: "off", or the references joined by "+" ("dem", "map", "dem+map")."""
        return "+".join(self.sources) if self.sources else "off"

    def to_json(self) -> dict:
        return {
            "used": self.used,
            "attempts": self.attempts,
            "fused": dict(self.fused),
            "refused": dict(self.refused),
            "last_sigma_m": None if self.last_sigma_m is None else round(self.last_sigma_m, 4),
            "match_ms_mean": round(1e3 * self.match_seconds / self.attempts, 2) if self.attempts else None,
            "correction_max_m": round(max(self.corrections_m), 4) if self.corrections_m else None,
            "height_correction_max_m": self._largest(self.height_corrections_m),
            "heading_correction_max_deg": self._largest(self.heading_corrections_deg),
            "drift_rate_m_per_m": round(self.drift_rate_m_per_m, 5),
            "fleet_ties": self.fleet_ties,
        }


def _plus(
    f: Callable[[np.ndarray], np.ndarray] | None, c: float
) -> Callable[[np.ndarray], np.ndarray] | None:
    """x -> f(x) + c (None without f)."""
    return None if f is None else (lambda x: f(x) + c)


def _sigma_xy(P: np.ndarray) -> float:
    """σ of the position along its worst horizontal direction [m] (the larger eigenvalue of P[6:8, 6:8])."""
    a, b, d = float(P[6, 6]), float(P[6, 7]), float(P[7, 7])
    return float(np.sqrt(max(0.5 * (a + d) + np.hypot(0.5 * (a - d), b), 0.0)))


@njit(cache=True, nogil=True)
def _due_feet(
    contact: np.ndarray, since: np.ndarray, taken: np.ndarray, t: float, settle_s: float, due: np.ndarray
) -> int:
    """Feet whose contact has lasted `settle_s` and whose stance gave no foothold yet, into `due` (4,); how
    many. `since` (4,) each contact's start [s] (inf without contact) and `taken` (4,) (this stance's foothold
    is in the track) are updated in place (compiled: every tick)."""
    n = 0
    for i in range(4):
        since[i] = min(since[i], t) if contact[i] else np.inf
        taken[i] = taken[i] and contact[i]
        due[i] = contact[i] and not taken[i] and t - since[i] >= settle_s
        n += due[i]
    return n


def search_config(c: LocalizerConfig, src: SourceConfig, sig_xy_m: float, sig_yaw_deg: float) -> MatchConfig:
    """The source's match configuration with its search window sized by the filter's own σ: position ±3σ
    (+ a step), heading ±3σ, within the source's limits; at least `yaw_steps` heading candidates a side, and
    steps fine enough that the track's far end moves no more than two position steps between them (a long
    DEM track turned by a coarse step lands nowhere near the relief it crossed)."""
    mc = src.match
    win = float(np.clip(c.window_sigmas * sig_xy_m + mc.step_m, 3 * mc.step_m, mc.window_m))
    ywin = float(np.clip(c.window_sigmas * sig_yaw_deg, 0.5, mc.yaw_window_deg))
    ystep = min(ywin / c.yaw_steps, float(np.degrees(2.0 * mc.step_m / max(src.track_m, 1.0))))
    return replace(mc, window_m=win, yaw_window_deg=ywin, yaw_step_deg=ywin / np.ceil(ywin / ystep))


class Localizer:
    def __init__(
        self,
        estimator: StateEstimator,
        config: LocalizerConfig = LocalizerConfig(),
        dem: HeightReference | None = None,
        map_source: MapSource | None = None,
        feet: PinocchioFeet | None = None,
    ) -> None:
        self.est = estimator
        self.config = config
        self.dem = dem
        self.map_source = map_source
        self.feet = feet or estimator.feet
        keep = max(config.dem.track_m if dem else 0.0, config.map.track_m if map_source else 0.0)
        self.track = FootholdTrack(keep_m=keep + 1.0)
        self.report = LocalizerReport(sources=tuple(n for n, r in (("dem", dem), ("map", map_source)) if r))
        self._since = np.full(4, np.inf)
        self._taken = np.zeros(4, bool)
        self._due = np.zeros(4, bool)
        self.walked_m = 0.0
        # each source's first match once its track is full
        self._next = {n: src.first_m if src.first_m is not None else src.track_m
                      for n, src in (("dem", config.dem), ("map", config.map))}  # fmt: skip
        self._prev_xy: tuple[float, float] | None = None
        self._tried = {"dem": 0.0, "map": 0.0}  # distance walked at each source's last attempt [m]
        self._height_at = {"dem": -np.inf, "map": -np.inf}  # ... at its last fused height fix [m]
        self._dem_new_from = 0.0  # footholds placed from here on [m walked] are new to the DEM place fix
        self.drift_rate = 0.0  # the height drift per metre walked taken off the estimate [m/m]
        self.drift_step_m = 0.0  # what the last tick took off the estimate's height for it [m]
        self.drift_rate_var = config.drift_rate_sigma**2  # its variance [(m/m)²]
        # the datum along the walk behind the last fused DEM fix (`HeightTrack.last_profile`), for the mapper's
        # held samples (holding.PoseFix.height_profile); the run loop takes it with the fix
        self.height_profile: Callable[[np.ndarray], np.ndarray] | None = None
        # ... and its variance there with the DEM's vertical bias (holding.PoseFix.height_profile_var): the
        # held footholds' vertical σ, what the map's height layer states and the others' height fixes add
        self.height_profile_var: Callable[[np.ndarray], np.ndarray] | None = None
        self.heights = (
            HeightTrack(config.height_track)
            if config.height_track is not None and isinstance(dem, DemReference)
            else None
        )
        self._tied: set[int] = set()  # pieces of walk (fleet_ties.py) whose datum the shared map measured

    def on_tick(self, sample: ProprioSample) -> None:
        c = self.config
        t = sample.t
        due = self._due
        est = self.est.ekf
        if _due_feet(np.asarray(sample.contact, bool), self._since, self._taken, t, c.settle_s, due):
            fb, _ = self.feet.feet_base_and_vel(sample.q, sample.dq)
            pts = fb[due] @ est.R.T + est.p
            pts[:, 2] -= C.FOOT_RADIUS
            self.track.add(pts, self.walked_m)
            if self.heights is not None:
                self.heights.add(pts, self.walked_m, _sigma_xy(est.P))
            self._taken |= due
        x, y = float(est.p[0]), float(est.p[1])
        if self._prev_xy is not None:
            step = float(np.hypot(x - self._prev_xy[0], y - self._prev_xy[1]))
            self.walked_m += step
            self.drift_step_m = self.drift_rate * step
            est.p[2] -= self.drift_step_m
        self._prev_xy = (x, y)
        for name in self.report.sources:
            if self.walked_m >= self._next[name]:
                self._next[name] = self.walked_m + getattr(c, name).every_m
                self.localize(name)

    def finish(self, min_track_m: float = 15.0, min_m: float = 5.0) -> None:
        """At the walk's end: one more attempt per source, over at least `min_track_m` of track, if `min_m`
        or more was walked since its last attempt, so the last stretch's footholds, held for the next fix, do
        not leave uncorrected (and a walk shorter than the first match's track gets one fix at all). The other
        scouts' cells under the stretch still held join the DEM's whole-walk fit first (`_tie_to_fleet`); if
        they added a tie and no DEM attempt is due, the whole-walk height is fitted again with them."""
        tied = self._tie_to_fleet()
        for name in self.report.sources:
            if self.walked_m >= min_track_m and self.walked_m - self._tried[name] >= min_m:
                self.localize(name)
                tied = tied if name != "dem" else 0
        if tied and self.heights is not None and isinstance(self.dem, DemReference):
            self._fuse_walk_height(self.config.dem)

    def _tie_to_fleet(self) -> int:
        """The other scouts' cells under the pieces of walk still held and not yet tied (`fleet_ties`), each
        a point measurement of the datum for the DEM's whole-walk fit (`HeightTrack.add_point`); how many."""
        c = self.config.fleet_tie
        if c is None or self.heights is None or self.map_source is None:
            return 0
        length = min(c.span_m, self.track.keep_m)
        pts = self.track.window(length, self.walked_m)
        walked = self.track.walked(length, self.walked_m)
        ties = fleet_ties(pts, walked, self.walked_m, self.map_source, _sigma_xy(self.est.ekf.P), c,
                          self.config.map.match, skip=self._tied.__contains__)  # fmt: skip
        for tie in ties:
            self.heights.add_point(tie.walked_m, tie.dz_m, tie.var_m2 + self.config.map.datum_m**2)
            self._tied.add(tie.piece)
        self.report.fleet_ties += len(ties)
        return len(ties)

    def _mark_tied(self, track_m: float) -> None:
        """The pieces at least half inside the last `track_m` walked (a map fix just measured their datum from
        the same cells) need no fleet tie."""
        c = self.config.fleet_tie
        if c is not None:
            a, b = max(self.walked_m - track_m, 0.0), self.walked_m
            for k in range(int(np.floor(a / c.piece_m)), int(np.floor(b / c.piece_m)) + 1):
                if min(b, (k + 1) * c.piece_m) - max(a, k * c.piece_m) >= 0.5 * c.piece_m:
                    self._tied.add(k)

    def _learn_drift_rate(self, fix: HeightFix, share: float) -> None:
        """The track's slope of reference minus footholds per metre walked (`HeightFix.rate_data`) is the drift
        rate left after what is already taken off, with a sign change: a scalar Kalman update of
        `drift_rate`, its variance × `share` (consecutive tracks share footholds), χ²-gated (p = gate_p)."""
        if not self.config.drift_rate_sigma or not np.isfinite(fix.rate_data_var):
            return
        var = fix.rate_data_var * share
        innov = -fix.rate_data
        if innov**2 / (self.drift_rate_var + var) > float(chi2.ppf(1.0 - self.config.gate_p, 1)):
            return
        k = self.drift_rate_var / (self.drift_rate_var + var)
        self.drift_rate += k * innov
        self.drift_rate_var *= 1.0 - k
        self.report.drift_rate_m_per_m = self.drift_rate

    def _reference(self, name: str, pts: np.ndarray) -> HeightReference | None:
        if name == "dem":
            return self.dem
        if self.map_source is None or not len(pts):
            return None
        lo, hi = pts[:, :2].min(0), pts[:, :2].max(0)
        mid = (lo + hi) / 2
        return self.map_source(float(mid[0]), float(mid[1]), float(np.hypot(*(hi - lo)) / 2 + 2.0))

    def localize(self, name: str) -> MatchResult | None:
        """One attempt against reference `name` ("dem" or "map") now; returns the fused match, or None."""
        c, ekf = self.config, self.est.ekf
        src: SourceConfig = getattr(c, name)
        w0 = time.perf_counter()
        self.report.attempts += 1
        pts = self.track.window(src.track_m, self.walked_m)
        self._tried[name] = self.walked_m
        ref = self._reference(name, pts)
        fused = None
        batch = name == "dem" and self.heights is not None  # the DEM's height from the whole walk
        if ref is None:
            self.report.refused[f"no_{name}"] += 1
        elif isinstance(ref, DemReference):  # place and heading (trail.py), then the height
            self._dem_fix(ref)
            if batch:
                self._tie_to_fleet()
                self._fuse_walk_height(src)
            elif src.height_fix and self.walked_m - self._height_at[name] >= src.height_every_m:
                sig_xy = float(np.sqrt(max(np.linalg.eigvalsh(ekf.P[6:8, 6:8]).max(), 0.0)))
                self._fuse_height(name, pts, ref, src, sig_xy)
        else:
            sig_xy = float(np.sqrt(max(np.linalg.eigvalsh(ekf.P[6:8, 6:8]).max(), 0.0)))
            sig_yaw = float(np.degrees(np.sqrt(max(ekf.P[2, 2], 0.0))))
            # the others' cells are where their own estimates put them: the search (within the source's window)
            # and a height fix's averaging over the places allowed cover both placements
            place = ref.place_var(pts[:, 0], pts[:, 1]) if isinstance(ref, GridReference) else 0.0
            sig_rel = float(np.sqrt(sig_xy**2 + place))
            res = match_track(pts, ref, search_config(c, src, sig_rel, sig_yaw), pivot=ekf.p[:2])
            if not res.ok:
                self.report.refused[f"{name}_{res.reason}"] += 1
                if src.height_fix and res.reason in src.height_fix_on and not batch:
                    if self.walked_m - self._height_at[name] >= src.height_every_m:
                        self._fuse_height(name, pts, ref, src, sig_rel)
            else:
                assert res.cov is not None
                cov = res.cov.copy()
                cov[2, 2] = np.inf if batch else cov[2, 2] + src.datum_m**2
                if isinstance(ref, GridReference):  # the others' placement, datum and heading: their frame
                    cov[0, 0] += place
                    cov[1, 1] += place
                    cov[2, 2] += ref.datum_var(pts[:, 0], pts[:, 1])
                cov[3, 3] += np.radians(src.frame_yaw_sigma_deg) ** 2
                cov *= max(1.0, min(src.track_m, self.walked_m) / src.every_m)  # footholds shared
                meas = np.r_[
                    ekf.p[0] + res.dx, ekf.p[1] + res.dy, ekf.p[2] + res.dz, heading(ekf.R) + res.dyaw
                ]
                k = int(np.isfinite(np.diag(cov)).sum())
                before = ekf.p.copy()
                up = update_pose(ekf, meas, cov, float(chi2.ppf(1.0 - c.gate_p, k)))
                if up.accepted:
                    if name == "map" and self.heights is not None:  # the DEM's next fix keeps this datum
                        self.heights.add_point(self.walked_m, res.dz, float(cov[2, 2]))
                        self._mark_tied(src.track_m)
                    self._shift(before, float(up.correction[3]))
                    self.report.fused[name] += 1
                    self.report.corrections_m.append(float(np.hypot(*up.correction[:2])))
                    fused = res
                else:
                    self.report.refused[f"{name}_gate"] += 1
            if batch:
                self._fuse_walk_height(src)
        self.report.last_sigma_m = float(np.sqrt(max(np.linalg.eigvalsh(ekf.P[6:8, 6:8]).max(), 0.0)))
        self.report.match_seconds += time.perf_counter() - w0
        return fused

    def _shift(self, before: np.ndarray, dyaw: float) -> None:
        """Move what the localizer holds of the walk as the correction just fused moved the estimate."""
        after = self.est.ekf.p.copy()
        self.track.shift(before, after, dyaw)
        if self.heights is not None:
            self.heights.shift(before, after, dyaw)

    def _fuse_walk_height(self, src: SourceConfig) -> None:
        """The DEM's datum from the whole walk (`HeightTrack.fix`) replaces what the filter knew of its height:
        it holds every foothold since launch and the shared map's height fixes, so fusing it as one more
        independent measurement would count them again. The filter's height is set to the fix's mean and
        variance (+ the DEM's vertical bias) by the one measurement whose update yields exactly those (its
        noise R = P·V/(P − V), its value offset by the gain); none where the filter already knows its height
        as well (V ≥ P: nothing new since the last). χ²-gated on the difference of the two estimates
        (d²/(P − V)); counted as fused / refused under "dem_height"."""
        assert self.heights is not None and isinstance(self.dem, DemReference)
        fix = self.heights.fix(self.dem.dem, self.dem.subpixel_m, self.walked_m)
        if fix is None:
            self.report.refused["dem_height_few"] += 1
            return
        ekf = self.est.ekf
        P0 = float(ekf.P[8, 8])
        V = fix.var_m2 + src.datum_m**2
        if not V < 0.98 * P0:
            self.report.refused["dem_height_known"] += 1
            return
        R = P0 * V / (P0 - V)
        gain = P0 / (P0 + R)
        meas = np.array([np.nan, np.nan, ekf.p[2] + fix.dz / gain, np.nan])
        before = ekf.p.copy()
        up = update_pose(ekf, meas, np.diag([np.inf, np.inf, R, np.inf]),
                         float(chi2.ppf(1.0 - self.config.gate_p, 1)))  # fmt: skip
        if up.accepted:
            self.height_profile = self.heights.last_profile  # computed in the frame before this correction
            self.height_profile_var = _plus(self.heights.last_profile_var, src.datum_m**2)
            self._shift(before, float(up.correction[3]))
            self.report.fused["dem_height"] += 1
            self._height_at["dem"] = self.walked_m
            self.report.height_corrections_m.append(float(up.correction[2]))
        else:
            self.report.refused["dem_height_gate"] += 1

    def _dem_fix(self, ref: DemReference) -> TrailFix:
        """The DEM's place and heading fix (`match_trail`) of the footholds walked since the last fused one,
        against the filter's own (x, y, heading) covariance, fused as a pose measurement without its height
        (χ²-gated, 3 dof); counted under "dem" (fused) or "dem_<reason>" / "dem_gate" (refused)."""
        c, ekf = self.config, self.est.ekf
        length = max(c.dem_trail_m, self.walked_m - self._dem_new_from)
        pts = self.track.window(length, self.walked_m)
        walked = self.track.walked(length, self.walked_m)
        H = np.zeros((3, 15))
        H[0, 6] = H[1, 7] = 1.0
        H[2, 0:3] = heading_row(ekf.R)
        prior = H @ ekf.P @ H.T
        fix = match_trail(pts, walked, ref, prior, ekf.p[:2], self._dem_new_from, c.dem_trail)
        if not fix.ok:
            self.report.refused[f"dem_{fix.reason}"] += 1
            return fix
        assert fix.offset is not None and fix.cov is not None
        meas = np.r_[
            ekf.p[0] + fix.offset[0], ekf.p[1] + fix.offset[1], np.nan, heading(ekf.R) + fix.offset[2]
        ]
        cov = np.zeros((4, 4))
        cov[np.ix_([0, 1, 3], [0, 1, 3])] = fix.cov
        cov[2, 2] = np.inf
        before = ekf.p.copy()
        up = update_pose(ekf, meas, cov, float(chi2.ppf(1.0 - c.gate_p, 3)))
        if not up.accepted:
            self.report.refused["dem_gate"] += 1
            return fix
        self._shift(before, float(up.correction[3]))
        self._dem_new_from = self.walked_m
        self.report.fused["dem"] += 1
        self.report.corrections_m.append(float(np.hypot(*up.correction[:2])))
        self.report.heading_corrections_deg.append(float(np.degrees(up.correction[3])))
        return fix

    def _fuse_height(
        self, name: str, pts: np.ndarray, ref: HeightReference, src: SourceConfig, sig_xy: float
    ) -> None:
        """The height alone from `ref` (`match_height`), χ²-gated with one degree of freedom; counted as
        fused / refused under "<name>_height"."""
        walked = self.track.walked(src.track_m, self.walked_m) if src.height_rate_sigma > 0 else None
        fix = match_height(pts, ref, sig_xy, src.match, walked, src.height_rate_sigma)
        if fix is None:
            self.report.refused[f"{name}_height_few"] += 1
            return
        ekf = self.est.ekf
        share = max(1.0, min(src.track_m, self.walked_m) / max(src.every_m, src.height_every_m))
        # the reference's own datum where it states one per cell (the shared map: the other scouts' vertical σ)
        datum_var = ref.datum_var(pts[:, 0], pts[:, 1]) if isinstance(ref, GridReference) else 0.0
        var = (fix.var_m2 + src.datum_m**2) * share + datum_var
        meas = np.array([np.nan, np.nan, ekf.p[2] + fix.dz, np.nan])
        cov = np.diag([np.inf, np.inf, var, np.inf])
        before = ekf.p.copy()
        up = update_pose(ekf, meas, cov, float(chi2.ppf(1.0 - self.config.gate_p, 1)))
        if up.accepted:
            if self.heights is not None:  # the DEM's next fix keeps what this one said
                self.heights.add_point(self.walked_m, fix.dz, var)
                if name == "map":
                    self._mark_tied(src.track_m)
            self._shift(before, float(up.correction[3]))
            self.report.fused[f"{name}_height"] += 1
            self._height_at[name] = self.walked_m
            self.report.height_corrections_m.append(float(up.correction[2]))
            self._learn_drift_rate(fix, share)
        else:
            self.report.refused[f"{name}_height_gate"] += 1
