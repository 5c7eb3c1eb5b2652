from __future__ import annotations

import math

from consumer_planner.table import COLUMNS, route_table, term_lines


def _route(name, **b):
    base = {"length_m": 10.0, "cost": 12.0, "expected_slip_events": 0.5, "mean_cot": 1.2, "min_giim": 0.3,
            "mean_giim": 0.5, "min_giam": 0.6, "mean_giam": 0.9, "max_slope_deg": 7.0, "unknown_fraction": 0.1,
            "inferred_fraction": 0.0, "terms": {"length": 10.0, "cot": 2.0, "slip": 0.0}}  # fmt: skip
    base.update(b)
    return {"name": name, "breakdown": base}


def test_one_row_per_route_with_every_column_and_dashes_for_missing_values():
    table = route_table([_route("direct"), _route("west", mean_cot=math.nan, min_giim=None)])
    lines = table.splitlines()
    assert len(lines) == 4 and set(lines[1]) == {"-"}
    assert all(h in lines[0] for h, _, _ in COLUMNS) and "inferred %" not in lines[0]
    assert lines[2].startswith("direct") and "1.20" in lines[2] and "10%" in lines[2]
    assert lines[3].count("—") == 2  # CoT, and GIIM min/mean (one of its two values is missing)


def test_inferred_column_only_when_a_route_used_inferred_cells():
    assert "inferred %" in route_table([_route("a"), _route("b", inferred_fraction=0.25)]).splitlines()[0]


def test_term_lines_list_the_nonzero_terms():
    lines = term_lines([_route("a")])
    assert lines[1] == "  a: length 10.00, cot 2.00"
