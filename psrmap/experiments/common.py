"""What every experiment shares: a run's spec, the worker that walks and scores it, a cached process pool.

A `RunSpec` names one scout walk completely (scene, terrain seed, noise seed, start, path, friction, time
cap). `run_spec` is the worker: it builds the world, walks it with `scout_agent.evaluate.Evaluator` hooked
into `run_scout`, and returns a picklable dict — the evaluator's scores, ground-truth slip counts, the local
map's cells at 0.4 m, the paper-variant margins per cell, the base track, and the elevation error of the
*same footholds* re-binned at finer cells (the estimators run once; every foothold, stance and sample the
mapper aggregated is logged and re-aggregated at 0.2 and 0.1 m with the same cell code).

`RunPool.run(specs)` runs specs in `spawn` worker processes (2 by default: the machine has 2 cores) under a
tqdm bar and caches each result under `<out>/runs/<key>.pkl`, so `experiment all` walks a run that two
experiments need (e.g. a ramp without patch for `ramps` and `slopes`) only once.
"""

from __future__ import annotations

import hashlib
import json
import math
import multiprocessing as mp
import pickle
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from protocol.layers import LAYERS, cell_center, layer_value
from psrmap.progress import progress
from scout_agent.cells import CellAccumulator, LocalMap

if TYPE_CHECKING:  # types only: the simulator and evaluator load inside the worker that walks
    from scout_agent.evaluate import Evaluator
    from scout_agent.sim.terrain import Terrain

__all__ = [
    "EXTRA_RES",
    "MAP_RES",
    "RunPool",
    "RunSpec",
    "fmean",
    "elevation_errors",
    "fstd",
    "jitter_start",
    "rebin",
    "recording_accumulator",
    "run_spec",
    "write_json",
]

MAP_RES = 0.4  # cell size of the scout's map [m] (the paper's)
EXTRA_RES = (0.2, 0.1)  # finer cells the same footholds are re-binned at [m]
CACHE_VERSION = 1  # bump when what a run returns changes


