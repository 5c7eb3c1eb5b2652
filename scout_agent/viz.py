"""Rerun logging for a scout (the only module of scout_agent that imports rerun).

One explicit `rr.RecordingStream` is passed in; entity paths mirror the system:
`world/terrain`, `world/friction`, `world/scouts/<id>/{base,feet,trajectory,signals/…}`.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from protocol.recording import APP_ID, recording_id
from scout_agent.signals import LEG_NAMES, GroundTruth, ProprioSample
from scout_agent.sim.friction import FrictionMap
from scout_agent.sim.terrain import Terrain

TIMELINE = "sim_time"


def open_recording(path: str, app_id: str = APP_ID) -> rr.RecordingStream:
    """A recording that streams to an .rrd file, in the mission's recording (`PSRMAP_RECORDING_ID`) if set."""
    rec = rr.RecordingStream(app_id, recording_id=recording_id())
    rec.save(path)
    return rec


def log_terrain(rec: rr.RecordingStream, terrain: Terrain, step: int = 2) -> None:
    """The terrain as a static triangle mesh (every `step`-th grid sample), coloured by slope."""
    z = terrain.z[::step, ::step]
    ny, nx = z.shape
    xa, ya, _, _ = terrain.extent
    xs = xa + np.arange(nx) * terrain.res * step
    ys = ya + np.arange(ny) * terrain.res * step
    X, Y = np.meshgrid(xs, ys)
    verts = np.stack([X.ravel(), Y.ravel(), z.ravel()], axis=1).astype(np.float32)
    idx = np.arange(ny * nx).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.uint32)
    slope = terrain.slope_deg(X.ravel(), Y.ravel())
    shade = np.clip(1.0 - slope / 40.0, 0.2, 1.0)
    colors = (np.stack([shade * 0.75, shade * 0.75, shade * 0.72], 1) * 255).astype(np.uint8)
    rec.log("world/terrain", rr.Mesh3D(vertex_positions=verts, triangle_indices=tris, vertex_colors=colors),
            static=True)


def log_friction(rec: rr.RecordingStream, friction: FrictionMap, terrain: Terrain) -> None:
    """Friction patches as labelled rectangles draped slightly above the terrain."""
    strips, labels = [], []
    for p in friction.patches:
        xs = np.array([p.x0, p.x1, p.x1, p.x0, p.x0])
        ys = np.array([p.y0, p.y0, p.y1, p.y1, p.y0])
        strips.append(np.stack([xs, ys, terrain.height(xs, ys) + 0.03], 1))
        labels.append(f"μ {p.mu:.2f}")
    if strips:
        rec.log("world/friction", rr.LineStrips3D(strips, labels=labels, colors=[80, 160, 255]), static=True)


_IN_CONTACT = np.array([40, 220, 40, 255])
_IN_SWING = np.array([200, 200, 200, 255])


class _Series:
    """Scalar time series buffered per entity and sent with `send_columns` (one chunk per flush, not one
    log call per sample)."""

    def __init__(self, rec: rr.RecordingStream) -> None:
        self.rec = rec
        self.t: dict[str, list[float]] = {}
        self.v: dict[str, list] = {}

    def add(self, path: str, t: float, value) -> None:
        self.t.setdefault(path, []).append(t)
        self.v.setdefault(path, []).append(value)

    def flush(self) -> None:
        for path, ts in self.t.items():
            if not ts:
                continue
            vals = np.asarray(self.v[path], dtype=float)
            cols = rr.Scalars.columns(scalars=vals.ravel())
            if vals.ndim == 2:
                cols = cols.partition(lengths=[vals.shape[1]] * len(ts))
            self.rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(ts))], columns=cols)
            ts.clear()
            self.v[path].clear()


