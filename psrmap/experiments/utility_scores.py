"""`psrmap experiment utility`, the scoring: what the scouts' map predicted against what the fresh robot felt.

`agreement` compares two maps cell by cell along a route, `predicted` and `predicted_vs_felt` put the
planner's breakdown beside the robot's experience, `beat` says whether the planned route beat the straight
one, `pool_rows` and `summary` pool seeds. The experiment itself (runs, plans, walks): `utility`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from psrmap.experiments.common import MAP_RES, fmean
from psrmap.experiments.maps import dense, merged_local_map
from scout_agent.cells import LocalMap

__all__ = ["agreement", "beat", "pool_rows", "predicted", "predicted_vs_felt", "summary"]


def agreement(scout_local: LocalMap, run: dict, cells_xy: np.ndarray) -> dict[str, Any]:
    """Per-cell agreement, along a route's cells, of the scouts' map and the fresh robot's own map."""
    own = merged_local_map([run])
    out: dict[str, Any] = {}
    ix = np.floor(cells_xy[:, 0] / MAP_RES).astype(int)
    iy = np.floor(cells_xy[:, 1] / MAP_RES).astype(int)
    for layer in ("cot", "giim", "giam", "elevation"):
        a = dense(scout_local.cells(layer), layer)
        b = dense(own.cells(layer), layer)
        n = a.shape[0]
        ok = (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n)
        va, vb = a[iy[ok], ix[ok]], b[iy[ok], ix[ok]]
        both = np.isfinite(va) & np.isfinite(vb)
        entry: dict[str, Any] = {"cells_both": int(both.sum()), "route_cells": int(ok.sum())}
        if both.sum() >= 3:
            entry["mean_abs_diff"] = float(np.mean(np.abs(va[both] - vb[both])))
            entry["bias_scouts_minus_fresh"] = float(np.mean(va[both] - vb[both]))
            if np.std(va[both]) > 0 and np.std(vb[both]) > 0:
                entry["pearson_r"] = float(np.corrcoef(va[both], vb[both])[0, 1])
        out[layer] = entry
    return out


def beat(p: dict, s: dict) -> dict[str, Any]:
    """Did the planned route (p) beat the straight one (s) in what the fresh robot experienced?"""

    def lower(k: str) -> bool | None:
        a, b = p.get(k), s.get(k)
        return None if a is None or b is None else bool(a < b)

    def higher(k: str) -> bool | None:
        a, b = p.get(k), s.get(k)
        return None if a is None or b is None else bool(a > b)

    out = {
        "energy": lower("energy_m"),
        "cot": lower("cot_whole_run"),
        "gt_slips": lower("gt_slips"),
        "giim_mean": higher("giim_mean"),
        "giim_min_cell": higher("giim_min_cell"),
        "cost_on_own_map": lower("cost_on_own_map"),
        "time": lower("sim_seconds"),
    }
    if s.get("fell") and not p.get("fell"):
        out["fall"] = True
    elif p.get("fell") and not s.get("fell"):
        out["fall"] = False
    return out


def predicted(b: dict | None) -> dict[str, Any] | None:
    if not b:
        return None
    return {
        k: b.get(k)
        for k in (
            "length_m",
            "cost",
            "mean_cot",
            "expected_slip_events",
            "mean_giim",
            "min_giim",
            "mean_giam",
            "min_giam",
            "max_slope_deg",
            "unknown_fraction",
            "inferred_fraction",
        )
    }


def predicted_vs_felt(pred: dict | None, felt: dict | None) -> dict[str, Any] | None:
    """What the shared map predicted for a route (mean CoT of its cells, expected slip events) beside what the
    fresh robot then felt walking it (its own whole-walk CoT, ground-truth and detected slips)."""
    if not pred or not felt:
        return None
    cot_p, cot_f = pred.get("mean_cot"), felt.get("cot_whole_run")
    err = 100.0 * (cot_p - cot_f) / cot_f if cot_p is not None and cot_f else None
    return {
        "cot_predicted": cot_p,
        "cot_felt": cot_f,
        "cot_felt_truth": felt.get("cot_whole_run_truth"),
        "cot_error_pct": round(err, 2) if err is not None else None,
        "cot_within_10pct": abs(err) <= 10.0 if err is not None else None,
        "slips_predicted": pred.get("expected_slip_events"),
        "slips_felt_truth": felt.get("gt_slips"),
        "slips_detected": felt.get("detected_slips"),
    }


def pool_rows(rows: list[dict]) -> dict[str, Any]:
    """Several fresh runs of one route: booleans counted, numbers averaged, text kept from the first."""
    out: dict[str, Any] = {"runs": len(rows)}
    for k in {k for r in rows for k in r}:
        vals = [r.get(k) for r in rows]
        if any(isinstance(v, str) for v in vals):
            out[k] = next(v for v in vals if isinstance(v, str))
        elif any(isinstance(v, bool) for v in vals):
            out[k] = sum(bool(v) for v in vals)
        else:
            out[k] = fmean(vals)
    return out


def summary(per_seed: dict[str, Any]) -> dict[str, Any]:
    done = [e for e in per_seed.values() if e.get("planned_beat_straight")]
    crit = ("energy", "cot", "gt_slips", "giim_mean", "giim_min_cell", "cost_on_own_map", "time")
    out: dict[str, Any] = {
        "seeds_planned": len(done),
        "seeds": len(per_seed),
        "planned_beat_straight_count": {
            c: sum(bool(e["planned_beat_straight"].get(c)) for e in done) for c in crit
        },
    }
    for name in ("planned", "straight"):
        pvf = [e["predicted_vs_felt"][name] for e in done if e.get("predicted_vs_felt", {}).get(name)]
        errs = [p["cot_error_pct"] for p in pvf if p["cot_error_pct"] is not None]
        out[f"{name}_predicted_vs_felt"] = {
            "cot_error_pct_mean_abs": fmean(abs(e) for e in errs),
            "cot_within_10pct": sum(abs(e) <= 10.0 for e in errs),
            "seeds": len(errs),
            "slips_predicted_mean": fmean(p["slips_predicted"] for p in pvf),
            "slips_felt_truth_mean": fmean(p["slips_felt_truth"] for p in pvf),
        }
        rows = [e["experienced"][name] for e in done if e["experienced"].get(name)]
        preds = [e["predicted"][name] for e in done if e["predicted"].get(name)]
        out[name] = {
            "experienced_mean": {
                k: fmean(r.get(k) for r in rows)
                for k in (
                    "cot_whole_run",
                    "cot_whole_run_truth",
                    "energy_m",
                    "gt_slips",
                    "detected_slips",
                    "giim_mean",
                    "giim_min_cell",
                    "giam_mean",
                    "distance_m",
                    "sim_seconds",
                    "cost_on_own_map",
                )
            },
            "falls": sum(int(r.get("fell") or 0) for r in rows),
            "predicted_mean": {
                k: fmean(p.get(k) for p in preds)
                for k in (
                    "mean_cot",
                    "expected_slip_events",
                    "mean_giim",
                    "mean_giam",
                    "length_m",
                    "unknown_fraction",
                    "inferred_fraction",
                )
            },
        }
    return out
