"""Record a walk's heading channel once, replay the gyro-z offset and heading with other standstill settings
offline (issue 23; evaluation only: it reads the simulator's sensor model and truth, which only score).

`record` walks one `psrmap evaluate --scene lunar` run and saves, per control tick, the sensor model's true gyro
offset and the filter's, the true and estimated heading, the estimate's world-z row, the filter's heading and
z-offset variances, the true angular rate; and every standstill's zero-rate window (its end, span, the trunk's
kinematic turn, its measurement). Against the truth each window's error is the gyro's white noise plus what the
kinematics cannot see: the stance turning in the world (the creep, standstill.py).

`replay` runs a two-state filter (heading, gyro z offset) over the recorded walk with the recorded windows'
measurements and other settings (the offset's walk, the creep's σ and sharing): the offset nominal between windows
moves as the recorded one did (its temperature term, the legs), the heading error is the recorded one with the
recorded offset's integral and zero-rate corrections replaced by the replayed ones (the scale, white-noise and map
terms stay as walked). The pauses stay where the walk made them: a shorter budget (more pauses) needs a new walk.

    python benchmarks/heading_replay.py record /tmp/h31.npz --field 100 --route direct --seed 31 --localize on
    python benchmarks/heading_replay.py replay /tmp/h31.npz [--walk-z 3e-6] [--creep 1.6e-4] [--creep-windows 2]
        [--hold-heading]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

import numpy as np

import scout_agent.evaluate as evaluate_mod
import scout_agent.run as run_mod
from scout_agent.cli import config_from_args, register_evaluate
from scout_agent.loop import _rotation
from scout_agent.state_estimation import standstill as standstill_mod
from scout_agent.state_estimation.ekf import NoiseConfig
from scout_agent.state_estimation.pose_update import heading
from scout_agent.state_estimation.standstill import StandstillConfig

# columns of the per-tick record
T, B_TRUE, B_EST, YAW_TRUE, YAW_EST, RZ, HVAR, PBZ, WALKED, OMEGA = (
    0, slice(1, 4), slice(4, 7), 7, 8, slice(9, 12), 12, 13, 14, slice(15, 18)
)  # fmt: skip


def _wrap(a: np.ndarray | float) -> np.ndarray | float:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def record(out: str, argv: list[str]) -> dict:
    ap = argparse.ArgumentParser(prog="heading_replay record")
    register_evaluate(ap.add_subparsers())
    args = ap.parse_args(["evaluate", "--scene", "lunar", *argv])
    box: dict = {}
    windows: list[list[float]] = []
    ticks: list[list[float]] = []
    close = standstill_mod.ZeroRateWindow.close

    def logged_close(self, feet_b, rms_max, turn_max):  # type: ignore[no-untyped-def]
        z = close(self, feet_b, rms_max, turn_max)
        windows.append([box["scout"].robot.estimator.t, self.span_s, self.turned_rad,
                        *(np.full(3, np.nan) if z is None else z)])  # fmt: skip
        return z

    class Hooked(run_mod.SimulatedScout):  # type: ignore[misc, valid-type]
        def __init__(self, *a, **k) -> None:  # type: ignore[no-untyped-def]
            super().__init__(*a, **k)
            box["scout"] = self

    class Logged(evaluate_mod.Evaluator):  # type: ignore[misc, valid-type]
        def on_tick(self, sample, truth, robot=None):  # type: ignore[no-untyped-def]
            out = super().on_tick(sample, truth, robot)
            scout = box["scout"]
            est, imu = scout.robot.estimator, scout.hardware.sensors.imu
            ekf = est.ekf
            Rt = _rotation(truth.base.quat)
            g_term = (imu.gyro_G @ (Rt.T @ -ekf.g - imu._f_cal)
                      if imu.gyro_G is not None and imu._f_cal is not None else np.zeros(3))  # fmt: skip
            b = imu.gyro_bias + imu.gyro_tc * imu.errors.temperature.delta_k_at(imu.t) + g_term
            ticks.append([sample.t, *b, *ekf.bg, heading(Rt), heading(ekf.R), *ekf.R[2], est.heading_variance(),
                          ekf.P[11, 11], est.walked_m, *truth.base.omega])  # fmt: skip
            return out

    standstill_mod.ZeroRateWindow.close = logged_close  # type: ignore[method-assign]
    run_mod.SimulatedScout = Hooked  # type: ignore[misc]
    evaluate_mod.Evaluator = Logged  # type: ignore[misc]
    res = evaluate_mod.evaluate_run(config_from_args(args), args.res, progress=False)
    imu = box["scout"].hardware.sensors.imu
    np.savez_compressed(
        out, tick=np.array(ticks), win=np.array(windows), gyro_M=imu.gyro_M, gyro_tc=imu.gyro_tc
    )
    keys = ("fell", "reached_goal", "distance_m", "yaw_error_max_deg", "pos_error_max_m", "inside_3sigma_frac",
            "standstills")  # fmt: skip
    return {k: res.get(k) for k in keys}


def windows_against_truth(path: str) -> list[dict]:
    """Each recorded window's measurement error about z against the true offset [rad/s]."""
    d = np.load(path)
    tk, win = d["tick"], d["win"]
    out = []
    for w in win:
        i = min(int(np.searchsorted(tk[:, T], w[0])), len(tk) - 1)
        out.append({"t_s": round(float(w[0]), 1), "turned_mrad": round(1e3 * float(w[2]), 2),
                    "error_1e-4": None if not np.isfinite(w[5]) else round(1e4 * float(w[5] - tk[i, B_TRUE][2]), 2)})  # fmt: skip
    return out


