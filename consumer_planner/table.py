"""The route comparison as a fixed-width text table: one format for `psrmap compare` and the mission.

Rows are routes in their JSON form (`{"name": ..., "breakdown": {...}}`, what `compare --json` prints and
the mission reads); a value that is missing or not finite prints as "—". The "inferred %" column appears
only when some route crossed cells whose values were inferred (`--unknown infer`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = ["COLUMNS", "route_table", "term_lines"]

COLUMNS: tuple[tuple[str, str | tuple[str, str], str], ...] = (
    ("route", "name", "{}"),
    ("length m", "length_m", "{:.1f}"),
    ("cost", "cost", "{:.1f}"),
    ("exp. slips", "expected_slip_events", "{:.1f}"),
    ("CoT", "mean_cot", "{:.2f}"),
    ("GIIM min/mean rad", ("min_giim", "mean_giim"), "{:.2f}/{:.2f}"),
    ("GIAM min/mean m/s²", ("min_giam", "mean_giam"), "{:.2f}/{:.2f}"),
    ("max slope °", "max_slope_deg", "{:.1f}"),
    ("unknown %", "unknown_fraction", "{:.0%}"),
)
_INFERRED = ("inferred %", "inferred_fraction", "{:.0%}")


def _cell(route: Mapping[str, Any], key: str | tuple[str, str], fmt: str) -> str:
    b = {"name": route.get("name"), **route.get("breakdown", {})}
    vals = [b.get(k) for k in (key if isinstance(key, tuple) else (key,))]
    if any(v is None or (isinstance(v, float) and not math.isfinite(v)) for v in vals):
        return "—"
    return fmt.format(*vals)


def route_table(routes: Sequence[Mapping[str, Any]]) -> str:
    """The routes as a table: a header, a rule, one row per route."""
    columns = list(COLUMNS)
    if any((r.get("breakdown", {}).get("inferred_fraction") or 0) > 0 for r in routes):
        columns.append(_INFERRED)
    rows = [[h for h, _, _ in columns]]
    rows += [[_cell(r, k, f) for _, k, f in columns] for r in routes]
    widths = [max(len(row[i]) for row in rows) for i in range(len(columns))]
    lines = [
        "  ".join(v.rjust(w) if i else v.ljust(w) for i, (v, w) in enumerate(zip(row, widths, strict=True)))
        for row in rows
    ]
    lines.insert(1, "-" * len(lines[0]))
    return "\n".join(lines)


def term_lines(routes: Sequence[Mapping[str, Any]]) -> list[str]:
    """The cost of each route split by term (the non-zero ones)."""
    out = ["cost by term (per route): "]
    for r in routes:
        terms = r.get("breakdown", {}).get("terms", {})
        out.append(f"  {r.get('name')}: " + ", ".join(f"{k} {v:.2f}" for k, v in terms.items() if v))
    return out
