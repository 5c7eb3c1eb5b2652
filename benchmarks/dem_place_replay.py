"""How well an orbital DEM can place a scout and give it its heading, offline (evaluation only: it reads the
simulator's truth, which only scores).

`record` walks `psrmap evaluate`'s own loop (realistic sensors, surveyed start) with localization off and saves,
per settled stance, the foothold as the estimate placed it, the distance walked and the true contact point, and
every 0.2 s the estimate's pose and covariance beside the true pose. `replay` runs the DEM place and heading
fixes again on that dead-reckoned walk, every 25 m from 30 m as the localizer does, over `--draws` DEM noise
draws (draw 0 is the walk's own DEM): the corrected estimate is the dead reckoning moved by the fixes fused so
far (a rigid turn and shift, as a heading and position correction moves what odometry integrates after it),
its (x, y, heading) covariance propagated from the last fix by the recorded filter's own growth since then, each
fix fused as a Kalman update, χ²-gated at p = 0.001. Prints per draw the largest position and heading error over
the walk and the share of 0.2 s samples inside the 3σ ellipse; `--fixes none` is dead reckoning alone, `--fixes
window` the build before `trail.py` (the likelihood's moments over a window sized by the filter's σ, the last
100 m of track, covariance × the footholds shared).

    python benchmarks/dem_place_replay.py record /tmp/s33.npz --seed 33
    python benchmarks/dem_place_replay.py replay /tmp/s33.npz --seed 33 --draws 6 [--fixes trail|window|none]
"""

from __future__ import annotations

import argparse
import collections
import json
from dataclasses import replace

import numpy as np

from scout_agent import evaluate as evaluate_module
from scout_agent.localization import DemReference, LocalizerConfig, match_track, match_trail
from scout_agent.localization.localizer import _due_feet, search_config
from scout_agent.robot import constants as C
from scout_agent.run import ScoutRunConfig
from scout_agent.sim.dem import OrbitalDemConfig, orbital_dem
from scout_agent.sim.terrain import LunarConfig, make_lunar
from scout_agent.state_estimation.consistency import yaw_of_quat
from scout_agent.state_estimation.pose_update import heading

POSE_EVERY_S = 0.2
XY_YAW = [6, 7, 2]  # the error state's x, y and base-z rotation (heading on level ground)


def record(out: str, seed: int, field_m: float, sim_seconds: float | None = None) -> dict:
    cfg = ScoutRunConfig(scene="lunar", seed=seed, field_m=field_m, route="direct", localize="off",
                         sim_seconds=sim_seconds)  # fmt: skip
    feet, poses = [], []
    st = {"since": np.full(4, np.inf), "taken": np.zeros(4, bool), "due": np.zeros(4, bool), "walked": 0.0,
          "prev": None, "next": 0.0}  # fmt: skip
    real_run = evaluate_module.run_scout

    def run(cfg_, on_tick=None, **kw):
        def tick(sample, truth, robot):
            e, t, due = robot.estimator.ekf, sample.t, st["due"]
            if _due_feet(np.asarray(sample.contact, bool), st["since"], st["taken"], t, 0.15, due):
                fb, _ = robot.estimator.feet.feet_base_and_vel(sample.q, sample.dq)
                pts = fb[due] @ e.R.T + e.p
                pts[:, 2] -= C.FOOT_RADIUS
                for p, q in zip(pts, truth.contact_point_world[due], strict=True):
                    feet.append([t, st["walked"], *p, *q])
                st["taken"] |= due
            if st["prev"] is not None:
                st["walked"] += float(np.hypot(e.p[0] - st["prev"][0], e.p[1] - st["prev"][1]))
            st["prev"] = (float(e.p[0]), float(e.p[1]))
            if t >= st["next"]:
                st["next"] += POSE_EVERY_S
                P = e.P[np.ix_(XY_YAW, XY_YAW)]
                poses.append([t, st["walked"], *e.p[:2], heading(e.R), *truth.base.pos[:2],
                              yaw_of_quat(truth.base.quat), *P.ravel()])  # fmt: skip
            return on_tick(sample, truth, robot) if on_tick is not None else None

        return real_run(cfg_, on_tick=tick, **kw)

    evaluate_module.run_scout = run
    try:
        res = evaluate_module.evaluate_run(cfg)
    finally:
        evaluate_module.run_scout = real_run
    np.savez_compressed(out, feet=np.array(feet), poses=np.array(poses), seed=seed, field_m=field_m)
    keys = (
        "fell",
        "reached_goal",
        "distance_m",
        "pos_error_max_m",
        "yaw_error_max_deg",
        "inside_3sigma_frac",
    )
    return {k: res.get(k) for k in keys}


