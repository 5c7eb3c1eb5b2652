"""Markdown tables from an `experiment all` folder, for docs/results.md (numbers copied by code, not by hand).

python -m psrmap.experiments.report DIR > tables.md
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

__all__ = ["tables"]


def _f(v: Any, nd: int = 3) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    return f"{v:.{nd}f}"


def _ms(d: dict | None, nd: int = 2) -> str:
    if not d or d.get("mean") is None:
        return "–"
    return f"{d['mean']:.{nd}f} ± {d['std']:.{nd}f}" if d.get("std") else f"{d['mean']:.{nd}f}"


def _table(head: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


_EST_HEAD = [
    "drift xy % (mean / max)",
    "drift z [m]",
    "drift yaw [°]",
    "elev. RMSE estimate / exact [m]",
    "CoT estimate / truth",
    "CoT error % (mean / max)",
    "pos. error max [m] (mean / max)",
    "yaw error max [°]",
    "NEES xy (2 = consistent)",
    "inside 3σ (min / mean)",
    "falls / runs",
]


def _est_row(e: dict) -> list[str]:
    return [
        f"{_f(e.get('drift_xy_pct_mean'), 2)} / {_f(e.get('drift_xy_pct_max'), 2)}",
        _f(e.get("drift_z_m_mean_abs"), 3),
        _f(e.get("drift_yaw_deg_mean_abs"), 2),
        f"{_f(e.get('elevation_rmse_m'), 4)} / {_f(e.get('elevation_rmse_exact_m'), 4)}",
        f"{_f(e.get('cot_whole_run'), 3)} / {_f(e.get('cot_whole_run_truth'), 3)}",
        f"{_f(e.get('cot_error_pct_mean'), 1)} / {_f(e.get('cot_error_pct_max'), 1)}",
        f"{_f(e.get('pos_error_max_m_mean'), 3)} / {_f(e.get('pos_error_max_m_max'), 3)}",
        _f(e.get("yaw_error_max_deg_max"), 2),
        _f(e.get("nees_pos_mean"), 2),
        f"{_f(e.get('inside_3sigma_frac_min'), 3)} / {_f(e.get('inside_3sigma_frac_mean'), 3)}",
        f"{e.get('falls')} / {e.get('runs')}",
    ]


def estimation_table(groups: dict[str, dict], label: str) -> str:
    """The state estimate's honesty per group of runs (`common.estimation_summary`)."""
    rows = [[k] + _est_row(e) for k, e in groups.items() if e]
    return (
        "State estimate (IMU + leg odometry EKF) against ground truth, and the figures it changes beside the "
        "same estimators on the exact state:\n\n" + _table([label] + _EST_HEAD, rows)
    )


def ramps_tables(r: dict) -> str:
    parts = [estimation_table({f"{a}°": e.get("estimation") for a, e in r["by_angle"].items()}, "slope")]
    rows = []
    for a, e in r["by_angle"].items():
        for cond in ("plain", "slippery"):
            if cond not in e:
                continue
            el = e[cond]["elevation"]
            rows.append(
                [f"{a}°", cond]
                + [
                    f"{_f(el[res]['rmse_mean_only_m'], 4)} / {_f(el[res]['rmse_m'], 4)} / {_f(el[res].get('rmse_plane_m'), 4)}"
                    for res in ("0.4", "0.2", "0.1")
                ]
                + [
                    _f(el["0.4"].get("rmse_ramps_mean_only_m"), 4)
                    + " / "
                    + _f(el["0.4"].get("rmse_ramps_plane_m"), 4)
                ]
            )
    parts.append(
        "Elevation RMSE [m] against the exact ramp at cell centres — mean (paper's estimate) / map value / "
        "scout's plane fit:\n\n"
        + _table(["α", "runs", "0.4 m", "0.2 m", "0.1 m", "0.4 m, ramp cells only (mean / plane)"], rows)
    )
    rows = []
    for a, e in r["by_angle"].items():
        for cond in ("plain", "slippery"):
            if cond not in e:
                continue
            s = e[cond]["slip"]
            cells = []
            for w in ("honest", "exact", "paper"):
                x = s[w]
                cells.append(
                    f"{_f(x['precision'], 2)} / {_f(x['recall'], 2)} ({x['tp']}/{x['detected']}/{x['truth']})"
                )
            mu = f" μ {e[cond]['patch_mu']:g}" if cond == "slippery" else ""
            rows.append([f"{a}°", cond + mu, *cells, _f(s.get("gt_in_patch_share"), 2)])
    parts.append(
        "Slip detection pooled over the runs — precision / recall (true positives / detections / true slips):\n\n"
        + _table(
            ["α", "runs", "honest state", "exact state", "paper-form detector", "true slips in patch"], rows
        )
    )
    rows = []
    for a, e in r["by_angle"].items():
        if "plain" not in e:
            continue
        sg = e["plain"]["segments"]
        for seg in ("up", "flat", "down"):
            x = sg[seg]
            rows.append(
                [
                    f"{a}°",
                    seg,
                    _f(x["cot_mean"], 2),
                    _f(x["giim_mean"], 3),
                    _f(x["giam_mean"], 3),
                    _f(x["giim_paper_mean"], 3),
                    _f(x["giam_paper_mean"], 3),
                    str(x["gt_slips"]),
                    str(x["slip_events"]),
                ]
            )
    parts.append(
        "Per segment, uniform regolith (means over the segment's cells, runs averaged):\n\n"
        + _table(
            [
                "α",
                "segment",
                "CoT",
                "GIIM [rad]",
                "GIAM [m/s²]",
                "GIIM paper",
                "GIAM paper",
                "true slips",
                "detected",
            ],
            rows,
        )
    )
    rows = [[f"{a}°", *(_f(v) for v in t.values())] for a, t in r["trends"].items()]
    head = ["α", *next(iter(r["trends"].values())).keys()] if r["trends"] else ["α"]
    parts.append("The paper's ramp-figure trends per angle (uniform regolith):\n\n" + _table(head, rows))
    return "\n\n".join(parts)


