"""Rerun logging for a scout (the only module of scout_agent that imports rerun).

One explicit `rr.RecordingStream` is passed in; entity paths mirror the system:
`world/terrain`, `world/friction`, `world/scouts/<id>/{base,feet,trajectory,trajectory_estimate,slips}`, and
time series grouped by unit (one plot per unit; series named after the scout, foot or joint):
`world/scouts/<id>/series/<group>` — see `SERIES`. Everything is on `sim_time` (psrmap_common.recording).
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from psrmap_common.recording import TIMELINE, open_stream, scout_color
from scout_agent.signals import JOINT_NAMES, LEG_NAMES, GroundTruth, ProprioSample
from scout_agent.sim.friction import FrictionMap
from scout_agent.sim.terrain import Terrain

# series group -> (title with unit, series names; "{id}" is the scout id). One entity per group and scout,
# one plot per group in the default blueprint.
SERIES: dict[str, tuple[str, tuple[str, ...]]] = {
    "speed_mps": ("speed [m/s]", ("{id} true", "{id} estimate")),
    "drift_m": ("state-estimate drift [m]", ("{id} horizontal", "{id} vertical")),
    "foot_pressure_n": ("foot pressure [N]", tuple(f"{{id}} {leg}" for leg in LEG_NAMES)),
    "stance_disp_m": ("stance foot displacement (truth) [m]", tuple(f"{{id}} {leg}" for leg in LEG_NAMES)),
    "joint_torque_nm": ("joint torque [N·m]", tuple("{id} " + j.removesuffix("_joint") for j in JOINT_NAMES)),
    "slip_dv_mps": (
        "slip ΔV and threshold ε_v [m/s]",
        (*(f"{{id}} ΔV {leg}" for leg in LEG_NAMES), "{id} ε_v"),
    ),
    "cot": ("running cost of transport [1]", ("{id}",)),
    "giim_rad": ("GIIM [rad]", ("{id}",)),
    "giam_mps2": ("GIAM [m/s²]", ("{id}",)),
    "nonfoot_contacts": ("non-foot contacts [count]", ("{id}",)),
}


def open_recording(path: str | None) -> rr.RecordingStream:
    """A recording saved to `path` (and streamed to the live viewer if `PSRMAP_VIEWER_URL` names one), in
    the mission's recording (`PSRMAP_RECORDING_ID`) if set."""
    return open_stream(path)


def log_terrain(rec: rr.RecordingStream, terrain: Terrain, step: int = 2) -> None:
    """The terrain as a static triangle mesh (every `step`-th grid sample), coloured by slope; z up."""
    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
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
    rec.log(
        "world/terrain",
        rr.Mesh3D(vertex_positions=verts, triangle_indices=tris, vertex_colors=colors),
        static=True,
    )


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


def _lighter(rgb: tuple[int, int, int], k: float = 0.55) -> list[int]:
    return [round(c + (255 - c) * k) for c in rgb]


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
            self.rec.send_columns(
                path, indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(ts))], columns=cols
            )
            ts.clear()
            self.v[path].clear()


