"""`psrmap evaluate`: one scout run scored against the simulator's ground truth, as one JSON object.

    psrmap evaluate --scene ramps --slope A [--slippery MU] [--res 0.4] --json
    psrmap evaluate --scene lunar --seed N [--slippery-patches N] [--route R] [--res 0.4] --json

The map under test is what the scout itself builds (`scout_agent.mapping.Mapper`: the estimators fed the
*honest* base state: the scout's own state estimate from its sensor models, unless `--state exact`). Beside it,
on the same run, the same estimators and map fed the simulator's exact base state (`*_exact`, e.g.
`elevation_rmse_exact_m`, `slip_precision_exact`) and the paper-form slip detector (`slip_paper_*`); the state
estimate's drift at the end (`drift_xy_pct`, `drift_z_m`, `drift_yaw_deg`), its error over the whole run and
whether its covariance contains it (`pos_error_max_m`, `pos_error_final_m`, `yaw_error_max_deg`, `nees_pos_mean`,
`pos_error_start_m` and the error's growth after the start `pos_error_growth_max_m`, `pos_error_growth_final_m`,
`drift_after_start_xy_pct`,
`inside_3sigma_frac`, and for the heading `nees_yaw_mean`, `yaw_inside_3sigma_frac`:
`scout_agent/state_estimation/consistency.py`), the sensor profile (`sensors`:
realistic/ideal), `localization` ("off" until a localizer runs), the start it was given (`launch`), and `cot_whole_run_truth` (the
simulator's exact joint energy at every physics step over the true horizontal path) beside `cot_whole_run`.

Ground truth and scoring:
- slip: a planned stance (per foot) whose contact point moved > 0.02 m from its first contact
  (`GroundTruth.stance_disp`, the paper's criterion); precision/recall count stances, detected vs true.
- elevation: the map's value per cell (`protocol.layers.layer_value`: plane fit at the cell centre, or the
  mean where the fit is ill conditioned) against the exact terrain height at the cell centre; also the mean
  alone (the paper's estimate) and the scout's truncated plane fit (`estimators.elevation.plane_from_moments`,
  which fits the slope along the directions the footholds span). Slope (`slope_rmse_deg`): that fit's slope
  from the same cell statistics against the exact cell slope (plane through the true heights over the cell),
  every cell; `slope_rmse_point_deg` against the exact slope at the centre point; `*_protocol_fit`: the
  protocol's fit, defined only where footholds spread ≥ 2 cm along both axes (rare: a cell usually holds one
  foot track).
- CoT, GIIM, GIAM: means over the map's cells (the paper averages its gridmap layers); on ramps per segment
  (cells whose centre lies on the up-ramp, the platform = `flat`, the down-ramp).
- friction patches: a slip is "in a patch" when the ground under the foot at touchdown has less than the
  default friction; the slip layer's rate (events / stances) inside vs outside patch cells.
- non-foot contacts: ticks with calf/thigh/trunk on the ground in truth vs ticks the proprioceptive
  detector flagged.
- unholdable ground (`sim.friction.unholdable`: μ < tan slope, the cell's plane-fit slope): `unholdable_cells`
  in the whole world (cell centres), `unholdable_cells_crossed` the cells a stance foot touched down in
  where the μ under the foot was below the tangent of the cell's slope.
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Any

import numpy as np

from protocol.layers import cell_center, elevation_slope_deg, layer_value
from psrmap_common.defaults import DEFAULT_DELTA_HZ, DEFAULT_RES_M
from scout_agent.errors import ScoutConfigError
from scout_agent.estimators import EstimatorPipeline, TickEstimates
from scout_agent.estimators.elevation import plane_from_moments, slope_deg
from scout_agent.holding import PoseFix
from scout_agent.mapping import Mapper, MapperConfig, default_pipeline_config, position_variances
from scout_agent.onboard.software import OnboardSoftware
from scout_agent.run import ScoutRunConfig, build_world, run_scout
from scout_agent.signals import GroundTruth, ProprioSample
from scout_agent.sim.friction import unholdable

__all__ = ["GT_SLIP_M", "Evaluator", "evaluate_run"]

# the state estimate against the truth over the whole run (state_estimation/consistency.py)
ERROR_KEYS = (
    "pos_error_max_m",
    "pos_error_final_m",
    "pos_error_start_m",  # the launch survey's error, and what the walk added to it after t = 0
    "pos_error_growth_max_m",
    "pos_error_growth_final_m",
    "drift_after_start_xy_pct",
    "yaw_error_max_deg",
    "yaw_error_start_deg",  # the survey's heading draw, and the most the walk moved the error from it
    "yaw_error_growth_max_deg",
    "nees_pos_mean",
    "inside_3sigma_frac",
    "nees_yaw_mean",
    "yaw_inside_3sigma_frac",
)
GT_SLIP_M = 0.02  # ground-truth slip: contact point moved more than this within one stance [m]
SEGMENTS = {"up": "up", "flat": "platform", "down": "down"}


def _pr(detected: set, truth: set) -> tuple[float, float]:
    tp = len(detected & truth)
    p = tp / len(detected) if detected else (1.0 if not truth else 0.0)
    r = tp / len(truth) if truth else (1.0 if not detected else math.nan)
    return p, r


def _cell_slope_deg(
    terrain: Any, cx: np.ndarray, cy: np.ndarray, res: float, step: float = 0.05
) -> np.ndarray:
    """Ground-truth slope of each cell [deg]: the least-squares plane through the exact terrain heights on a
    `step` grid over the cell (the cell's slope, not the slope at one point of a rough surface)."""
    off = np.arange(-res / 2 + step / 2, res / 2, step)
    dx, dy = (a.ravel() for a in np.meshgrid(off, off))
    a = np.stack([np.ones_like(dx), dx, dy], axis=1)
    pinv = np.linalg.pinv(a)  # (3, k)
    z = terrain.height(cx[:, None] + dx[None, :], cy[:, None] + dy[None, :])  # (cells, k)
    coef = z @ pinv.T
    return np.degrees(np.arctan(np.hypot(coef[:, 1], coef[:, 2])))


def _r(v: float, nd: int = 4) -> float | None:
    return None if v is None or not math.isfinite(v) else round(float(v), nd)


class _CellMeans:
    """Mean of a per-tick quantity per CoM cell, then over cells (as the map layers are averaged)."""

    def __init__(self, res: float) -> None:
        self.res = res
        self.sums: dict[tuple[int, int], list[float]] = defaultdict(lambda: [0.0, 0])

    def add(self, x: float, y: float, v: float) -> None:
        if v == v:
            s = self.sums[(math.floor(x / self.res), math.floor(y / self.res))]
            s[0] += v
            s[1] += 1

    def cell_means(self) -> dict[tuple[int, int], float]:
        return {k: s / n for k, (s, n) in self.sums.items() if n}


class Evaluator:
    """Runs alongside `run_scout` (`on_tick`), then `result(world)` scores the run."""

    def __init__(self, res: float = DEFAULT_RES_M, delta_hz: float = DEFAULT_DELTA_HZ) -> None:
        self.mapper = Mapper(MapperConfig(res=res, delta_hz=delta_hz))
        feet = self.mapper.feet
        # the scout's own pipeline, plus the diagnostics that do not change what it maps
        self.mapper.pipeline = EstimatorPipeline(
            feet, default_pipeline_config(feet, paper_margins=True, stance_margins=True, paper_slip=True)
        )
        # the same estimators and map fed the simulator's exact base state, for the `*_exact` figures only
        self.exact = Mapper(MapperConfig(res=res, delta_hz=delta_hz), feet=feet)
        self.res = res
        self.paper_means = {k: _CellMeans(res) for k in ("giim", "giam", "giim_stance", "giam_stance")}
        self.giim_ticks: list[float] = []
        self._prev_planned = np.zeros(4, dtype=bool)
        self._sid = [0, 0, 0, 0]
        self._touched = [False] * 4
        self._gt_max = [0.0] * 4
        self._td = [(math.nan, math.nan, math.nan)] * 4  # x, y, mu at touchdown
        self.stances: dict[
            tuple[int, int], tuple[float, float, float, float]
        ] = {}  # (leg, sid) → x, y, mu, disp
        self.detected: dict[str, set[tuple[int, int]]] = {"honest": set(), "exact": set(), "paper": set()}
        self.nonfoot_truth = 0
        self.nonfoot_flagged = 0
        self.nonfoot_both = 0
        self.ticks = 0

    # ------------------------------------------------------------------ per tick
    def on_hazard(self, felt: Any) -> None:
        self.mapper.record_hazard(felt.x, felt.y, felt.reasons)

    def on_fix(self, fix: PoseFix) -> None:
        """A pose fix the localizer fused: the scout's own map is corrected as the published one is (the
        exact-state map is not: its poses need none)."""
        self.mapper.fix(fix)

    def on_tick(self, sample: ProprioSample, truth: GroundTruth, robot: object = None) -> TickEstimates:
        self.ticks += 1
        planned = sample.stance_planned
        contact = sample.contact
        for i in range(4):
            if planned[i] and not self._prev_planned[i]:
                self._sid[i] += 1
                self._touched[i] = False
                self._gt_max[i] = 0.0
            if not planned[i] and self._prev_planned[i] and self._touched[i]:
                self._close_stance(i)
            if planned[i] and contact[i]:
                if not self._touched[i]:
                    self._touched[i] = True
                    p = truth.foot_pos_world[i]
                    self._td[i] = (float(p[0]), float(p[1]), float(truth.friction_at_feet[i]))
                d = truth.stance_disp[i]
                if d == d and d > self._gt_max[i]:
                    self._gt_max[i] = float(d)
        self._prev_planned = planned.copy()

        var = position_variances(robot) if isinstance(robot, OnboardSoftware) else None
        est = self.mapper.update(sample, *var) if var is not None else self.mapper.update(sample)
        ex = self.exact.update(sample._replace(base=truth.base))  # evaluation only: never fed back
        self._mark(est.slip.event, "honest")
        self._mark(ex.slip.event, "exact")
        if est.slip_paper is not None:
            self._mark(est.slip_paper.event, "paper")
        self._stability(est)
        t_nf = truth.nonfoot_contacts > 0
        self.nonfoot_truth += t_nf
        self.nonfoot_flagged += est.nonfoot
        self.nonfoot_both += t_nf and est.nonfoot
        return est

    def _mark(self, events, which: str) -> None:
        for i in range(4):
            if events[i]:
                self.detected[which].add((i, self._sid[i]))

    def _close_stance(self, i: int) -> None:
        x, y, mu = self._td[i]
        self.stances[(i, self._sid[i])] = (x, y, mu, self._gt_max[i])

    def _stability(self, est: TickEstimates) -> None:
        x, y = est.com_xy
        if not est.stability_guarded:
            self.paper_means["giim"].add(x, y, est.giim_paper)
            self.paper_means["giam"].add(x, y, est.giam_paper)
            self.giim_ticks.append(est.giim)
        self.paper_means["giim_stance"].add(x, y, est.giim_stance)
        self.paper_means["giam_stance"].add(x, y, est.giam_stance)

    def _unholdable(self, world: Any) -> dict[str, int]:
        """Ground truth of ground no robot holds (μ < tan of the cell's slope): in the world, and crossed."""
        res, terrain = self.res, world.terrain
        xa, ya, xb, yb = terrain.extent
        ix, iy = np.meshgrid(np.arange(math.floor(xa / res), math.ceil(xb / res)),
                             np.arange(math.floor(ya / res), math.ceil(yb / res)))  # fmt: skip
        cx, cy = cell_center(ix.ravel(), iy.ravel(), res)
        inside = (cx > xa) & (cx < xb) & (cy > ya) & (cy < yb)
        cx, cy = cx[inside], cy[inside]
        world_cells = int(unholdable(world.friction.at(cx, cy), _cell_slope_deg(terrain, cx, cy, res)).sum())
        mu_min: dict[tuple[int, int], float] = {}
        for x, y, mu, _ in self.stances.values():
            if x == x:
                key = (math.floor(x / res), math.floor(y / res))
                mu_min[key] = min(mu, mu_min.get(key, math.inf))
        crossed = 0
        if mu_min:
            keys = np.array(list(mu_min), dtype=float)
            kx, ky = cell_center(keys[:, 0], keys[:, 1], res)
            slope = _cell_slope_deg(terrain, kx, ky, res)
            crossed = int(unholdable(np.array(list(mu_min.values())), slope).sum())
        return {"unholdable_cells": world_cells, "unholdable_cells_crossed": crossed}

    # ------------------------------------------------------------------ scoring
    def result(self, world: Any, friction_default: float) -> dict:
        for i in range(4):  # stances still open at the end
            if self._prev_planned[i] and self._touched[i]:
                self._close_stance(i)
        self.mapper.close()
        self.exact.close()
        terrain = world.terrain
        local = self.mapper.local
        res = self.res
        out: dict[str, Any] = {"res": res, "ticks": self.ticks}

        # ---- slip
        truth = {k for k, v in self.stances.items() if v[3] > GT_SLIP_M}
        known = set(self.stances)
        for which, suffix in (("honest", ""), ("exact", "_exact"), ("paper", "_paper")):
            det = self.detected[which] & known if known else self.detected[which]
            p, r = _pr(det, truth)
            key = "slip" if which != "paper" else "slip_paper"
            sfx = suffix if which != "paper" else ""
            out[f"{key}_precision{sfx}"] = _r(p)
            out[f"{key}_recall{sfx}"] = _r(r)
            out[f"{key}_events{sfx}" if which != "honest" else "slip_events"] = len(self.detected[which])
        out["stances"] = len(self.stances)
        out["gt_slips"] = len(truth)
        in_patch = {k for k, v in self.stances.items() if v[2] < friction_default - 1e-9}
        out["gt_slips_in_patch_share"] = _r(len(truth & in_patch) / len(truth)) if truth else None
        det = self.detected["honest"] & known
        out["slip_events_in_patch_share"] = _r(len(det & in_patch) / len(det)) if det else None
        out["stances_in_patch"] = len(in_patch)
        out.update(self._unholdable(world))

        # ---- layers from the local map
        def cells(layer: str) -> dict[str, np.ndarray]:
            return local.cells(layer)

        ex_elev = self.exact.local.cells("elevation")
        if len(ex_elev["ix"]):
            cx, cy = cell_center(ex_elev["ix"], ex_elev["iy"], res)
            err = layer_value("elevation", ex_elev) - terrain.height(cx, cy)
            out["elevation_rmse_exact_m"] = _r(float(np.sqrt(np.nanmean(err**2))), 5)
        elev = cells("elevation")
        if len(elev["ix"]):
            cx, cy = cell_center(elev["ix"], elev["iy"], res)
            h_true = terrain.height(cx, cy)
            value = layer_value("elevation", elev)
            mean = elev["sum"] / elev["n"]
            z_fit, gx, gy = plane_from_moments(elev)
            out["elevation_cells"] = int(len(cx))
            out["elevation_rmse_m"] = _r(float(np.sqrt(np.nanmean((value - h_true) ** 2))), 5)
            # the map's height datum is the launch's (declared 0 without a DEM or map): its offset, and the
            # RMSE of the relief once that one offset is removed
            bias = float(np.nanmean(value - h_true))
            out["elevation_bias_m"] = _r(bias, 5)
            out["elevation_rmse_relative_m"] = _r(float(np.sqrt(np.nanmean((value - h_true - bias) ** 2))), 5)
            out["elevation_rmse_mean_only_m"] = _r(float(np.sqrt(np.mean((mean - h_true) ** 2))), 5)
            out["elevation_rmse_plane_m"] = _r(float(np.sqrt(np.nanmean((z_fit - h_true) ** 2))), 5)
            s_true = _cell_slope_deg(terrain, cx, cy, res)
            s_fit = slope_deg(gx, gy)
            out["slope_rmse_deg"] = _r(float(np.sqrt(np.nanmean((s_fit - s_true) ** 2))), 3)
            s_point = terrain.slope_deg(cx, cy)
            out["slope_rmse_point_deg"] = _r(float(np.sqrt(np.nanmean((s_fit - s_point) ** 2))), 3)
            s_map = elevation_slope_deg(elev)  # protocol's fit: needs spread along both axes
            ok = np.isfinite(s_map)
            out["slope_cells_protocol_fit"] = int(ok.sum())
            if ok.any():
                out["slope_rmse_deg_protocol_fit"] = _r(
                    float(np.sqrt(np.mean((s_map[ok] - s_true[ok]) ** 2))), 3
                )
                out["slope_rmse_deg_same_cells"] = _r(
                    float(np.sqrt(np.mean((s_fit[ok] - s_true[ok]) ** 2))), 3
                )

        layer_vals: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        for name in ("cot", "giim", "giam", "slip"):
            c = cells(name)
            if len(c["ix"]):
                x, y = cell_center(c["ix"], c["iy"], res)
                layer_vals[name] = (x, y, layer_value(name, c))
        for name in ("cot", "giim", "giam"):
            if name in layer_vals:
                out[f"{name}_mean"] = _r(float(np.nanmean(layer_vals[name][2])))
        g = cells("giim")
        if len(g["ix"]):
            out["giim_worst"] = _r(float(np.min(g["min"])))
            out["giam_worst"] = _r(float(np.min(cells("giam")["min"])))
        ticks = np.array(self.giim_ticks)
        ticks = ticks[np.isfinite(ticks)]
        if ticks.size:
            out["giim_tick_p1_p5"] = [_r(float(np.percentile(ticks, 1))), _r(float(np.percentile(ticks, 5)))]
            out["giim_nonpositive_share"] = _r(float(np.mean(ticks <= 0)), 5)
        for key, cm in self.paper_means.items():
            vals = list(cm.cell_means().values())
            name = {"giim": "giim_paper_mean", "giam": "giam_paper_mean"}.get(key, f"{key}_mean")
            out[name] = _r(float(np.mean(vals))) if vals else None
        out["cot_whole_run"] = _r(self.mapper.pipeline.cot.cot)

        # slip layer inside / outside friction patches (cell centres)
        sl = cells("slip")
        if len(sl["ix"]):
            x, y = cell_center(sl["ix"], sl["iy"], res)
            mu = world.friction.at(x, y)
            inside = mu < friction_default - 1e-9
            for tag, m in (("in_patches", inside), ("outside_patches", ~inside)):
                n = float(sl["n"][m].sum())
                out[f"slip_rate_{tag}"] = _r(float(sl["events"][m].sum()) / n) if n else None
            out["slip_cells_in_patches"] = int(inside.sum())

        # ramps: per segment
        segs = terrain.info.get("segments")
        if segs:
            out["segments"] = {}
            slips_x = [self.stances.get(k, (math.nan,))[0] for k in self.detected["honest"]]
            for label, seg in SEGMENTS.items():
                a, b = segs[seg]
                entry: dict[str, Any] = {}
                for name in ("cot", "giim", "giam"):
                    if name in layer_vals:
                        x, _, v = layer_vals[name]
                        m = (x >= a) & (x < b)
                        entry[f"{name}_mean"] = (
                            _r(float(np.nanmean(v[m]))) if np.isfinite(v[m]).any() else None
                        )
                for key in ("giim", "giam"):
                    means = self.paper_means[key].cell_means()
                    vals = [v for (ix, _), v in means.items() if a <= (ix + 0.5) * res < b]
                    entry[f"{key}_paper_mean"] = _r(float(np.mean(vals))) if vals else None
                entry["slip_events"] = int(sum(1 for sx in slips_x if a <= sx < b))
                gts = [self.stances[k][0] for k in truth]
                entry["gt_slips"] = int(sum(1 for sx in gts if a <= sx < b))
                out["segments"][label] = entry

        # non-foot contacts
        out["nonfoot_contact_ticks"] = int(self.nonfoot_truth)
        out["nonfoot_flagged_ticks"] = int(self.nonfoot_flagged)
        out["nonfoot_flagged_true_ticks"] = int(self.nonfoot_both)
        c = cells("contacts")
        out["nonfoot_cells"] = int((c["nonfoot"] > 0).sum()) if len(c["ix"]) else 0
        out["deltas"] = self.mapper.deltas
        return out


def evaluate_run(cfg: ScoutRunConfig, res: float = DEFAULT_RES_M, progress: bool = False) -> dict:
    """Walk `cfg` with an `Evaluator` beside the robot (cells of `res` [m]) and return the scores as one dict
    (`psrmap evaluate` prints it)."""
    if not res > 0:
        raise ScoutConfigError(f"--res {res}: need a cell size > 0 [m]")
    world = build_world(cfg)
    ev = Evaluator(res=res)
    summary = run_scout(
        cfg, on_tick=ev.on_tick, progress=progress, world=world, on_hazard=ev.on_hazard, on_fix=ev.on_fix
    )
    out = {
        "scene": cfg.scene,
        "terrain": summary["terrain"],
        "slope_deg": cfg.slope_deg if cfg.scene == "ramps" else None,
        "seed": cfg.seed,
        "slippery_mu": cfg.slippery_mu,
        "slippery_patches": cfg.slippery_patches,
        "holdable_patches": cfg.holdable_patches,
        "state_source": summary["state_source"],
        "sensors": summary["sensors"],
        "localization": summary["localization"],
        "launch": summary["launch"],
        "localization_stats": summary["localization_stats"],
        "contact_source": cfg.sim.contact.source,
        "fell": summary["fell"],
        "fall_xy": summary["fall_xy"],
        "reached_goal": summary["reached_goal"],
        "hazard_stops": summary["hazard_stops"],
        "standstills": summary["standstills"],
        "zaru": summary["zaru"],
        "climb_calibration": summary["climb_calibration"],
        "detour_m": summary["detour_m"],
        "gave_up": summary["gave_up"],
        "friction_estimate": summary["friction_estimate"],
        "hazard_control": cfg.hazard_control,
        "distance_m": summary["distance_m"],
        "sim_seconds": summary["sim_seconds"],
        "wall_seconds": summary["wall_seconds"],
        "mass_kg": round(ev.mapper.feet.total_mass_kg, 3),
        "gia_source": "imu (accelerometer, estimated orientation)",
        **{
            k: summary[k]
            for k in ("drift_xy_m", "drift_xy_pct", "drift_z_m", "drift_yaw_deg", *ERROR_KEYS)
            if k in summary
        },
    }
    out.update(ev.result(world, cfg.friction_default))
    out["cot_whole_run_truth"] = summary["cot_whole_run_truth"]
    return out