def slopes_tables(r: dict) -> str:
    rows = []
    for x, m in sorted(r["means"].items(), key=lambda kv: float(kv[0])):
        rows.append(
            [x]
            + [
                _ms(m[k], 3)
                for k in ("cot_mean", "giim_mean", "giam_mean", "giim_paper_mean", "giam_paper_mean")
            ]
        )
    parts = [
        "Means per inclination (negative = uphill), ± std over runs:\n\n"
        + _table(["incl. [°]", "CoT", "GIIM [rad]", "GIAM [m/s²]", "GIIM paper", "GIAM paper"], rows)
    ]
    rows = []
    for k, t in r["trends"].items():
        rows.append(
            [
                k,
                ", ".join(
                    f"{kk}: {_f(vv, 1 if kk.endswith('deg') else 3) if isinstance(vv, float) else _f(vv)}"
                    for kk, vv in t.items()
                ),
            ]
        )
    parts.append("Trend checks on the 4th-degree fits:\n\n" + _table(["metric", "result"], rows))
    return "\n\n".join(parts)


def lunar_tables(r: dict) -> str:
    routes = ("direct", "west", "east")
    t, p, m = r["table"], r["paper_table"], r["merged_map_table"]
    est = {
        f"seed {sd} {x}": s.get("estimation", {}).get(x) for sd, s in r["per_seed"].items() for x in routes
    }
    rows = [
        ["total slips (slip-layer events)"]
        + [f"{_ms(t[x]['total_slips'], 1)} ({p['total_slips'][x]})" for x in routes],
        ["true slips (ground truth)"] + [_ms(t[x]["gt_slips"], 1) for x in routes],
        ["overall CoT (mean over cells)"]
        + [f"{_ms(t[x]['overall_cot'])} ({p['overall_cot'][x]})" for x in routes],
        ["CoT of the whole walk"] + [_ms(t[x]["cot_whole_run"]) for x in routes],
        ["avg GIIM, four footholds [rad]"]
        + [f"{_ms(t[x]['avg_giim'])} ({p['avg_giim'][x]})" for x in routes],
        ["avg GIIM, paper variant [rad]"] + [_ms(t[x]["avg_giim_paper"]) for x in routes],
        ["avg GIAM, four footholds [m/s²]"]
        + [f"{_ms(t[x]['avg_giam'])} ({p['avg_giam'][x]})" for x in routes],
        ["avg GIAM, paper variant [m/s²]"] + [_ms(t[x]["avg_giam_paper"]) for x in routes],
        ["slip precision / recall (honest)"]
        + [f"{_ms(t[x]['slip_precision'])} / {_ms(t[x]['slip_recall'])}" for x in routes],
        ["falls / runs"] + [f"{t[x]['fell']} / {t[x]['runs']}" for x in routes],
    ]
    parts = [
        estimation_table(est, "run"),
        "Per trajectory, from its own map; ours as mean ± std over terrain seeds, the paper's in brackets:\n\n"
        + _table(["metric", "direct (paper: traj. 1)", "west (traj. 2)", "east (traj. 3)"], rows),
    ]
    rows = [
        ["expected slips (planner)"] + [_f(m[x]["total_slips"], 1) for x in routes],
        ["mean CoT"] + [_f(m[x]["overall_cot"], 2) for x in routes],
        ["mean GIIM [rad]"] + [_f(m[x]["avg_giim"], 3) for x in routes],
        ["mean GIAM [m/s²]"] + [_f(m[x]["avg_giam"], 3) for x in routes],
    ]
    parts.append(
        "The same table by the planner's comparison on the merged map of all trajectories (mean over seeds):\n\n"
        + _table(["metric", "direct", "west", "east"], rows)
    )
    rows = []
    for seed, s in r["per_seed"].items():
        for x in routes:
            tr, mm = s["trajectories"][x], s["merged_map_compare"][x]
            rows.append(
                [
                    seed,
                    x,
                    _ms(tr["total_slips"], 0),
                    _f(mm["total_slips"], 1),
                    _ms(tr["gt_slips"], 0),
                    _ms(tr["overall_cot"]),
                    _f(mm["overall_cot"], 2),
                    _ms(tr["avg_giim"], 3),
                    _f(mm["avg_giim"], 3),
                    f"{tr['fell']}",
                ]
            )
    parts.append(
        "Per seed — own map vs merged map (planner):\n\n"
        + _table(
            [
                "seed",
                "route",
                "slips own",
                "slips merged",
                "true slips",
                "CoT own",
                "CoT merged",
                "GIIM own",
                "GIIM merged",
                "fell",
            ],
            rows,
        )
    )
    return "\n\n".join(parts)


