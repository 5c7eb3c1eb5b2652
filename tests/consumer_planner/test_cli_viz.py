"""`psrmap plan` / `psrmap compare` on a saved .npz map, and the Rerun recording they write."""

from __future__ import annotations

import json

import numpy as np
import pytest

from consumer_planner.cost_config import Weights
from psrmap.cli import main


@pytest.fixture
def npz(tmp_path):
    h, w = 12, 16
    n = np.full((h, w), 10.0)
    n[:, 7:9] = 0.0  # an unexplored band
    arrays = {"res": 0.5, "ix0": -2, "iy0": -2, "w": w, "h": h}
    for layer, v in (("cot", 1.2), ("giim", 0.5), ("giam", 0.8)):
        arrays[f"{layer}/n"] = n
        arrays[f"{layer}/value"] = np.where(n > 0, v, np.nan)
    arrays["slip/n"] = n
    arrays["slip/events"] = np.where(n > 0, 1.0, 0.0)
    path = tmp_path / "map.npz"
    np.savez(path, **arrays)
    return path


def test_plan_json_has_path_length_cost_breakdown(npz, tmp_path, capsys):
    rrd = tmp_path / "plan.rrd"
    args = ["plan", "--npz", str(npz), "--from=-0.5,-0.5", "--to", "6.5,3.5", "--unknown", "infer"]
    assert main([*args, "--json", "--weights", "cot=2,slip=1", "--rrd", str(rrd)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"path", "length_m", "cost", "breakdown"} <= set(out)
    assert out["weights"]["cot"] == 2.0 and out["unknown"] == "infer"
    assert out["path"][0] == [-0.25, -0.25] and out["path"][-1] == [6.75, 3.75]
    assert out["breakdown"]["inferred_fraction"] > 0
    assert sum(out["breakdown"]["terms"].values()) == pytest.approx(out["cost"])
    assert rrd.stat().st_size > 0


def test_compare_table_and_json(npz, capsys):
    routes = ["--route", "-0.5,-0.5 6.5,3.5", "--route", "-0.5,-0.5 -0.5,3.5 6.5,3.5"]
    assert main(["compare", "--npz", str(npz), *routes]) == 0
    table = capsys.readouterr().out
    assert "route0" in table and "route1" in table and "GIIM min/mean" in table
    assert main(["compare", "--npz", str(npz), *routes, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in out["routes"]] == ["route0", "route1"]
    assert out["routes"][1]["length_m"] > out["routes"][0]["length_m"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--unknown", "guess"], "forbid, penalty, infer"),
        (["--weights", "cots=1"], "distance, cot, slip, giim, giam, slope, confidence"),
        (["--slip-spread=-0.4"], "0 <= M < inf (0 = the raw slip layer)"),
        (["--slip-spread", "wide"], "0 <= M < inf (0 = the raw slip layer)"),
        (["--watch"], "--watch follows map servers: give --connect and --map, not --npz"),
    ],
)
def test_bad_options_name_valid_values(npz, capsys, extra, message):
    with pytest.raises(SystemExit) as exc:
        main(["plan", "--npz", str(npz), "--from", "0,0", "--to", "1,1", *extra])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_plan_errors_are_readable(npz, capsys):
    with pytest.raises(SystemExit, match=r"outside the map box x -1..7, y -1..5 m"):
        main(["plan", "--npz", str(npz), "--from", "0,0", "--to", "50,1"])
    with pytest.raises(SystemExit, match="no passable route"):
        main(["plan", "--npz", str(npz), "--from", "0,0", "--to", "6,1", "--unknown", "forbid"])
    with pytest.raises(SystemExit):
        main(["plan", "--from", "0,0", "--to", "6,1"])
    assert "give either --connect ENDPOINT (with --map ID) or --npz FILE" in capsys.readouterr().err


def test_compare_names_routes_in_order(npz, capsys):
    routes = ["--route", "-0.5,-0.5 6.5,3.5", "--route", "-0.5,-0.5 -0.5,3.5 6.5,3.5"]
    assert main(["compare", "--npz", str(npz), *routes, "--name", "direct", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in out["routes"]] == ["direct", "route1"]
    with pytest.raises(SystemExit) as exc:
        main(["compare", "--npz", str(npz), routes[0], routes[1], "--name", "a", "--name", "b"])
    assert exc.value.code == 2
    assert "at most one name per route" in capsys.readouterr().err


def test_slip_spread_option_reaches_the_cost(npz, capsys):
    """The fixture's slip rate (0.1) spreads into the unexplored band: penalty + slip term there."""
    route = ["--route", "-0.5,-0.5 6.5,-0.5"]
    costs = {}
    for spread in ("0", "0.8"):
        argv = [
            "compare",
            "--npz",
            str(npz),
            *route,
            "--unknown",
            "penalty",
            "--slip-spread",
            spread,
            "--json",
        ]
        assert main(argv) == 0
        out = json.loads(capsys.readouterr().out)
        assert out["slip_spread_m"] == float(spread)
        costs[spread] = out["routes"][0]["breakdown"]
    assert costs["0.8"]["unknown_fraction"] == costs["0"]["unknown_fraction"] > 0
    assert costs["0.8"]["expected_slip_events"] > costs["0"]["expected_slip_events"]
    assert costs["0.8"]["terms"]["slip"] == pytest.approx(
        Weights().slip * costs["0.8"]["expected_slip_events"]
    )
    assert main(["compare", "--npz", str(npz), *route]) == 0
    assert "slip spread 0.8 m" in capsys.readouterr().out


def test_plan_recording_is_placed_draped_and_readable(npz, tmp_path, capsys):
    """The cost grid lands on the map box (row 0 of the image = the north edge, as Rerun draws it), the path
    is draped on the map's elevation, the breakdown is a Markdown table, all at the given sim_time."""
    from rerun.chunk import RrdReader

    data = dict(np.load(npz))
    for key in [k for k in data if k.endswith("/n")]:
        data[key][-2:, :] = 0.0  # the two northmost rows (iy 10, 11: y 4..5 m) unexplored
    data["elevation/n"] = data["cot/n"].copy()
    data["elevation/value"] = np.where(data["elevation/n"] > 0, 0.7, np.nan)
    np.savez(npz, **data)
    rrd = tmp_path / "plan.rrd"
    assert (
        main(
            [
                "plan",
                "--npz",
                str(npz),
                "--from=-0.5,-0.5",
                "--to",
                "6.5,3.5",
                "--unknown",
                "penalty",
                "--json",
                "--rrd",
                str(rrd),
                "--sim-time",
                "42.5",
            ]
        )
        == 0
    )
    capsys.readouterr()
    cols: dict[str, dict] = {}
    for chunk in RrdReader(rrd).stream():
        rb = chunk.to_record_batch()
        if not chunk.is_static:
            assert "sim_time" in chunk.timeline_names, chunk.entity_path
            t = rb.column(rb.schema.names.index("sim_time")).cast("int64").to_pylist()
            assert t == [42_500_000_000] * len(t)
        cols.setdefault(chunk.entity_path, {}).update(
            {n: rb.column(i).to_pylist()[-1] for i, n in enumerate(rb.schema.names) if ":" in n}
        )
    cost = cols["/map/cost"]
    assert np.ravel(cost["GridMap:translation"])[:2].tolist() == [-1.0, -1.0]  # ix0 = iy0 = -2 at 0.5 m
    fmt = cost["GridMap:format"][0]
    img = np.asarray(cost["GridMap:data"][0], dtype=np.uint8).reshape(fmt["height"], fmt["width"], 4)
    # the dearest cells (the unknown-cell penalty) are bright (viridis' yellow): the whole row iy = 10, near the
    # north edge, is; Rerun draws image row 0 at the top, so it must be image row h - 1 - 10 = 1
    bright = (img[..., 0] > 200) & (img[..., 1] > 200)
    assert bright[1].all() and bright[2:, 7:9].all()
    assert not bright[10].all() and not bright[2:, :7].any()
    path = (
        np.asarray(cols["/plans/plan/path"]["LineStrips3D:strips"][0]) if "/plans/plan/path" in cols else None
    )
    if path is None:
        path = np.asarray(next(v["LineStrips3D:strips"][0] for k, v in cols.items() if k.endswith("/path")))
    assert np.allclose(path[:, 2], 0.7 + 0.15)  # on the mapped ground, lifted to stay visible
    text = cols["/plans/breakdown"]["TextDocument:text"][0]
    assert text.startswith("| route | length [m] |") and "|---|" in text


def test_cost_image_marks_impassable_cells_red_and_spans_the_cost_range():
    from consumer_planner.viz import cost_image

    class _Costs:  # cost_image reads only `.cost`
        cost = np.array([[1.0, 2.0], [np.inf, 3.0]])

    img = cost_image(_Costs())  # type: ignore[arg-type]
    assert img.shape == (2, 2, 4)
    assert tuple(img[1, 0]) == (220, 30, 30, 230)  # impassable
    assert tuple(img[0, 0, :3]) == (68, 1, 84) and tuple(img[1, 1, :3]) == (
        253,
        231,
        37,
    )  # min, max of viridis


@pytest.mark.parametrize(
    ("extra", "message"),
    [(["--resync-s", "0"], "need a period > 0"), (["--max-seconds", "nan"], "need a duration > 0")],
)
def test_watch_options_name_valid_values(capsys, extra, message):
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "plan",
                "--map",
                "m",
                "--connect",
                "tcp/127.0.0.1:1",
                "--from",
                "0,0",
                "--to",
                "1,1",
                "--watch",
                *extra,
            ]
        )
    assert exc.value.code == 2 and message in capsys.readouterr().err
