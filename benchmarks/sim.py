"""Real-time factor of the whole scout loop (physics + control + signals) on the lunar field, and in the same
run the raw MuJoCo step rate on the same scene. Prints one JSON object. Wall-clock figures depend on what
else the (shared, 2-core) machine runs; the `_cpu` figures divide by this process's CPU time instead.

    python3 benchmarks/sim.py [--seed 0] [--sim-seconds 30]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from scout_agent.robot import constants as C  # noqa: E402
from scout_agent.run import ScoutRunConfig, build_world, run_scout  # noqa: E402
from scout_agent.sim.simulator import ScoutSim  # noqa: E402


def raw_step_rate(world, steps: int) -> float:
    """mj_step/s with the robot standing on the same scene under constant joint PD (no Python per step)."""
    sim = ScoutSim(world.terrain, world.friction, start=world.start)
    m, d = sim.model, sim.data
    m.actuator_gainprm[sim._pd_ids, 0] = 40.0
    m.actuator_biasprm[sim._pd_ids, 1] = -40.0
    m.actuator_biasprm[sim._pd_ids, 2] = -1.0
    d.ctrl[sim._pd_ids] = C.HOME_Q
    mujoco.mj_step(m, d, nstep=200)
    t0, c0 = time.perf_counter(), time.process_time()
    mujoco.mj_step(m, d, nstep=steps)
    return steps / (time.perf_counter() - t0), steps / (time.process_time() - c0)


def main() -> int:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sim-seconds", type=float, default=30.0)
    args = ap.parse_args()
    cfg = ScoutRunConfig(scene="lunar", seed=args.seed, route="direct", sim_seconds=args.sim_seconds)
    world = build_world(cfg)
    c0 = time.process_time()
    summary = run_scout(cfg, progress=False, world=world)
    cpu = time.process_time() - c0
    rate, rate_cpu = raw_step_rate(world, 20000)
    dt = 0.002
    print(
        json.dumps(
            {
                "scene": world.terrain.name,
                "hfield": list(world.terrain.shape),
                "res_m": world.terrain.res,
                "control_hz": round(1.0 / (dt * cfg.sim.decimation), 1),
                "physics_hz": 1.0 / dt,
                "scout_loop_real_time_factor": summary["real_time_factor"],
                "scout_sim_seconds": summary["sim_seconds"],
                "scout_wall_seconds": summary["wall_seconds"],
                "scout_cpu_seconds": round(cpu, 2),
                "scout_loop_real_time_factor_cpu": round(summary["sim_seconds"] / cpu, 2),
                "fell": summary["fell"],
                "raw_mj_steps_per_s": round(rate),
                "raw_real_time_factor": round(rate * dt, 1),
                "raw_mj_steps_per_cpu_s": round(rate_cpu),
                "raw_real_time_factor_cpu": round(rate_cpu * dt, 1),
                "goal_real_time_factor": 8.0,
                "meets_goal": bool(summary["real_time_factor"] >= 8.0),
                "meets_goal_per_cpu_second": bool(summary["sim_seconds"] / cpu >= 8.0),
                "cpu_load_1min": round(float(np.loadtxt("/proc/loadavg", usecols=0)), 2),
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
