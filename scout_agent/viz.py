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
    """Logs one scout's state every `every` control ticks."""

    def __init__(self, rec: rr.RecordingStream, scout_id: str, every: int = 5) -> None:
        self.rec = rec
        self.root = f"world/scouts/{scout_id}"
        self.every = every
        self._k = 0
        self._traj: list[np.ndarray] = []

    def log_tick(self, sample: ProprioSample, truth: GroundTruth) -> None:
        self._k += 1
        if self._k % self.every:
            return
        rec, root = self.rec, self.root
        rec.set_time(TIMELINE, duration=truth.t)
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

    def finish(self) -> None:
        if self._traj:
            self.rec.log(f"{self.root}/trajectory", rr.LineStrips3D([np.array(self._traj)], colors=[255, 60, 60]),
                         static=True)