@dataclass(frozen=True)
class RunSpec:
    """One scout walk. `label` is for humans and is not part of the cache key."""

    scene: str  # "ramps" | "lunar"
    slope_deg: float = 0.0  # ramps: α [deg]
    terrain_seed: int = 0  # lunar terrain (and its slippery patches)
    noise_seed: int = 0  # base-velocity noise of the honest state
    start: tuple[float, ...] | None = None  # x, y [m] (None: the scene's / route's start)
    route: str | None = None  # lunar: named route of LUNAR_ROUTES
    waypoints: tuple[tuple[float, float], ...] | None = None  # explicit path start … goal [m]
    slippery_mu: float | None = None  # ramps: patch over the middle of the down-ramp
    slippery_patches: int = 0  # lunar: seeded patches
    sim_seconds: float | None = None  # cap on simulated time [s]
    res: float = MAP_RES
    sensors: str = "realistic"  # sensor profile (scout_agent.sim.sensors.SENSOR_PROFILES)
    launch: str = "survey"  # start given to the scout (state_estimation.launch.LAUNCH_MODES)
    label: str = field(default="", compare=False)

    def key(self) -> str:
        d = asdict(self)
        d.pop("label")
        d["v"] = CACHE_VERSION
        return hashlib.sha1(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def jitter_start(xy: Sequence[float], seed: int, dx: float = 0.05, dy: float = 0.1) -> tuple[float, float]:
    """The start `xy` moved by a seeded offset in [-dx, dx] × [-dy, dy] [m].

    MuJoCo is deterministic: runs that differ only by the noise seed of the honest base state would repeat
    the same physics. A few centimetres of start offset make repeated runs physically different, as
    repeated traversals in the paper's simulator were.
    """
    rng = np.random.default_rng(10_000 + seed)
    return (round(float(xy[0] + rng.uniform(-dx, dx)), 4), round(float(xy[1] + rng.uniform(-dy, dy)), 4))


# ------------------------------------------------------------------------------------------ the worker


def _run_config(spec: RunSpec):
    from scout_agent.loop import SimConfig
    from scout_agent.run import ScoutRunConfig
    from scout_agent.sim.sensors import SensorConfig
    from scout_agent.state_estimation.launch import LaunchSurvey

    kw: dict[str, Any] = {}
    if spec.waypoints is not None:
        pts = spec.waypoints
        kw.update(start=tuple(pts[0]), via=tuple(tuple(p) for p in pts[1:-1]), goal=tuple(pts[-1]))
    if spec.start is not None:
        kw["start"] = tuple(spec.start)
    return ScoutRunConfig(
        scene=spec.scene,
        slope_deg=spec.slope_deg,
        seed=spec.terrain_seed,
        route=spec.route,
        slippery_mu=spec.slippery_mu,
        slippery_patches=spec.slippery_patches,
        holdable_patches=True,  # the paper's experiments: every patch walkable ...
        # ... walked by the paper-like fixed trot: on these holdable patches the hazard reflex reads creeping
        # slips on shallow slopes as unholdable and stops (docs/results.md, issue 24), cutting the walks short
        hazard_control=False,
        sim_seconds=spec.sim_seconds,
        scout_id=spec.label or "scout",
        sim=SimConfig(sensors=SensorConfig.named(spec.sensors), launch=LaunchSurvey(mode=spec.launch)),
        **kw,
    )


class RecordingAccumulator(CellAccumulator):
    """The mapper's accumulator, also keeping every row it was given (to re-bin at other cell sizes)."""

    def __init__(self, res: float) -> None:
        super().__init__(res)
        self.log: dict[str, list[tuple[float, ...]]] = {}
        self.footholds: list[tuple[float, float, float]] = []

    def append(self, layer: str, row: tuple[float, ...]) -> None:
        super().append(layer, row)
        if layer == "elevation":  # a held foothold released as its row (x, y, n, z, ...): keep the foothold
            self.footholds.append((row[0], row[1], row[3]))
        elif layer != "height":  # the height layer's moments are relative to this size's cell centres
            self.log.setdefault(layer, []).append(row)

    def add_elevation(self, x: float, y: float, z: float) -> None:
        super().add_elevation(x, y, z)
        self.footholds.append((x, y, z))


def recording_accumulator(res: float) -> RecordingAccumulator:
    return RecordingAccumulator(res)


def rebin(acc: RecordingAccumulator, res: float) -> LocalMap:
    """A `LocalMap` at cell size `res` [m] from everything a `RecordingAccumulator` was given."""
    fresh = CellAccumulator(res)
    for layer, rows in acc.log.items():
        for row in rows:
            fresh.append(layer, row)
    for x, y, z in acc.footholds:
        fresh.add_elevation(x, y, z)
    local = LocalMap(res)
    layers = fresh.flush()
    if layers:
        local.merge(layers)
    return local


def elevation_errors(local: LocalMap, terrain: Terrain, segments: dict | None = None) -> dict[str, Any]:
    """RMSE [m] of the elevation layer against the exact terrain at cell centres, three ways from the same
    cell statistics: the mean alone (the paper's estimate, eq. 14), the map's value (`layer_value`: the
    protocol's plane fit where footholds spread ≥ 2 cm along both axes, else the mean) and the scout's
    truncated plane fit (`plane_from_moments`: slope only along the directions the footholds span); also on
    the ramp cells only."""
    from scout_agent.estimators.elevation import plane_from_moments

    c = local.cells("elevation")
    if not len(c["ix"]):
        return {"cells": 0}
    cx, cy = cell_center(c["ix"], c["iy"], local.res)
    truth = terrain.height(cx, cy)
    value = layer_value("elevation", c)
    mean = c["sum"] / c["n"]
    plane = plane_from_moments(c)[0]
    out: dict[str, Any] = {"cells": int(len(cx)), "footholds": int(c["n"].sum())}

    def rmse(v: np.ndarray, m: np.ndarray) -> float | None:
        e = (v - truth)[m]
        e = e[np.isfinite(e)]
        return round(float(np.sqrt(np.mean(e**2))), 5) if e.size else None

    every = np.ones(len(cx), bool)
    out["rmse_m"] = rmse(value, every)
    out["rmse_mean_only_m"] = rmse(mean, every)
    out["rmse_plane_m"] = rmse(plane, every)
    if segments:
        on = np.zeros(len(cx), bool)
        for seg in ("up", "down"):
            a, b = segments[seg]
            on |= (cx >= a) & (cx < b)
        out["ramp_cells"] = int(on.sum())
        out["rmse_ramps_m"] = rmse(value, on)
        out["rmse_ramps_mean_only_m"] = rmse(mean, on)
        out["rmse_ramps_plane_m"] = rmse(plane, on)
    return out


def _slip_counts(ev: Evaluator) -> dict[str, dict[str, int]]:
    from scout_agent.evaluate import GT_SLIP_M

    truth = {k for k, v in ev.stances.items() if v[3] > GT_SLIP_M}
    known = set(ev.stances)
    out = {}
    for which in ("honest", "exact", "paper"):
        det = ev.detected[which] & known
        out[which] = {"tp": len(det & truth), "detected": len(det), "truth": len(truth)}
    return out


def _slip_points(ev: Evaluator) -> dict[str, np.ndarray]:
    """Touchdown (x, y) of ground-truth slips and of honest detections (for maps and profiles)."""
    from scout_agent.evaluate import GT_SLIP_M

    gt = [(v[0], v[1]) for v in ev.stances.values() if v[3] > GT_SLIP_M]
    det = [ev.stances[k][:2] for k in ev.detected["honest"] if k in ev.stances]
    return {"truth": np.array(gt, float).reshape(-1, 2), "detected": np.array(det, float).reshape(-1, 2)}


def _paper_cells(ev: Evaluator) -> dict[str, dict[str, np.ndarray]]:
    out = {}
    for key in ("giim", "giam"):
        sums = ev.paper_means[key].sums
        keys = sorted(sums)
        out[key] = {
            "ix": np.array([k[0] for k in keys], np.int32),
            "iy": np.array([k[1] for k in keys], np.int32),
            "sum": np.array([sums[k][0] for k in keys], float),
            "n": np.array([sums[k][1] for k in keys], float),
        }
    return out


def run_spec(spec: RunSpec) -> dict[str, Any]:
    """Walk one spec with the evaluator attached; return everything the experiments read (picklable)."""
    from scout_agent.evaluate import Evaluator
    from scout_agent.run import build_world, run_scout

    wall0 = time.perf_counter()
    cfg = _run_config(spec)
    world = build_world(cfg)  # terrain and patches from the terrain seed
    cfg = replace(cfg, seed=spec.noise_seed)  # the walk's noise from the noise seed
    ev = Evaluator(res=spec.res)
    acc = recording_accumulator(spec.res)
    ev.mapper.use_accumulator(acc)
    track: list[tuple[float, float, float, float]] = []

    def on_tick(sample, truth, sim) -> None:
        ev.on_tick(sample, truth, sim)
        if ev.ticks % 25 == 1:
            p = truth.base.pos
            track.append((sample.t, float(p[0]), float(p[1]), float(p[2])))

    summary = run_scout(cfg, on_tick=on_tick, progress=False, world=world)
    scores = ev.result(world, cfg.friction_default)
    segments = world.terrain.info.get("segments")
    elevation = {f"{spec.res:g}": elevation_errors(ev.mapper.local, world.terrain, segments)}
    for r in EXTRA_RES:
        elevation[f"{r:g}"] = elevation_errors(rebin(acc, r), world.terrain, segments)
    # the same estimators fed the simulator's exact base state: beside the honest figures, never instead
    elevation_exact = elevation_errors(ev.exact.local, world.terrain, segments)
    summary.pop("friction", None)
    return {
        "key": spec.key(),
        "spec": asdict(spec),
        "summary": summary,
        "scores": scores,
        "slip_counts": _slip_counts(ev),
        "slip_points": _slip_points(ev),
        "elevation": elevation,
        "elevation_exact": elevation_exact,
        "cells": {name: ev.mapper.local.cells(name) for name in LAYERS},
        "paper_cells": _paper_cells(ev),
        "track": np.array(track, float).reshape(-1, 4),
        "friction": {
            "default": world.friction.default,
            "patches": [[float(v) for v in (p.x0, p.y0, p.x1, p.y1, p.mu)] for p in world.friction.patches],
        },
        "segments": {k: [float(a), float(b)] for k, (a, b) in segments.items()} if segments else None,
        "waypoints": world.waypoints.tolist(),
        "mass_kg": float(ev.mapper.feet.total_mass_kg),
        "worker_seconds": round(time.perf_counter() - wall0, 2),
    }


# ------------------------------------------------------------------------------------------ the pool


class RunPool:
    """Runs specs in `workers` spawn processes with a progress bar; results cached in `cache_dir`."""

    def __init__(self, cache_dir: Path, workers: int = 2, progress: bool = True, fresh: bool = False) -> None:
        self.cache_dir = Path(cache_dir)
        self.cache_dir.mkdir(parents=True, exist_ok=True)
        self.workers = max(1, int(workers))
        self.progress = progress
        self.fresh = fresh
        self._done_fresh: set[str] = set()  # with `fresh`, runs of this session count as cached
        self.walked = 0  # runs simulated by this pool (not from the cache)
        self.worker_seconds = 0.0

    def _path(self, key: str) -> Path:
        return self.cache_dir / f"{key}.pkl"

    def _cached(self, spec: RunSpec) -> dict | None:
        key = spec.key()
        path = self._path(key)
        if not path.is_file() or (self.fresh and key not in self._done_fresh):
            return None
        with path.open("rb") as f:
            return pickle.load(f)

    def run(self, specs: Iterable[RunSpec], desc: str = "runs") -> list[dict]:
        """Results in the order of `specs` (duplicates walked once)."""
        specs = list(specs)
        results: dict[str, dict] = {}
        todo: dict[str, RunSpec] = {}
        for s in specs:
            k = s.key()
            if k in results or k in todo:
                continue
            hit = self._cached(s)
            if hit is not None:
                results[k] = hit
            else:
                todo[k] = s
        bar = None
        if self.progress:
            bar = progress(len(results) + len(todo), desc, "run", initial=len(results), every_s=30.0)
        try:
            for res in self._walk(list(todo.values())):
                key = res["key"]
                tmp = self._path(key).with_suffix(".tmp")
                with tmp.open("wb") as f:
                    pickle.dump(res, f)
                tmp.replace(self._path(key))
                self._done_fresh.add(key)
                self.walked += 1
                self.worker_seconds += res["worker_seconds"]
                results[key] = res
                if bar is not None:
                    s = res["summary"]
                    bar.set_postfix(last=f"{res['spec']['label']} {'FELL' if s['fell'] else 'ok'}")
                    bar.update(1)
        finally:
            if bar is not None:
                bar.close()
        return [results[s.key()] for s in specs]

    def _walk(self, todo: list[RunSpec]):
        if not todo:
            return
        if self.workers == 1 or len(todo) == 1:
            for s in todo:
                yield run_spec(s)
            return
        ctx = mp.get_context("spawn")
        with ctx.Pool(min(self.workers, len(todo)), maxtasksperchild=8) as pool:
            yield from pool.imap_unordered(run_spec, todo)


# ------------------------------------------------------------------------------------------ numbers out


def fmean(values: Iterable[Any]) -> float | None:
    """Mean of the finite values, None when there is none (no warning on empty input)."""
    v = [float(x) for x in values if x is not None and math.isfinite(float(x))]
    return float(np.mean(v)) if v else None


def estimation_summary(runs: list[dict]) -> dict[str, Any]:
    """How honest the scouts' state estimate was over a group of runs: drift at the end (horizontal as a share
    of the distance, vertical, heading), elevation RMSE at 0.4 m on the estimate beside the same estimators on
    the exact state, and the whole-walk CoT beside the simulator's exact energy over the true path."""

    def cot_err(r: dict) -> float | None:
        a, b = r["scores"].get("cot_whole_run"), r["summary"].get("cot_whole_run_truth")
        return 100.0 * abs(a - b) / b if a is not None and b else None

    def vals(fn) -> list[Any]:
        return [fn(r) for r in runs]

    xy = [v for v in vals(lambda r: r["summary"].get("drift_xy_pct")) if v is not None]
    return {
        "runs": len(runs),
        "falls": sum(bool(r["summary"]["fell"]) for r in runs),
        "drift_xy_pct_mean": fmean(xy),
        "drift_xy_pct_max": max(xy) if xy else None,
        # the same less the launch survey's start error (consistency.py: the error's growth after t = 0)
        "drift_after_start_xy_pct_mean": fmean(vals(lambda r: r["summary"].get("drift_after_start_xy_pct"))),
        "pos_error_start_m_mean": fmean(vals(lambda r: r["summary"].get("pos_error_start_m"))),
        "drift_z_m_mean_abs": fmean(
            abs(v) for v in vals(lambda r: r["summary"].get("drift_z_m")) if v is not None
        ),
        "drift_yaw_deg_mean_abs": fmean(
            abs(v) for v in vals(lambda r: r["summary"].get("drift_yaw_deg")) if v is not None
        ),
        "elevation_rmse_m": fmean(vals(lambda r: r["elevation"][f"{MAP_RES:g}"].get("rmse_m"))),
        "elevation_rmse_exact_m": fmean(vals(lambda r: (r.get("elevation_exact") or {}).get("rmse_m"))),
        "cot_whole_run": fmean(vals(lambda r: r["scores"].get("cot_whole_run"))),
        "cot_whole_run_truth": fmean(vals(lambda r: r["summary"].get("cot_whole_run_truth"))),
        "cot_error_pct_mean": fmean(vals(cot_err)),
        "cot_error_pct_max": max((v for v in vals(cot_err) if v is not None), default=None),
        # the estimate's error over the whole run and whether its covariance held it (consistency.py)
        "pos_error_max_m_mean": fmean(vals(lambda r: r["summary"].get("pos_error_max_m"))),
        "pos_error_max_m_max": max(
            (v for v in vals(lambda r: r["summary"].get("pos_error_max_m")) if v is not None), default=None
        ),
        "yaw_error_max_deg_max": max(
            (v for v in vals(lambda r: r["summary"].get("yaw_error_max_deg")) if v is not None), default=None
        ),
        "nees_pos_mean": fmean(vals(lambda r: r["summary"].get("nees_pos_mean"))),
        "inside_3sigma_frac_min": min(
            (v for v in vals(lambda r: r["summary"].get("inside_3sigma_frac")) if v is not None), default=None
        ),
        "inside_3sigma_frac_mean": fmean(vals(lambda r: r["summary"].get("inside_3sigma_frac"))),
    }


def fstd(values: Iterable[Any]) -> float | None:
    v = [float(x) for x in values if x is not None and math.isfinite(float(x))]
    return float(np.std(v)) if len(v) > 1 else (0.0 if v else None)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        f = float(x)
        return round(f, 6) if math.isfinite(f) else None
    return x


def write_json(path: Path, obj: Any) -> Path:
    """JSON with numpy types converted, NaN/inf as null."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(obj), indent=1) + "\n")
    return path
