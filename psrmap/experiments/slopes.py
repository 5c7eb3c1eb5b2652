"""`psrmap experiment slopes`: CoT, GIIM and GIAM against inclination, −20…+20° in 5° steps.

Sign convention (the paper's figure): **negative = uphill, positive = downhill**. Each ramp run of angle α
gives three points: the up-ramp's cells at −α, the platform's at 0°, the down-ramp's at +α (ramps on
uniform regolith, the same runs as `ramps` without a patch — shared through the run cache). A metric's value
at a point is the mean over that segment's map cells (the paper averages its gridmap layers).

Fits: 4th-degree polynomials (`numpy.polyfit`) over every run's points. GIIM and GIAM are shown under both
conventions: the default margins over the four most recent footholds, and the paper-compatible variant
(`giim_paper`, `giam_paper`). The paper's trends (docs/results.md, slope sweep) are checked on the fits and on the
per-angle means.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from psrmap.experiments import ramps
from psrmap.experiments.common import RunPool, RunSpec, fmean, fstd
from psrmap.experiments.config import ExperimentConfig

__all__ = ["add_arguments", "analyse", "fit", "points", "run", "specs", "trends"]

NAME = "slopes"
DEFAULT_SEEDS = "0"
DEFAULT_RUNS = 4
METRICS = ("cot_mean", "giim_mean", "giam_mean", "giim_paper_mean", "giam_paper_mean")
SEGMENT_SIGN = {"up": -1.0, "flat": 0.0, "down": 1.0}  # paper's figure: negative = uphill
FIT_DEGREE = 4


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Uses the ramps options (`--angles`)."""


def specs(cfg: ExperimentConfig) -> list[RunSpec]:
    return ramps.run_specs(cfg, cfg.angles, slippery=False)


def points(runs: list[dict]) -> list[dict[str, Any]]:
    out = []
    for r in runs:
        segs = r["scores"].get("segments") or {}
        a = r["spec"]["slope_deg"]
        for label, sign in SEGMENT_SIGN.items():
            e = segs.get(label)
            if e:
                out.append(
                    {
                        "inclination_deg": sign * a,
                        "segment": label,
                        "ramp_deg": a,
                        "run": r["spec"]["label"],
                        **{m: e.get(m) for m in METRICS},
                    }
                )
    return out


def fit(pts: list[dict], metric: str, degree: int = FIT_DEGREE) -> dict[str, Any] | None:
    xy = [(p["inclination_deg"], p[metric]) for p in pts if p[metric] is not None and np.isfinite(p[metric])]
    if not xy:
        return None
    x, y = np.array(xy).T
    deg = min(degree, len(np.unique(x)) - 1)
    if deg < 1:
        return None
    coef = np.polyfit(x, y, deg)
    resid = y - np.polyval(coef, x)
    return {
        "degree": int(deg),
        "coef_high_to_low": coef.tolist(),
        "rmse": float(np.sqrt(np.mean(resid**2))),
        "x_range": [float(x.min()), float(x.max())],
        "points": int(len(x)),
    }


def _grid(f: dict) -> tuple[np.ndarray, np.ndarray]:
    xs = np.linspace(f["x_range"][0], f["x_range"][1], 401)
    return xs, np.polyval(f["coef_high_to_low"], xs)


def _mean_over(xs: np.ndarray, ys: np.ndarray, lo: float, hi: float) -> float | None:
    m = (xs >= lo) & (xs <= hi)
    return float(ys[m].mean()) if m.any() else None


