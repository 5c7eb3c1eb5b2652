"""Where a walk's heading error comes from, step by step against the simulator's truth (issue 23).

    python3 benchmarks/heading_budget.py --field 100 --route direct --seed 23 [any `psrmap evaluate` flag]

Walks one `psrmap evaluate --scene lunar` run (the same build of the world, scout and map estimators) and, every
control tick, splits the change of the heading error ψ_est − ψ_true into:
- `bias`: the gyro's true offset (the sensor model's turn-on bias and walk, temperature term, g-sensitivity on
  standing gravity) less the filter's bias estimate, about world z, integrated;
- `scale`: the gyro's scale, cross-axis and misalignment matrix acting on the true rate, about world z;
- `resid`: what is left of the IMU propagation's error (white noise, tilt error × rate, tick averaging);
- the measurement updates that turned the heading: `zaru` (standstill zero-rate updates, through the
  heading–bias covariance), `grav` (the standstill's gravity update), `odo` (leg odometry), `other` (pose fixes
  of the localizer, between the estimator's ticks).
Prints the run's evaluate figures, the budget at the largest heading error and at the end, each standstill's
gyro-z bias error before and after it with what the walk before it and the standstill itself added to the heading
error, and each pose fix of the localizer with the heading error and σ before and after it. Evaluation only: it reads the simulator's sensor model and truth, which the
robot's software never does.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

import scout_agent.evaluate as evaluate_mod
import scout_agent.run as run_mod
from scout_agent.cli import config_from_args, register_evaluate
from scout_agent.loop import _rotation
from scout_agent.state_estimation.pose_update import heading

TERMS = ("bias", "scale", "resid", "zaru", "grav", "odo", "other")


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class HeadingBudget:
    """Hooks one scout's estimator and filter; `on_tick` logs a row per control tick."""

    def __init__(self) -> None:
        self.scout = None
        self.rows: list[dict] = []
        self._acc = dict.fromkeys(("prop", "zaru", "grav", "odo", "other"), 0.0)
        self._last_est: float | None = None
        self._tick: dict | None = None

    def attach(self, scout) -> None:
        self.scout = scout
        est, ekf, acc = scout.robot.estimator, scout.robot.estimator.ekf, self._acc
        ekf_update, est_update = ekf.update, est.update

        def update(residual, H, noise_var, gate_chi2=None, hold_heading=False):
            y0 = heading(ekf.R)
            out = ekf_update(residual, H, noise_var, gate_chi2, hold_heading)
            d = _wrap(heading(ekf.R) - y0)
            if H.shape[0] == 3 and np.allclose(H[:, 9:12], np.eye(3)) and not H[:, 0:3].any():
                acc["zaru"] += d
            elif H.shape[0] == 3 and np.allclose(H[:, 12:15], np.eye(3)):
                acc["grav"] += d
            elif H.shape[0] % 3 == 0:
                acc["odo"] += d
            else:
                acc["other"] += d
            return out

        def tick(t, sensor_tick, dt, *args, **kwargs):
            y0 = heading(ekf.R)
            for k in acc:
                acc[k] = 0.0
            ext = 0.0 if self._last_est is None else _wrap(y0 - self._last_est)  # moved between ticks: fixes
            out = est_update(t, sensor_tick, dt, *args, **kwargs)
            self._last_est = heading(ekf.R)
            # the propagation and the leg odometry run inside one compiled kernel (tick_kernel.odometry_tick),
            # which calls neither `ekf.propagate` nor `ekf.update`: their share is the tick's whole change less
            # the updates seen here (the odometry holds heading, so it is the propagation's)
            acc["prop"] = _wrap(self._last_est - y0) - acc["zaru"] - acc["grav"] - acc["odo"] - acc["other"]
            self._tick = {**acc, "other": acc["other"] + ext, "dt": dt, "stand": bool(kwargs.get("standing"))}
            return out

        ekf.update, est.update = update, tick

    def on_tick(self, sample, truth, robot) -> None:
        p = self._tick
        if p is None or self.scout is None:
            return
        est = self.scout.robot.estimator
        ekf, imu = est.ekf, self.scout.hardware.sensors.imu
        Rt = _rotation(truth.base.quat)
        dtemp = imu.errors.temperature.delta_k_at(imu.t)
        f_still = Rt.T @ -ekf.g
        g_term = (
            imu.gyro_G @ (f_still - imu._f_cal) if imu.gyro_G is not None and imu._f_cal is not None else 0.0
        )
        b_true = imu.gyro_bias + imu.gyro_tc * dtemp + g_term
        dt, w = p["dt"], truth.base.omega
        yt = heading(Rt)
        d_true = 0.0 if not self.rows else _wrap(yt - self.rows[-1]["yaw_true"])
        self.rows.append(
            {
                "t": sample.t,
                "yaw_true": yt,
                "err": _wrap(heading(ekf.R) - yt),
                "sigma": math.sqrt(est.heading_variance()),
                "prop": p["prop"] - d_true,
                "bias": float(ekf.R[2] @ (b_true - ekf.bg)) * dt,
                "scale": float(ekf.R[2] @ ((imu.gyro_M - np.eye(3)) @ w)) * dt,
                **{k: p[k] for k in ("zaru", "grav", "odo", "other")},
                "stand": p["stand"],
                "bz_true": float(b_true[2]),
                "bz_est": float(ekf.bg[2]),
                "walked": est.walked_m,
            }
        )

    def report(self) -> dict:
        r = self.rows
        cum = {
            k: np.cumsum([row[k] for row in r])
            for k in ("prop", "bias", "scale", "zaru", "grav", "odo", "other")
        }
        cum["resid"] = cum["prop"] - cum["bias"] - cum["scale"]
        err = np.array([row["err"] for row in r])
        i_max = int(np.argmax(np.abs(err)))

        def at(i: int) -> dict:
            return {
                "t_s": round(r[i]["t"], 1),
                "walked_m": round(r[i]["walked"], 1),
                "error_deg": round(math.degrees(err[i]), 2),
                "sigma_deg": round(math.degrees(r[i]["sigma"]), 2),
                "start_deg": round(math.degrees(err[0]), 2),
                **{f"{k}_deg": round(math.degrees(cum[k][i]), 2) for k in TERMS},
            }

        stand = np.array([row["stand"] for row in r])
        edges = np.diff(np.r_[0, stand.astype(int), 0])
        stands = []
        prev_end = 0
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True):
            true_bz = float(np.mean([row["bz_true"] for row in r[a : b + 1]]))
            stands.append(
                {
                    "t_s": round(r[a]["t"], 1),
                    "s": round(r[b]["t"] - r[a]["t"], 1),
                    "bz_error_before": round((r[a]["bz_est"] - true_bz) * 1e4, 2),
                    "bz_error_after": round((r[b]["bz_est"] - true_bz) * 1e4, 2),
                    # what the walk since the last standstill added to the heading error, and this one
                    "walk_added_deg": round(math.degrees(err[a] - err[prev_end]), 2),
                    "stand_added_deg": round(math.degrees(err[b] - err[a]), 2),
                    "zaru_turned_deg": round(
                        math.degrees(cum["zaru"][b] - cum["zaru"][a - 1 if a else 0]), 2
                    ),
                    "error_after_deg": round(math.degrees(err[b]), 2),
                }
            )
            prev_end = b
        # the localizer's pose fixes, with the error and σ around them: a fix moves the estimate after the
        # estimator's tick k and before row k is logged; the next tick's hook books it (row k + 1's `other`)
        other = np.array([row["other"] for row in r])
        fixes = [
            {
                "t_s": round(r[i - 1]["t"], 1),
                "walked_m": round(r[i - 1]["walked"], 1),
                "turned_deg": round(math.degrees(other[i]), 3),
                "error_before_deg": round(math.degrees(err[i - 2]), 2),
                "error_after_deg": round(math.degrees(err[i - 1]), 2),
                "sigma_before_deg": round(math.degrees(r[i - 2]["sigma"]), 2),
                "sigma_after_deg": round(math.degrees(r[i - 1]["sigma"]), 2),
            }
            for i in np.flatnonzero(np.abs(other) > math.radians(0.005))
            if i > 1
        ]
        return {
            "at_max": at(i_max),
            "at_end": at(len(r) - 1),
            "standstills_bz_error_1e-4_rad_s": stands,
            "pose_fixes": fixes,
            "turns": self.turns(cum["scale"], err),
        }

    def turns(
        self, scale_cum: np.ndarray, err: np.ndarray, rate_min: float = 0.1, net_min_deg: float = 20.0
    ) -> list[dict]:
        """The walk's turns: runs of ticks whose true heading rate exceeds `rate_min` [rad/s] (runs less than 1 s
        apart joined), kept when they turned at least `net_min_deg` net; each with its net turn, the heading the
        gyro's scale and cross-axis error added over it, and the heading error's change across it [°]."""
        r = self.rows
        if len(r) < 3:
            return []
        t = np.array([row["t"] for row in r])
        yaw = np.unwrap(np.array([row["yaw_true"] for row in r]))
        edges = np.diff(np.r_[0, (np.abs(np.gradient(yaw, t)) > rate_min).astype(int), 0])
        runs: list[list[int]] = []
        for i, j in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True):
            if runs and t[i] - t[runs[-1][1]] < 1.0:
                runs[-1][1] = int(j)
            else:
                runs.append([int(i), int(j)])
        out = []
        for i0, j0 in runs:  # from the tick before the run to the tick after it
            i, j = max(i0 - 1, 0), min(j0 + 1, len(r) - 1)
            net = math.degrees(yaw[j] - yaw[i])
            if abs(net) >= net_min_deg:
                out.append(
                    {
                        "t_s": round(float(t[i]), 1),
                        "s": round(float(t[j] - t[i]), 1),
                        "net_turn_deg": round(net, 1),
                        "scale_added_deg": round(math.degrees(scale_cum[j] - scale_cum[i]), 3),
                        "error_change_deg": round(math.degrees(err[j] - err[i]), 3),
                    }
                )
        return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="heading_budget")
    register_evaluate(ap.add_subparsers())
    args = ap.parse_args(["evaluate", "--scene", "lunar", *argv])
    cfg = config_from_args(args)
    budget = HeadingBudget()
    scout_cls = run_mod.SimulatedScout

    class Hooked(scout_cls):  # type: ignore[misc, valid-type]
        def __init__(self, *a, **k) -> None:
            super().__init__(*a, **k)
            budget.attach(self)

    evaluator_cls = evaluate_mod.Evaluator

    class Logged(evaluator_cls):  # type: ignore[misc, valid-type]
        def on_tick(self, sample, truth, robot=None):
            out = super().on_tick(sample, truth, robot)
            budget.on_tick(sample, truth, robot)
            return out

    run_mod.SimulatedScout = Hooked  # type: ignore[misc]
    evaluate_mod.Evaluator = Logged  # type: ignore[misc]
    res = evaluate_mod.evaluate_run(cfg, args.res, progress=False)
    keys = ("fell", "reached_goal", "gave_up", "distance_m", "sim_seconds", "yaw_error_max_deg", "yaw_error_start_deg",
            "yaw_error_growth_max_deg", "pos_error_final_m", "nees_yaw_mean",
            "yaw_inside_3sigma_frac", "pos_error_max_m", "inside_3sigma_frac", "standstills", "launch")  # fmt: skip
    est = budget.scout.robot.estimator if budget.scout is not None else None
    out = {k: res.get(k) for k in keys} | budget.report()
    if est is not None and budget.scout is not None:
        k, sd = est.tempco.slope()
        out["tempco_learnt"] = {"k": k.round(7).tolist(), "sd": sd.round(7).tolist()}
        out["tempco_true"] = budget.scout.hardware.sensors.imu.gyro_tc.round(7).tolist()
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
