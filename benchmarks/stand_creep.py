"""How a standing robot's stance turns in the world during its standstills, against MuJoCo's truth (issue 23).

    python benchmarks/stand_creep.py [--leg-gravity] [any `psrmap evaluate --scene lunar` flag]
    python benchmarks/stand_creep.py --field 100 --seed 31 --start 15.78,15.61 --goal 95,95 --standstill on \
        --localize off --sim-seconds 26           # one 20 s start standstill at a spot where seed 31's walk paused
    python benchmarks/stand_creep.py --field 100 --route direct --seed 31 --localize off --sim-seconds 450

Walks one `psrmap evaluate` run and, on every tick the controller stands (its gait frozen on four feet, from 1 s
after it froze), logs the four feet's true centres in the world and each foot's contact with the ground (its
normal and its force in the contact's own frame: `mujoco.mj_contactForce`). Per standstill it prints:
- `yaw_rate_1e-4`: the stance's turn in the world [1e-4 rad/s] (a 2-D Kabsch fit of the true feet, a line fitted
  over time): what a standstill's zero-rate window reads as gyro bias (state_estimation/standstill.py);
- per foot: its creep [mm/s], the tilt of its contact normal [deg] and the tangential force in its contact frame
  [N] (a vertical load on a tilted facet of the ground pushes along it; MuJoCo's soft friction lets a foot creep
  at a speed proportional to that force);
- `ground_mz`: the ground forces' yaw moment about the feet's centre [N·m] (≈ 0 when the robot stands still);
- `nonrigid_sigma_1e-4`: what the robot itself could see: its feet moving against each other (the encoders'
  feet in the base frame, their rigid motion fitted out), turned into the σ of a stance rotation under the
  model of independent feet (σ² = |non-rigid rate|² / (5·Σ|r|²)).
`--leg-gravity`: the controller also holds its legs' own weight while standing
(`ControllerConfig.stand_leg_gravity`). Evaluation only: the simulator's truth scores, it is never an input.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

import mujoco
import numpy as np

import scout_agent.evaluate as evaluate_mod
import scout_agent.run as run_mod
from scout_agent.cli import config_from_args, register_evaluate
from scout_agent.robot import kinematics as K


def _kabsch2(p0: np.ndarray, p: np.ndarray) -> tuple[float, np.ndarray]:
    """The rotation [rad] taking the centred points p0 (k, 2) onto p, and the residual (k, 2)."""
    a, b = p0 - p0.mean(axis=0), p - p.mean(axis=0)
    th = float(np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b)))
    c, s = np.cos(th), np.sin(th)
    return th, b - a @ np.array([[c, s], [-s, c]])


def _contacts(hw: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per foot: the ground's force on it (world, N, summed over its contacts), the normal of its most loaded
    contact (world) and the force split along that normal and across it (normal, tangential, 0) [N]."""
    m, d = hw.model, hw.data  # type: ignore[attr-defined]
    leg_of = hw._leg_of_geom  # type: ignore[attr-defined]
    f_w, normal, f_c = np.zeros((4, 3)), np.zeros((4, 3)), np.zeros((4, 3))
    load = np.zeros(4)
    c6 = np.zeros(6)
    for ci in range(d.ncon):
        con = d.contact[ci]
        for gid, sign in ((con.geom1, -1.0), (con.geom2, 1.0)):
            leg = leg_of[gid]
            if leg < 0:
                continue
            mujoco.mj_contactForce(m, d, ci, c6)
            frame = con.frame.reshape(3, 3)
            f_w[leg] += sign * (frame.T @ c6[:3])
            if c6[0] > load[leg]:
                load[leg] = c6[0]
                normal[leg] = sign * frame[0]
    for i in range(4):
        n = normal[i] / max(float(np.linalg.norm(normal[i])), 1e-12)
        f_c[i, 0] = float(f_w[i] @ n)
        f_c[i, 1] = float(np.linalg.norm(f_w[i] - f_c[i, 0] * n))
    return f_w, normal, f_c