def trends(fits: dict[str, Any], means: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The paper's slope-sweep trends checked on the fits (and the per-angle means beside them)."""
    out: dict[str, Any] = {}
    f = fits.get("cot_mean")
    if f:
        xs, ys = _grid(f)
        i = int(np.argmin(ys))
        interior = 0 < i < len(xs) - 1
        out["cot"] = {
            "fit_min_at_deg": float(xs[i]),
            "min_on_5_10_descent": bool(5.0 <= xs[i] <= 10.0),
            "rises_toward_both_ends": bool(interior and ys[0] > ys[i] and ys[-1] > ys[i]),
            "mean_min_at_deg": _arg(means, "cot_mean", min),
        }
    for name in ("giim", "giam"):
        for conv, metric in (("four_footholds", f"{name}_mean"), ("paper", f"{name}_paper_mean")):
            f = fits.get(metric)
            if not f:
                continue
            xs, ys = _grid(f)
            i = int(np.argmax(ys))
            entry: dict[str, Any] = {
                "fit_max_at_deg": float(xs[i]),
                "mean_max_at_deg": _arg(means, metric, max),
            }
            if name == "giim":
                entry["max_on_moderate_uphill"] = bool(-15.0 <= xs[i] <= -5.0)
                entry["falls_toward_both_ends"] = bool(0 < i < len(xs) - 1)
            else:
                desc, asc = _mean_over(xs, ys, 0.1, 15.0), _mean_over(xs, ys, -15.0, -0.1)
                entry["descent_mean_within_15"] = desc
                entry["ascent_mean_within_15"] = asc
                entry["higher_on_descents_within_15"] = (
                    None if desc is None or asc is None else bool(desc > asc)
                )
                lo, hi = xs[0], xs[-1]
                if lo <= -20 + 1e-6 and hi >= 20 - 1e-6:
                    v = np.polyval(f["coef_high_to_low"], [-20.0, -15.0, 15.0, 20.0])
                    entry["falls_beyond_15"] = bool(v[3] < v[2] and v[0] < v[1])
                else:
                    entry["falls_beyond_15"] = None
            out[f"{name}_{conv}"] = entry
    return out


def _arg(means: dict[str, dict[str, Any]], metric: str, fn) -> float | None:
    vals = {float(k): v[metric]["mean"] for k, v in means.items() if v[metric]["mean"] is not None}
    return fn(vals, key=vals.get) if vals else None


def analyse(cfg: ExperimentConfig, runs: list[dict], out_dir: Path) -> dict[str, Any]:
    from psrmap.experiments import plots

    pts = points(runs)
    incl = sorted({p["inclination_deg"] for p in pts})
    means: dict[str, dict[str, Any]] = {}
    for x in incl:
        sel = [p for p in pts if p["inclination_deg"] == x]
        means[f"{x:g}"] = {
            m: {
                "mean": fmean(p[m] for p in sel),
                "std": fstd(p[m] for p in sel),
                "n": sum(p[m] is not None for p in sel),
            }
            for m in METRICS
        }
    fits = {m: fit(pts, m) for m in METRICS}
    fig = plots.slopes(out_dir / "slopes.png", pts, fits, METRICS)
    return {
        "experiment": NAME,
        "convention": "inclination_deg: negative = uphill, positive = downhill (the paper's figure)",
        "protocol": {
            "angles_deg": list(cfg.angles),
            "seeds": list(cfg.seeds),
            "runs_per_seed": cfg.runs,
            "segment_cells": "up-ramp → −α, platform → 0, down-ramp → +α; mean over the segment's cells",
            "fit": f"numpy.polyfit degree {FIT_DEGREE} over every run's points",
        },
        "paper_trends": {
            "cot": "U shape, minimum on a 5–10° descent, rising toward both ends",
            "giim": "highest on moderate uphill (≈ −10°), falling toward both ends",
            "giam": "higher on descents within ±15°, falling beyond",
        },
        "means": means,
        "fits": fits,
        "trends": trends(fits, means),
        "points": pts,
        "figures": [fig.name] if fig else [],
    }


def run(cfg: ExperimentConfig, pool: RunPool, out_dir: Path) -> dict[str, Any]:
    return analyse(cfg, pool.run(specs(cfg), desc=NAME), out_dir)
