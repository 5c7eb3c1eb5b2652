"""Where the scout loop's CPU goes, per control tick: the benchmark's walk (lunar field, route direct, the
estimators the pilot feels in the loop as in `benchmarks/sim.py`) with each hot method wrapped by a
thread-CPU-time timer, exclusive of the other wrapped methods it calls. The unwrapped loop's CPU per tick is
measured first (the wrappers add ~1 µs per call); the parts are its shares.

    python3 benchmarks/loop_profile.py [--sim-seconds 10] [--seed 0] [--no-estimators]
"""

from __future__ import annotations

import argparse
import collections
import importlib
import time
from collections.abc import Callable
from typing import Any

import mujoco
from sim import pilot_estimators

from scout_agent.run import OnTick, ScoutRunConfig, build_world, run_scout

PARTS = (  # (module, attribute path, part)
    ("mujoco", "mj_step", "physics (mj_step)"),
    ("scout_agent.control.controller", "TrotController.step", "controller (excl. QP)"),
    ("scout_agent.control.stance", "StanceQP.solve", "stance QP"),
    ("scout_agent.control.stance", "StanceQP.solve_feet", "stance QP"),
    ("scout_agent.sim.sensors.suite", "SensorSuite.read", "sensor models"),
    ("scout_agent.onboard.drivers", "ContactDetector.read", "drivers (contact flags)"),
    ("scout_agent.state_estimation.estimator", "StateEstimator.update", "state estimator"),
    ("scout_agent.sim.aliengo", "tick_truth_into", "ground truth (contacts, feet, terrain)"),
    ("scout_agent.sim.aliengo", "SimulatedAliengo._apply_friction", "friction lookup"),
    ("scout_agent.sim.aliengo", "SimulatedAliengo.truth", "ground truth records (evaluation channel)"),
    ("scout_agent.sim.aliengo", "SimulatedAliengo.write", "per-step copies, controls (hardware)"),
    ("scout_agent.onboard.software", "OnboardSoftware.sense", "records and glue (robot software)"),
    ("scout_agent.onboard.software", "OnboardSoftware.command", "records and glue (robot software)"),
    ("scout_agent.loop", "SimulatedScout.step", "loop glue"),
    ("scout_agent.control.pilot", "Pilot.command", "pilot (modes, trail)"),
    ("scout_agent.control.pilot", "Pilot.feel", "pilot (modes, trail)"),
    ("scout_agent.control.follower", "PathFollower.command", "path follower"),
    ("scout_agent.control.friction_estimate", "FrictionEstimate.update", "friction estimate"),
    ("scout_agent.control.adaptation", "GaitAdaptation.setting", "adaptive gait, reflex"),
    ("scout_agent.control.reflex", "Senses.feel", "adaptive gait, reflex"),
    (
        "scout_agent.estimators.pipeline",
        "EstimatorPipeline.update",
        "estimators: pipeline (CoT, margins, forces)",
    ),
    ("scout_agent.estimators.slip", "SlipDetector.update", "estimators: slip detector"),
    ("scout_agent.localization.localizer", "Localizer.on_tick", "localizer bookkeeping"),
    ("scout_agent.run", "run_scout", "run loop (truth bookkeeping)"),
)


def _wrap(owner: Any, name: str, part: str, acc: collections.Counter, stack: list[float]) -> None:
    f: Callable[..., Any] = getattr(owner, name)

    def timed(*a: Any, **k: Any) -> Any:
        t0 = time.thread_time()
        stack.append(0.0)
        try:
            return f(*a, **k)
        finally:
            dt = time.thread_time() - t0
            acc[part] += dt - stack.pop()
            if stack:
                stack[-1] += dt

    setattr(owner, name, timed)


def main() -> int:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--sim-seconds", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-estimators", action="store_true", help="the loop without the estimators (sim.py)")
    args = ap.parse_args()

    def on_tick() -> OnTick | None:
        return None if args.no_estimators else pilot_estimators()

    cfg = ScoutRunConfig(scene="lunar", seed=args.seed, route="direct", sim_seconds=args.sim_seconds)
    world = build_world(cfg)
    warm = ScoutRunConfig(scene="lunar", seed=args.seed, route="direct", sim_seconds=0.2)
    run_scout(warm, on_tick=on_tick(), progress=False, world=world)  # loads the compiled kernels
    t0 = time.thread_time()
    summary = run_scout(cfg, on_tick=on_tick(), progress=False, world=world)
    per_tick = (time.thread_time() - t0) / round(summary["sim_seconds"] / 0.01)
    acc: collections.Counter = collections.Counter()
    stack: list[float] = []
    for module, path, part in PARTS:
        owner: Any = importlib.import_module(module)
        *outer, name = path.split(".")
        for attr in outer:
            owner = getattr(owner, attr)
        _wrap(owner, name, part, acc, stack)
    importlib.import_module("scout_agent.sim.aliengo").mujoco = mujoco  # the wrapped mj_step
    importlib.import_module("scout_agent.run").run_scout(cfg, on_tick=on_tick(), progress=False, world=world)
    total = sum(acc.values())
    print(f"scout loop: {1e6 * per_tick:.0f} us CPU per control tick (thread time, unwrapped run)")
    for part, t in acc.most_common():
        print(f"{100 * t / total:5.1f} %  {1e6 * per_tick * t / total:6.0f} us  {part}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