class ScoutLogger:
    """Logs one scout: pose, feet and contacts, signals and the estimators' outputs (ΔV, ε_v, running CoT,
    GIIM, GIAM), sampled every `every` control ticks and sent in columns every `flush_every_s` (one Rerun
    call per entity per flush: a `log` call costs ~0.5 ms); the trail every `trail_every_s`; slip events as
    they happen.

    `height(x, y)` (optional, e.g. the terrain's) only places slip-event markers on the ground for display."""

    def __init__(
        self,
        rec: rr.RecordingStream,
        scout_id: str,
        every: int = 5,
        height=None,
        trail_every_s: float = 2.0,
        flush_every_s: float = 1.0,
    ) -> None:
        self.rec = rec
        self.root = f"world/scouts/{scout_id}"
        self.every = every
        self.height = height
        self.trail_every_s = trail_every_s
        self.flush_every_s = flush_every_s
        self.series = _Series(rec)
        self._k = 0
        self._ke = 0
        self._traj: list[np.ndarray] = []
        self._traj_est: list[np.ndarray] = []  # the scout's own estimate of where it walked
        self._next_trail = 0.0
        self._next_flush = 0.0
        self._slips: list[list[float]] = []
        self._work = 0.0
        self._dist = 0.0
        self._t = 0.0
        self._static_logged = False
        self._pose_t: list[float] = []
        self._pose: list[np.ndarray] = []
        self._quat: list[list[float]] = []
        self._feet: list[np.ndarray] = []
        self._contact: list[np.ndarray] = []

    def log_tick(self, sample: ProprioSample, truth: GroundTruth) -> None:
        self._k += 1
        if self._k % self.every:
            return
        root, t = self.root, truth.t
        self._t = t
        b = truth.base
        self._traj.append(b.pos.copy())
        self._traj_est.append(sample.base.pos.copy())
        self._pose_t.append(t)
        self._pose.append(b.pos.copy())
        self._quat.append([b.quat[1], b.quat[2], b.quat[3], b.quat[0]])  # xyzw
        self._feet.append(truth.foot_pos_world.copy())
        self._contact.append(sample.contact.copy())
        sig, add = f"{root}/signals", self.series.add
        add(f"{sig}/speed_mps", t, float(np.hypot(*b.vel[:2])))
        add(f"{sig}/speed_estimate_mps", t, float(np.hypot(*sample.base.vel[:2])))
        add(f"{sig}/drift_xy_m", t, float(np.hypot(*(sample.base.pos[:2] - b.pos[:2]))))
        add(f"{sig}/drift_z_m", t, float(sample.base.pos[2] - b.pos[2]))
        add(f"{sig}/foot_pressure_n", t, sample.foot_pressure)
        add(f"{sig}/stance_disp_m", t, np.nan_to_num(truth.stance_disp))
        add(f"{sig}/nonfoot_contacts", t, float(truth.nonfoot_contacts))
        add(f"{sig}/tau", t, sample.tau)
        if t >= self._next_trail:
            self._next_trail = t + self.trail_every_s
            self.rec.set_time(TIMELINE, duration=t)
            self._log_trail()
        if t >= self._next_flush:
            self._next_flush = t + self.flush_every_s
            self._flush()

    def _flush(self) -> None:
        """Send the buffered poses, feet and time series, one `send_columns` call per entity."""
        if self._pose_t:
            rec, root, n = self.rec, self.root, len(self._pose_t)
            if not self._static_logged:  # what rides on the base and never changes: once
                rec.log(f"{root}/base/body", rr.Boxes3D(half_sizes=[[0.32, 0.075, 0.056]], colors=[230, 115, 25]),
                        static=True)
                rec.log(f"{root}/feet", rr.Points3D.from_fields(radii=[0.03] * 4, labels=list(LEG_NAMES)),
                        static=True)
                self._static_logged = True
            time = [rr.TimeColumn(TIMELINE, duration=np.asarray(self._pose_t))]
            rec.send_columns(f"{root}/base", indexes=time, columns=rr.Transform3D.columns(
                translation=np.asarray(self._pose), quaternion=np.asarray(self._quat)))
            colors = np.where(np.asarray(self._contact).reshape(-1, 1), _IN_CONTACT, _IN_SWING).astype(np.uint8)
            rec.send_columns(f"{root}/feet", indexes=time, columns=rr.Points3D.columns(
                positions=np.asarray(self._feet).reshape(-1, 3), colors=colors).partition(lengths=[4] * n))
            for buf in (self._pose_t, self._pose, self._quat, self._feet, self._contact):
                buf.clear()
        self.series.flush()

    def log_estimates(self, est) -> None:
        """One tick of `scout_agent.estimators.TickEstimates` (after `log_tick` of the same tick)."""
        self._work += est.work_m
        self._dist += est.dist_m
        if any(est.slip.event) and len(est.slip_xy):
            self.rec.set_time(TIMELINE, duration=est.t)
            for x, y in np.asarray(est.slip_xy, dtype=float).reshape(-1, 2):
                z = float(self.height(x, y)) + 0.02 if self.height is not None else 0.0
                self._slips.append([float(x), float(y), z])
            self.rec.log(f"{self.root}/slips", rr.Points3D(self._slips, radii=0.05, colors=[255, 40, 40]))
        self._ke += 1
        if self._ke % self.every:
            return
        root, t, add = f"{self.root}/estimates", est.t, self.series.add
        add(f"{root}/dv", t, np.nan_to_num(np.asarray(est.slip.dv, dtype=float)))
        add(f"{root}/eps_v", t, float(est.slip.eps_v))
        if self._dist > 0.05:
            add(f"{root}/cot_running", t, self._work / self._dist)
        if np.isfinite(est.giim):
            add(f"{root}/giim_rad", t, float(est.giim))
            add(f"{root}/giam_mps2", t, float(est.giam))

    def _log_trail(self) -> None:
        """The true trajectory (red) and the scout's estimate of it (cyan), side by side."""
        if len(self._traj) > 1:
            self.rec.log(f"{self.root}/trajectory", rr.LineStrips3D([np.array(self._traj)], colors=[255, 60, 60]))
            self.rec.log(f"{self.root}/trajectory_estimate",
                         rr.LineStrips3D([np.array(self._traj_est)], colors=[40, 200, 230]))

    def finish(self) -> None:
        self.rec.set_time(TIMELINE, duration=self._t)
        self._log_trail()
        self._flush()