def replay(
    path: str, walk_z: float, ss: StandstillConfig, recorded_walk_z: float, hold_heading: bool = False
) -> dict:
    """The heading error over the recorded walk with these settings (module docstring). `hold_heading`: the
    zero-rate windows correct the offset only, not the heading (a Schmidt update of heading)."""
    d = np.load(path)
    tk, win = d["tick"], d["win"]
    t = tk[:, T]
    dt = np.diff(t, prepend=t[0])
    bt, be, rz = tk[:, B_TRUE], tk[:, B_EST], tk[:, RZ]
    e_rec = _wrap(tk[:, YAW_EST] - tk[:, YAW_TRUE])
    rate_rec = np.einsum("ij,ij->i", rz, bt - be)  # d(ψ̂ − ψ)/dt from the recorded offset error
    at = {int(i): k for k, i in enumerate(np.searchsorted(t, win[:, 0]))}
    jump_e, jump_b = np.zeros(len(t)), np.zeros(len(t))
    for i in at:
        if 0 < i < len(t):
            jump_e[i] = _wrap(e_rec[i] - e_rec[i - 1]) - rate_rec[i] * dt[i]
            jump_b[i] = be[i, 2] - be[i - 1, 2]
    drift_b = np.diff(be[:, 2], prepend=be[0, 2]) - jump_b
    grow_p = np.maximum(np.diff(tk[:, PBZ], prepend=tk[0, PBZ]), 0.0)
    q_gyro = NoiseConfig().gyro ** 2
    b = be[0, 2]
    P = np.diag([tk[0, HVAR], tk[0, PBZ]])
    e = np.empty(len(t))
    acc_rec = acc_new = 0.0
    for i in range(len(t)):
        h = dt[i]
        b += drift_b[i]
        acc_rec += rate_rec[i] * h + jump_e[i]
        acc_new += (
            rz[i, 0] * (bt[i, 0] - be[i, 0]) + rz[i, 1] * (bt[i, 1] - be[i, 1]) + rz[i, 2] * (bt[i, 2] - b)
        ) * h
        qb = (0.0 if i in at else grow_p[i]) + (walk_z**2 - recorded_walk_z**2) * h
        F = np.array([[1.0, -h], [0.0, 1.0]])
        P = F @ P @ F.T + np.diag([q_gyro * h, max(qb, 0.0)])
        k = at.get(i)
        if k is not None and np.isfinite(win[k, 5]):
            S = P[1, 1] + ss.zaru_var(float(win[k, 1]), float(win[k, 2]))
            K = P[:, 1] / S
            nu = float(win[k, 5]) - b
            b += K[1] * nu
            if hold_heading:  # Schmidt (gain [0, k]): P <- A P A' + k^2 R e2 e2', A = diag(1, 1 - k)
                k1 = K[1]
                P[0, 1] *= 1.0 - k1
                P[1, 0] = P[0, 1]
                P[1, 1] = (1.0 - k1) ** 2 * P[1, 1] + k1 * k1 * (S - P[1, 1])
            else:
                acc_new += K[0] * nu
                P = P - np.outer(K, P[1, :])
        e[i] = e_rec[i] - acc_rec + acc_new
    walking = t < t[-1] - 5.0
    return {"yaw_error_max_deg": round(float(np.degrees(np.abs(e[walking]).max())), 2),
            "yaw_error_rms_deg": round(float(np.degrees(np.sqrt(np.mean(e[walking] ** 2)))), 2),
            "recorded_max_deg": round(float(np.degrees(np.abs(e_rec[walking]).max())), 2)}  # fmt: skip


def main(argv: list[str]) -> int:
    if len(argv) < 2 or argv[0] not in ("record", "replay"):
        print(__doc__)
        return 2
    if argv[0] == "record":
        print(json.dumps(record(argv[1], argv[2:]), indent=1))
        return 0
    ap = argparse.ArgumentParser(prog="heading_replay replay")
    ap.add_argument("path")
    ap.add_argument("--walk-z", type=float, default=NoiseConfig().gyro_bias_walk_z)
    ap.add_argument("--recorded-walk-z", type=float, default=NoiseConfig().gyro_bias_walk_z)
    ap.add_argument("--creep", type=float, default=StandstillConfig().creep_std_rad_s)
    ap.add_argument("--creep-windows", type=int, default=StandstillConfig().creep_windows)
    ap.add_argument(
        "--hold-heading", action="store_true", help="the windows correct the offset, not the heading"
    )
    a = ap.parse_args(argv[1:])
    ss = replace(StandstillConfig(), creep_std_rad_s=a.creep, creep_windows=a.creep_windows)
    out = replay(a.path, a.walk_z, ss, a.recorded_walk_z, a.hold_heading) | {
        "windows": windows_against_truth(a.path)
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
