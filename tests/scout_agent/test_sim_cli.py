"""`psrmap scout`: argument errors name valid values; a short run prints the JSON summary and an .rrd."""

from __future__ import annotations

import argparse
import json

import pytest

from scout_agent.cli import register


def _parser():
    p = argparse.ArgumentParser(prog="psrmap")
    register(p.add_subparsers(dest="command", required=True))
    return p


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--scene", "moon"], "choose from 'ramps', 'lunar'"),
        (["--slope", "30"], "0–25"),
        (["--scene", "lunar", "--slippery", "0.3"], "--slippery-patches"),
        (["--scene", "ramps", "--slippery-patches", "2"], "--slippery MU"),
        (["--scene", "lunar", "--goal", "30,1"], "outside the terrain"),
        (["--patch", "1,2,3"], "x0,y0,x1,y1,MU"),
        (["--route", "west"], "--scene lunar"),
        (["--scene", "lunar", "--holdable-patches"], "--slippery-patches N"),
    ],
)
def test_errors_name_valid_values(argv, message, capsys):
    from psrmap.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["scout", *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_short_run_prints_json_and_writes_rrd(tmp_path, capsys):
    rrd = tmp_path / "scout.rrd"
    args = _parser().parse_args(
        [
            "scout",
            "--scene",
            "lunar",
            "--seed",
            "2",
            "--route",
            "direct",
            "--sim-seconds",
            "2",
            "--json",
            "--quiet",
            "--rrd",
            str(rrd),
            "--slippery-patches",
            "2",
        ]
    )
    assert args.func(args) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in (
        "fell",
        "fall_xy",
        "reached_goal",
        "distance_m",
        "mean_speed_mps",
        "sim_seconds",
        "real_time_factor",
    ):
        assert key in summary
    assert summary["fell"] is False and summary["sim_seconds"] == pytest.approx(2.0, abs=0.02)
    assert len(summary["friction"]["patches"]) == 2
    assert rrd.exists() and rrd.stat().st_size > 10_000


def test_recording_holds_pose_trail_estimates_and_slip_events(tmp_path, capsys):
    from rerun.chunk import RrdReader

    rrd = tmp_path / "scout.rrd"
    # a slippery down-ramp makes slip events; a short ramp layout reaches it within seconds (1 m of flat first:
    # with 0.5 m the robot spawns straddling the 20° ramp foot and its margin reflex stops it there)
    args = _parser().parse_args(
        [
            "scout",
            "--scene",
            "ramps",
            "--slope",
            "20",
            "--slippery",
            "0.4",
            "--ramp-lengths",
            "1,1,0.5,2,0.5",
            "--sim-seconds",
            "30",
            "--json",
            "--quiet",
            "--rrd",
            str(rrd),
        ]
    )
    args.func(args)
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    from scout_agent.viz import SERIES

    chunks = list(RrdReader(rrd).stream())
    entities = {c.entity_path for c in chunks}
    root = "/world/scouts/scout1"
    for suffix in (
        "/base",
        "/feet",
        "/trajectory",
        "/trajectory_estimate",
        *(f"/series/{group}" for group in SERIES),
    ):
        assert root + suffix in entities, suffix
    # series grouped by unit, named after scout and foot / joint (not dv[0], tau[3])
    names: dict[str, list[str]] = {}
    for c in chunks:
        rb = c.to_record_batch()
        if c.is_static and "SeriesLines:names" in rb.schema.names:
            names[c.entity_path] = rb.column(rb.schema.names.index("SeriesLines:names")).to_pylist()[0]
    assert names[root + "/series/foot_pressure_n"] == ["scout1 FL", "scout1 FR", "scout1 RL", "scout1 RR"]
    assert names[root + "/series/joint_torque_nm"][:3] == [
        "scout1 FL_hip",
        "scout1 FL_thigh",
        "scout1 FL_calf",
    ]
    assert names[root + "/series/slip_dv_mps"][-1] == "scout1 ε_v"
    assert "/world/terrain" in entities and "/world/friction" in entities
    assert summary["map"]["slip_events"] > 0 and root + "/slips" in entities