class ScoutLogger:
    """Logs one scout: pose (a box in the scout's colour, labelled with its id), feet and contacts, the true
    trajectory (scout colour) beside the scout's own estimate of it (lighter), slip events, and time series
    grouped by unit (`SERIES`), sampled every `every` control ticks and sent in columns every `flush_every_s`
    (one Rerun call per entity per flush: a `log` call costs ~0.5 ms); the trail every `trail_every_s`.

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
        self.id = scout_id
        self.root = f"world/scouts/{scout_id}"
        self.color = scout_color(scout_id)
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
        self._hazards: list[tuple[list[float], str]] = []
        self._work = 0.0
        self._dist = 0.0
        self._t = 0.0
        self._static_logged = False
        self._pose_t: list[float] = []
        self._pose: list[np.ndarray] = []
        self._quat: list[list[float]] = []
        self._feet: list[np.ndarray] = []
        self._contact: list[np.ndarray] = []

    def _series(self, group: str) -> str:
        return f"{self.root}/series/{group}"

    def _log_static(self) -> None:
        """What never changes: the body box, the feet's size, every series' name and colour."""
        rec, root = self.rec, self.root
        rec.log(
            f"{root}/base/body",
            rr.Boxes3D(
                half_sizes=[[0.32, 0.075, 0.056]], colors=[self.color], labels=[self.id], show_labels=True
            ),
            static=True,
        )
        rec.log(f"{root}/feet", rr.Points3D.from_fields(radii=[0.03] * 4), static=True)
        for group, (_, names) in SERIES.items():
            rec.log(
                self._series(group), rr.SeriesLines(names=[n.format(id=self.id) for n in names]), static=True
            )
        self._static_logged = True

    def log_tick(self, sample: ProprioSample, truth: GroundTruth) -> None:
        self._k += 1
        if self._k % self.every:
            return
        t = truth.t
        self._t = t
        b = truth.base
        self._traj.append(b.pos.copy())
        self._traj_est.append(sample.base.pos.copy())
        self._pose_t.append(t)
        self._pose.append(b.pos.copy())
        self._quat.append([b.quat[1], b.quat[2], b.quat[3], b.quat[0]])  # xyzw
        self._feet.append(truth.foot_pos_world.copy())
        self._contact.append(sample.contact.copy())
        add, s = self.series.add, self._series
        add(s("speed_mps"), t, [float(np.hypot(*b.vel[:2])), float(np.hypot(*sample.base.vel[:2]))])
        add(
            s("drift_m"),
            t,
            [float(np.hypot(*(sample.base.pos[:2] - b.pos[:2]))), float(sample.base.pos[2] - b.pos[2])],
        )
        add(s("foot_pressure_n"), t, sample.foot_pressure)
        add(s("stance_disp_m"), t, np.nan_to_num(truth.stance_disp))
        add(s("nonfoot_contacts"), t, float(truth.nonfoot_contacts))
        add(s("joint_torque_nm"), t, sample.tau)
        if t >= self._next_trail:
            self._next_trail = t + self.trail_every_s
            self.rec.set_time(TIMELINE, duration=t)
            self._log_trail()
        if t >= self._next_flush:
            self._next_flush = t + self.flush_every_s
            self._flush()

    def _flush(self) -> None:
        """Send the buffered poses, feet and time series, one `send_columns` call per entity."""
        if not self._static_logged:
            self._log_static()
        if self._pose_t:
            rec, root, n = self.rec, self.root, len(self._pose_t)
            time = [rr.TimeColumn(TIMELINE, duration=np.asarray(self._pose_t))]
            rec.send_columns(
                f"{root}/base",
                indexes=time,
                columns=rr.Transform3D.columns(
                    translation=np.asarray(self._pose), quaternion=np.asarray(self._quat)
                ),
            )
            colors = np.where(np.asarray(self._contact).reshape(-1, 1), _IN_CONTACT, _IN_SWING).astype(
                np.uint8
            )
            rec.send_columns(
                f"{root}/feet",
                indexes=time,
                columns=rr.Points3D.columns(
                    positions=np.asarray(self._feet).reshape(-1, 3), colors=colors
                ).partition(lengths=[4] * n),
            )
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
        t, add, s = est.t, self.series.add, self._series
        add(
            s("slip_dv_mps"), t, [*np.nan_to_num(np.asarray(est.slip.dv, dtype=float)), float(est.slip.eps_v)]
        )
        if self._dist > 0.05:
            add(s("cot"), t, self._work / self._dist)
        if np.isfinite(est.giim):
            add(s("giim_rad"), t, float(est.giim))
            add(s("giam_mps2"), t, float(est.giam))

    def log_hazard(self, felt) -> None:
        """A hazard stop (`control.reflex.Felt`): a labelled marker where the reflex felt it."""
        self.rec.set_time(TIMELINE, duration=felt.t)
        z = float(self.height(felt.x, felt.y)) + 0.05 if self.height is not None else 0.0
        self._hazards.append(([felt.x, felt.y, z], f"{self.id}: {','.join(felt.reasons)}"))
        self.rec.log(
            f"{self.root}/hazards",
            rr.Points3D(
                [p for p, _ in self._hazards],
                radii=0.15,
                colors=[255, 140, 0],
                labels=[label for _, label in self._hazards],
                show_labels=True,
            ),
        )

    def _log_trail(self) -> None:
        """The true trajectory (scout colour) and the scout's estimate of it (lighter), side by side."""
        if len(self._traj) > 1:
            self.rec.log(
                f"{self.root}/trajectory",
                rr.LineStrips3D([np.array(self._traj)], colors=[self.color], labels=[self.id]),
            )
            self.rec.log(
                f"{self.root}/trajectory_estimate",
                rr.LineStrips3D([np.array(self._traj_est)], colors=[_lighter(self.color)]),
            )

    def finish(self) -> None:
        self.rec.set_time(TIMELINE, duration=self._t)
        self._log_trail()
        self._flush()