def utility_tables(r: dict) -> str:
    proto = r.get("protocol", {})
    head = (
        f"Planner: `--unknown {proto.get('unknown')}`, slip spread "
        f"{_f(proto.get('slip_spread_m', proto.get('inflate_slip_m')), 1)} m, weights {proto.get('weights')}."
    )
    rows = []
    for seed, e in r["per_seed"].items():
        if "error" in e:
            rows.append([seed, "–", e["error"], *["–"] * 9])
            continue
        for name in ("planned", "straight"):
            p, x = e["predicted"].get(name) or {}, e["experienced"].get(name) or {}
            rows.append(
                [
                    seed,
                    name,
                    f"{_f(p.get('length_m'), 1)} / {_f(x.get('distance_m'), 1)}",
                    f"{_f(p.get('mean_cot'), 2)} / {_f(x.get('cot_whole_run'), 2)}",
                    _f(x.get("energy_m"), 1),
                    f"{_f(p.get('expected_slip_events'), 1)} / {_f(x.get('gt_slips'), 0)} / {_f(x.get('detected_slips'), 0)}",
                    f"{_f(p.get('mean_giim'), 3)} / {_f(x.get('giim_mean'), 3)}",
                    f"{_f(p.get('min_giim'), 3)} / {_f(x.get('giim_min_cell'), 3)}",
                    f"{_f(p.get('mean_giam'), 3)} / {_f(x.get('giam_mean'), 3)}",
                    _f(p.get("unknown_fraction"), 2),
                    _f(x.get("cost_on_own_map"), 1),
                    str(x.get("fell")),
                ]
            )
    parts = [
        head,
        "Predicted (scouts' map, planner breakdown) / experienced (fresh robot) per route:\n\n"
        + _table(
            [
                "seed",
                "route",
                "length [m] pred / walked",
                "CoT pred / exp",
                "energy [m]",
                "slips pred / true / detected",
                "GIIM mean pred / exp",
                "GIIM worst cell pred / exp",
                "GIAM mean pred / exp",
                "unknown share",
                "cost on own map",
                "fell",
            ],
            rows,
        ),
    ]
    rows = []
    for seed, e in r["per_seed"].items():
        b = e.get("planned_beat_straight")
        if b:
            rows.append(
                [
                    seed,
                    *(
                        _f(b.get(k))
                        for k in (
                            "energy",
                            "cot",
                            "gt_slips",
                            "giim_mean",
                            "giim_min_cell",
                            "cost_on_own_map",
                            "time",
                        )
                    ),
                ]
            )
    parts.append(
        "Did the planned route beat the straight one in what the fresh robot experienced?\n\n"
        + _table(
            [
                "seed",
                "less energy",
                "lower CoT",
                "fewer true slips",
                "higher mean GIIM",
                "higher worst-cell GIIM",
                "lower cost on own map",
                "faster",
            ],
            rows,
        )
    )
    rows = []
    for seed, e in r["per_seed"].items():
        ag = (e.get("map_agreement_along_route") or {}).get("planned") or {}
        rows.append(
            [seed]
            + [
                f"{_f((ag.get(k) or {}).get('pearson_r'), 2)} / {_f((ag.get(k) or {}).get('mean_abs_diff'), 3)} ({(ag.get(k) or {}).get('cells_both', 0)})"
                for k in ("cot", "giim", "giam", "elevation")
            ]
        )
    parts.append(
        "Scouts' map vs the fresh robot's own map along the planned route — Pearson r / mean |diff| (cells):\n\n"
        + _table(["seed", "CoT", "GIIM", "GIAM", "elevation"], rows)
    )
    return "\n\n".join(parts)


def tables(folder: Path) -> str:
    folder = Path(folder)
    out = []
    top = folder / "results.json"
    if top.is_file():
        t = json.loads(top.read_text())["timing"]
        out.append(
            f"Timing: {t['wall_seconds']} s wall, {t['runs_walked']} runs, {t['worker_seconds']} worker-seconds, {t['workers']} workers."
        )
    for name, fn in (
        ("ramps", ramps_tables),
        ("slopes", slopes_tables),
        ("lunar", lunar_tables),
        ("utility", utility_tables),
    ):
        p = folder / name / "results.json"
        if p.is_file():
            out.append(f"## {name}\n\n" + fn(json.loads(p.read_text())))
    return "\n\n".join(out) + "\n"


if __name__ == "__main__":
    sys.stdout.write(tables(Path(sys.argv[1])))