def _standstill(rows: list[list[float]]) -> dict:
    a = np.array(rows)
    t = a[:, 0] - a[0, 0]
    feet_w = a[:, 1:9].reshape(-1, 4, 2)
    feet_b = a[:, 9:17].reshape(-1, 4, 2)
    f_w = a[:, 17:29].reshape(-1, 4, 3).mean(axis=0)
    normal = a[:, 29:41].reshape(-1, 4, 3).mean(axis=0)
    f_c = a[:, 41:53].reshape(-1, 4, 3).mean(axis=0)
    yaw = np.array([_kabsch2(feet_w[0], f)[0] for f in feet_w])
    rate = float(np.polyfit(t, yaw, 1)[0])
    creep = np.polyfit(t, feet_w.reshape(len(t), 8), 1)[0].reshape(4, 2)
    r = feet_w[0] - feet_w[0].mean(axis=0)
    mz = float(np.sum(r[:, 0] * f_w[:, 1] - r[:, 1] * f_w[:, 0]))
    res = np.array([_kabsch2(feet_b[0], f)[1].ravel() for f in feet_b])
    v_res = np.polyfit(t, res, 1)[0]
    rb = feet_b[0] - feet_b[0].mean(axis=0)
    sigma = float(np.sqrt(np.sum(v_res**2) / 5.0 / np.sum(rb**2)))
    tilt = np.degrees(
        np.arccos(np.clip(np.abs(normal[:, 2]) / np.linalg.norm(normal, axis=1).clip(1e-9), 0, 1))
    )
    return {
        "t_s": round(float(a[0, 0]), 1),
        "span_s": round(float(t[-1]), 1),
        "yaw_rate_1e-4": round(1e4 * rate, 2),
        "creep_mm_s": np.round(1e3 * np.hypot(creep[:, 0], creep[:, 1]), 3).tolist(),
        "normal_tilt_deg": np.round(tilt, 1).tolist(),
        "tangential_n": np.round(f_c[:, 1], 2).tolist(),
        "normal_n": np.round(f_c[:, 0], 2).tolist(),
        "ground_mz": round(mz, 4),
        "nonrigid_sigma_1e-4": round(1e4 * sigma, 2),
    }


def run(argv: list[str], leg_gravity: bool) -> dict:
    ap = argparse.ArgumentParser(prog="stand_creep")
    register_evaluate(ap.add_subparsers())
    args = ap.parse_args(["evaluate", "--scene", "lunar", *argv])
    box: dict = {}
    stands: list[list[list[float]]] = []

    class Hooked(run_mod.SimulatedScout):  # type: ignore[misc, valid-type]
        def __init__(self, *a, **k) -> None:  # type: ignore[no-untyped-def]
            super().__init__(*a, **k)
            ctl = self.robot.controller
            ctl.config = replace(ctl.config, stand_leg_gravity=leg_gravity)
            box["scout"] = self

    class Logged(evaluate_mod.Evaluator):  # type: ignore[misc, valid-type]
        def on_tick(self, sample, truth, robot=None):  # type: ignore[no-untyped-def]
            out = super().on_tick(sample, truth, robot)
            scout = box["scout"]
            ctl, hw = scout.robot.controller, scout.hardware
            if not ctl.standing:
                box["since"] = None
                return out
            if box.get("since") is None:
                box["since"] = sample.t
                stands.append([])
            if sample.t - box["since"] < 1.0:  # the trunk still settles
                return out
            feet_w = hw.data.geom_xpos[hw._foot_geoms][:, :2]
            feet_b = K.fk(sample.q)[:, :2]  # what the robot's encoders say
            f_w, normal, f_c = _contacts(hw)
            stands[-1].append(
                [sample.t, *feet_w.ravel(), *feet_b.ravel(), *f_w.ravel(), *normal.ravel(), *f_c.ravel()]
            )
            return out

    run_mod.SimulatedScout = Hooked  # type: ignore[misc]
    evaluate_mod.Evaluator = Logged  # type: ignore[misc]
    res = evaluate_mod.evaluate_run(config_from_args(args), args.res, progress=False)
    per = [_standstill(s) for s in stands if len(s) >= 200]
    rates = np.array([p["yaw_rate_1e-4"] for p in per])
    pauses = rates[1:] if len(rates) > 1 else rates
    return {
        "leg_gravity": leg_gravity,
        "fell": res.get("fell"),
        "distance_m": res.get("distance_m"),
        "pauses_yaw_rate_1e-4": {
            "mean": round(float(pauses.mean()), 2) if len(pauses) else None,
            "rms": round(float(np.sqrt(np.mean(pauses**2))), 2) if len(pauses) else None,
        },
        "standstills": per,
    }


def main(argv: list[str]) -> int:
    leg_gravity = "--leg-gravity" in argv
    rest = [a for a in argv if a != "--leg-gravity"]
    print(json.dumps(run(rest, leg_gravity), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
