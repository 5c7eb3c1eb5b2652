"""`psrmap evaluate`: the JSON it prints, and its scoring helpers."""

from __future__ import annotations

import json
import math

import pytest

from scout_agent.evaluate import _pr

REQUIRED = (
    "elevation_rmse_m",
    "slope_rmse_deg",
    "slip_precision",
    "slip_recall",
    "slip_precision_exact",
    "slip_recall_exact",
    "slip_events",
    "cot_mean",
    "giim_mean",
    "giam_mean",
    "giim_paper_mean",
    "giam_paper_mean",
    "nonfoot_contact_ticks",
    "slip_events_in_patch_share",
    "gt_slips",
    "state_source",
    "drift_xy_pct",
    "drift_z_m",
    "drift_yaw_deg",
    "cot_whole_run",
    "cot_whole_run_truth",
    "elevation_rmse_exact_m",
    "sensors",
    "localization",
    "pos_error_max_m",
    "pos_error_final_m",
    "yaw_error_max_deg",
    "yaw_error_start_deg",
    "yaw_error_growth_max_deg",
    "nees_pos_mean",
    "inside_3sigma_frac",
    "nees_yaw_mean",
    "yaw_inside_3sigma_frac",
)


def test_precision_recall_over_stances():
    assert _pr({(0, 1), (1, 2)}, {(0, 1), (2, 3)}) == (0.5, 0.5)
    assert _pr(set(), set()) == (1.0, 1.0)  # nothing to find, nothing claimed
    assert _pr(set(), {(0, 1)}) == (
        0.0,
        0.0,
    )  # found nothing that was there (as the paper-form detector once scored)
    p, r = _pr({(0, 1)}, set())
    assert p == 0.0 and math.isnan(r)


def test_evaluate_prints_one_json_object_with_the_figures(capsys):
    from psrmap.cli import main

    code = main(
        [
            "evaluate",
            "--scene",
            "ramps",
            "--slope",
            "10",
            "--slippery",
            "0.25",
            "--sim-seconds",
            "12",
            "--json",
            "--quiet",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    res = json.loads(out[0])
    for key in REQUIRED:
        assert key in res, key
    assert set(res["segments"]) == {"up", "flat", "down"}
    for seg in res["segments"].values():
        assert {"cot_mean", "giim_mean", "giam_mean", "slip_events"} <= set(seg)
    assert res["elevation_rmse_m"] < 0.03  # the approach and the first metres of the up-ramp
    # GIA from the IMU sees the trunk's own accelerations: a few ticks dip to a zero margin
    assert res["giim_mean"] > 0 and res["giim_nonpositive_share"] < 0.1
    assert res["slip_events"] == 0  # the patch is on the down-ramp, not reached in 12 s
    assert res["state_source"] == "estimate"
    assert (res["sensors"], res["localization"], res["launch"]["mode"]) == ("realistic", "off", "survey")
    assert res["launch"]["datum"] == "declared"  # no DEM, no map: the height is declared, never read
    assert res["pos_error_final_m"] <= res["pos_error_max_m"] and 0.0 <= res["inside_3sigma_frac"] <= 1.0
    assert res["nees_yaw_mean"] > 0 and 0.0 <= res["yaw_inside_3sigma_frac"] <= 1.0
    assert 0 < res["drift_xy_pct"] < 5 and abs(res["drift_z_m"]) < 0.05
    assert res["elevation_rmse_exact_m"] <= res["elevation_rmse_m"] + 0.01
    assert res["cot_whole_run"] == pytest.approx(res["cot_whole_run_truth"], rel=0.1)
    # the legs' climb calibration (climb_calibration.py): pairs of revisited footholds fused within 12 s, its σ
    # below the prior's 0.6 %
    cal = res["climb_calibration"]
    assert cal["pairs"] > 5 and 0 < cal["std_pct"] < 0.6 and abs(cal["bias_pct"]) < 3


def test_evaluate_rejects_a_bad_resolution():
    from psrmap.cli import main

    with pytest.raises(SystemExit):
        main(["evaluate", "--res", "0", "--sim-seconds", "1", "--json"])


@pytest.mark.parametrize(
    "argv",
    [["--sensors", "perfect"], ["--launch", "gps"], ["--launch-sigma", "-1,1"], ["--launch-sigma", "0.1"]],
)
def test_evaluate_rejects_bad_sensor_and_launch_options(argv, capsys):
    from psrmap.cli import main

    with pytest.raises(SystemExit):
        main(["evaluate", "--sim-seconds", "1", "--json", *argv])
    err = capsys.readouterr().err
    assert any(w in err for w in ("realistic", "survey", "launch-sigma", "launch survey"))
