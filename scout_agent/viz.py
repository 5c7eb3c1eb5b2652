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


class ScoutLogger:
    """Logs one scout: pose, feet and contacts, signals every `every` control ticks; the trail every
    `trail_every_s`; the estimators' outputs (ΔV, ε_v, CoT, GIIM, GIAM) and slip events as they happen.

    `height(x, y)` (optional, e.g. the terrain's) only places slip-event markers on the ground for display."""

    def __init__(
        self,
        rec: rr.RecordingStream,
        scout_id: str,
        every: int = 5,
        height=None,
        trail_every_s: float = 2.0,
    ) -> None:
        self.rec = rec
        self.root = f"world/scouts/{scout_id}"
        self.every = every
        self.height = height
        self.trail_every_s = trail_every_s
        self._k = 0
        self._ke = 0
        self._traj: list[np.ndarray] = []
        self._next_trail = 0.0
        self._slips: list[list[float]] = []
        self._work = 0.0
        self._dist = 0.0
        self._t = 0.0

    def log_tick(self, sample: ProprioSample, truth: GroundTruth) -> None:
        self._k += 1
        if self._k % self.every:
            return
        rec, root = self.rec, self.root
        rec.set_time(TIMELINE, duration=truth.t)
        self._t = truth.t
        b = truth.base
        self._traj.append(b.pos.copy())
        rec.log(f"{root}/base", rr.Transform3D(translation=b.pos, quaternion=rr.Quaternion(
            xyzw=[b.quat[1], b.quat[2], b.quat[3], b.quat[0]])))
        rec.log(f"{root}/base/body", rr.Boxes3D(half_sizes=[[0.32, 0.075, 0.056]], colors=[230, 115, 25]))
        colors = np.where(sample.contact[:, None], [[40, 220, 40]], [[200, 200, 200]])
        rec.log(f"{root}/feet", rr.Points3D(truth.foot_pos_world, radii=0.03, colors=colors,
                                            labels=list(LEG_NAMES)))
        sig = f"{root}/signals"
        rec.log(f"{sig}/speed_mps", rr.Scalars(float(np.hypot(*b.vel[:2]))))
        rec.log(f"{sig}/speed_noisy_mps", rr.Scalars(float(np.hypot(*sample.base.vel[:2]))))
        rec.log(f"{sig}/foot_force_z", rr.Scalars(sample.foot_force_world[:, 2]))
        rec.log(f"{sig}/stance_disp_m", rr.Scalars(np.nan_to_num(truth.stance_disp)))
        rec.log(f"{sig}/nonfoot_contacts", rr.Scalars(float(truth.nonfoot_contacts)))
        rec.log(f"{sig}/tau", rr.Scalars(sample.tau))
        if truth.t >= self._next_trail:
            self._next_trail = truth.t + self.trail_every_s
            self._log_trail()

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
        rec, est_root = self.rec, f"{self.root}/estimates"
        rec.set_time(TIMELINE, duration=est.t)
        dv = np.asarray(est.slip.dv, dtype=float)
        rec.log(f"{est_root}/dv", rr.Scalars(np.nan_to_num(dv)))
        rec.log(f"{est_root}/eps_v", rr.Scalars(float(est.slip.eps_v)))
        if self._dist > 0.05:
            rec.log(f"{est_root}/cot_running", rr.Scalars(self._work / self._dist))
        if np.isfinite(est.giim):
            rec.log(f"{est_root}/giim_rad", rr.Scalars(float(est.giim)))
            rec.log(f"{est_root}/giam_mps2", rr.Scalars(float(est.giam)))

    def _log_trail(self) -> None:
        if len(self._traj) > 1:
            self.rec.log(f"{self.root}/trajectory", rr.LineStrips3D([np.array(self._traj)], colors=[255, 60, 60]))

    def finish(self) -> None:
        self.rec.set_time(TIMELINE, duration=self._t)
        self._log_trail()
