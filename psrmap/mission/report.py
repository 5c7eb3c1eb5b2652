"""The mission summary as JSON and as the report printed at the end (with the route table)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from psrmap.mission.config import MissionConfig

__all__ = ["config_json", "deltas_sent", "json_default", "print_report"]


def deltas_sent(scout_summary: dict[str, Any]) -> int:
    """How many distinct deltas a scout published (its `--json` summary's `map.publisher.sent`)."""
    return int(scout_summary.get("map", {}).get("publisher", {}).get("sent", 0))


def config_json(cfg: MissionConfig) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(cfg), default=json_default))


def json_default(o: object) -> object:
    if isinstance(o, Path):
        return str(o)
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)


def print_report(summary: dict[str, Any]) -> None:
    print()
    print(f"Mission finished in {summary['wall_seconds']} s — run folder {summary['run_dir']}")
    st = summary.get("status", {})
    print(
        f"  map server: {st.get('merged')} deltas merged, {st.get('cells')} cells, rejected {st.get('rejected')}"
    )
    for sid, s in summary.get("scouts", {}).items():
        if "error" in s:
            print(f"  {sid}: {s['error']}")
            continue
        print(
            f"  {sid}: {s.get('distance_m', float('nan')):.1f} m in {s.get('sim_seconds', float('nan')):.0f} s, "
            f"fell={s.get('fell')}, reached_goal={s.get('reached_goal')}, deltas={deltas_sent(s)}, "
            f"slip events felt={s.get('map', {}).get('slip_events')}, "
            f"drift {s.get('drift_xy_pct')} % / z {s.get('drift_z_m')} m / yaw {s.get('drift_yaw_deg')}°, "
            f"position error max {s.get('pos_error_max_m')} m, inside 3σ {s.get('inside_3sigma_frac')} "
            f"({s.get('sensors')} sensors, localization {s.get('localization')})"
        )
    for pair, a in (summary.get("elevation_agreement") or {}).items():
        print(
            f"  own maps {pair}: {a['cells']} shared elevation cells, differ by {a['mean_diff_m']:+.3f} m "
            f"(RMS {a['rms_diff_m']:.3f} m)"
        )
    plan = summary.get("plan") or {}
    if "error" in plan:
        print(f"  plan: {plan['error']}")
    else:
        moved = plan.get("goal_moved_m") or 0.0
        print(
            f"  plan: {plan.get('length_m', float('nan')):.1f} m, cost {plan.get('cost', float('nan')):.2f}"
            + (
                f" (goal cell forbidden by the map: moved {moved:.2f} m to the nearest passable cell)"
                if moved
                else ""
            )
        )
    comparison = summary.get("comparison") or {}
    if comparison.get("routes"):
        print()
        from consumer_planner.table import route_table  # lazy: the planner package loads its numba kernels

        print(route_table(comparison["routes"]))
        print(
            "(routes costed on the slip layer as the map holds it; the planner itself spreads slip rates over "
            f"{(summary.get('plan') or {}).get('slip_spread_m', '?')} m when it plans)"
        )
    elif "error" in comparison:
        print(f"  comparison: {comparison['error']}")
    if summary.get("map_png"):
        print(f"\nMap picture: {summary['map_png']}")
    if summary.get("recording"):
        print(f"Recording: rerun {summary['recording']}")