def _turn(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _carry(d: np.ndarray) -> np.ndarray:
    """How an (x, y, heading) error moves over a displacement d: a heading error turns it."""
    F = np.eye(3)
    F[0, 2], F[1, 2] = -d[1], d[0]
    return F


def _psd(M: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh((M + M.T) / 2)
    return V @ np.diag(np.maximum(w, 0.0)) @ V.T


def replay(path: str, draws: int, fixes: str, every_m: float = 25.0, first_m: float = 30.0) -> list[dict]:
    d = np.load(path)
    feet, poses, seed = d["feet"], d["poses"], int(d["seed"])
    terrain = make_lunar(LunarConfig(seed=seed, size_m=float(d["field_m"])))
    t, w, est_xy, est_yaw = poses[:, 0], poses[:, 1], poses[:, 2:4], poses[:, 4]
    true_xy, true_yaw, P_dr = poses[:, 5:7], poses[:, 7], poses[:, 8:].reshape(-1, 3, 3)
    tf, wf, foot_xy, foot_z = feet[:, 0], feet[:, 1], feet[:, 2:4], feet[:, 4]
    lc = LocalizerConfig()
    rows = []
    for draw in range(draws):
        dem = orbital_dem(terrain, replace(OrbitalDemConfig(), seed=seed if draw == 0 else 9000 + draw))
        ref = DemReference(dem)
        R, shift, dyaw = np.eye(2), np.zeros(2), 0.0  # corrected = R · dead reckoning + shift
        k, P_k, next_fix, new_from = 0, P_dr[0].copy(), first_m, 0.0
        err, yaw_err, inside, reasons = [], [], [], collections.Counter()
        for i in range(len(t)):
            est = R @ est_xy[i] + shift
            D = _carry(est - (R @ est_xy[k] + shift))
            Ddr = _carry(est_xy[i] - est_xy[k])
            P = D @ P_k @ D.T + _psd(P_dr[i] - Ddr @ P_dr[k] @ Ddr.T)
            e = est - true_xy[i]
            ey = (est_yaw[i] + dyaw - true_yaw[i] + np.pi) % (2 * np.pi) - np.pi
            err.append(float(np.hypot(*e)))
            yaw_err.append(abs(float(np.degrees(ey))))
            inside.append(float(e @ np.linalg.solve(P[:2, :2], e)) <= 11.83)
            if fixes == "none" or w[i] < next_fix:
                continue
            next_fix = w[i] + every_m
            if fixes == "trail":
                length = max(lc.dem_trail_m, w[i] - new_from)
                sel = (tf <= t[i]) & (wf >= w[i] - length)
                pts = np.column_stack([foot_xy[sel] @ R.T + shift, foot_z[sel]])
                fix = match_trail(pts, wf[sel], ref, P, est, new_from, lc.dem_trail)
                reasons[fix.reason] += 1
                if not fix.ok:
                    continue
                assert fix.offset is not None and fix.cov is not None
                z, Rm = fix.offset, fix.cov
            else:
                src = lc.dem
                sel = (tf <= t[i]) & (wf >= w[i] - src.track_m)
                pts = np.column_stack([foot_xy[sel] @ R.T + shift, foot_z[sel]])
                sxy = float(np.sqrt(np.linalg.eigvalsh(P[:2, :2]).max()))
                mc = search_config(lc, src, sxy, float(np.degrees(np.sqrt(P[2, 2]))))
                res = match_track(pts, ref, mc, pivot=est)
                reasons[res.reason] += 1
                if not res.ok:
                    continue
                assert res.cov is not None
                z = np.r_[res.dx, res.dy, res.dyaw]
                Rm = res.cov[np.ix_([0, 1, 3], [0, 1, 3])] * max(1.0, min(src.track_m, w[i]) / src.every_m)
            S = P + Rm
            if float(z @ np.linalg.solve(S, z)) > 16.27:
                reasons["gate"] += 1
                continue
            K = P @ np.linalg.inv(S)
            corr = K @ z
            turn = _turn(corr[2])
            R, shift, dyaw = turn @ R, est + turn @ (shift - est) + corr[:2], dyaw + corr[2]
            P_k, k, new_from = (np.eye(3) - K) @ P, i, w[i]
        rows.append({"draw": draw, "pos_error_max_m": round(max(err), 2), "pos_error_final_m": round(err[-1], 2),
                     "yaw_error_max_deg": round(max(yaw_err), 2), "inside_3sigma_frac": round(float(np.mean(inside)), 3),
                     "walked_m": round(float(w[-1]), 1), "fixes": dict(reasons)})  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("--seed", type=int, required=True)
    r.add_argument("--field", type=float, default=100.0)
    r.add_argument("--sim-seconds", type=float, default=None, help="stop after this much (default: the walk)")
    p = sub.add_parser("replay")
    p.add_argument("rec")
    p.add_argument("--draws", type=int, default=6)
    p.add_argument("--fixes", choices=("trail", "window", "none"), default="trail")
    a = ap.parse_args()
    if a.cmd == "record":
        print(json.dumps(record(a.out, a.seed, a.field, a.sim_seconds)))
        return
    rows = replay(a.rec, a.draws, a.fixes)
    for row in rows:
        print(json.dumps(row))
    print(json.dumps({k: round(float(np.mean([row[k] for row in rows])), 3)
                      for k in ("pos_error_max_m", "yaw_error_max_deg", "inside_3sigma_frac")} | {"mean_of": len(rows)}))  # fmt: skip


if __name__ == "__main__":
    main()
