"""Where the scout loop's CPU goes, per control tick: the benchmark's walk (lunar field, route direct, the
estimators the pilot feels in the loop as in `benchmarks/sim.py`) with each hot method wrapped by a
thread-CPU-time timer, exclusive of the other wrapped methods it calls. The unwrapped loop's CPU per tick is
measured first; the parts are its shares. A wrapper costs ≈ 1 µs a call, half of it outside its own timer, in
the caller's: calibrated on a wrapped no-op at start and taken off both (else a part that calls many wrapped
parts, such as the run loop with six a tick, looks ≈ 20 µs a tick dearer than it is).

    python3 benchmarks/loop_profile.py [--sim-seconds 10] [--seed 0] [--no-estimators]
"""

from __future__ import annotations

import argparse
import collections
import importlib
import time
from collections.abc import Callable
from typing import Any

from sim import pilot_estimators

from scout_agent.run import OnTick, ScoutRunConfig, build_world, run_scout

PARTS = (  # (module, attribute path, part)
    ("scout_agent.sim.aliengo", "_physics_tick", "physics (5 x mj_step, the readings' copies)"),
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
    ("scout_agent.estimators.nonfoot", "UnexplainedForce.update", "estimators: non-foot force (dynamics)"),
    ("scout_agent.localization.localizer", "Localizer.on_tick", "localizer bookkeeping"),
    ("scout_agent.run", "run_scout", "run loop (truth bookkeeping)"),
)
RUN_LOOP = PARTS[-1][2]


def _wrap(
    owner: Any,
    name: str,
    part: str,
    acc: collections.Counter,
    stack: list[float],
    overhead: tuple[float, float] = (0.0, 0.0),
) -> None:
    """Time `owner.name` into `acc[part]`, exclusive of the wrapped calls it makes; `overhead`: the wrapper's
    own cost per call inside its timer and outside it (`_calibrate`), taken off the part and its caller."""
    f: Callable[..., Any] = getattr(owner, name)
    inside, outside = overhead

    def timed(*a: Any, **k: Any) -> Any:
        t0 = time.thread_time()
        stack.append(0.0)
        try:
            return f(*a, **k)
        finally:
            dt = time.thread_time() - t0
            acc[part] += dt - stack.pop() - inside
            if stack:
                stack[-1] += dt + outside

    setattr(owner, name, timed)


def _cpu(f: Callable[[], Any]) -> float:
    t0 = time.thread_time()
    f()
    return time.thread_time() - t0


def _calibrate(n: int = 50_000) -> tuple[float, float]:
    """The wrapper's cost per call [s]: inside its own timer, and outside it (charged to the caller): a wrapped
    no-op called `n` times by a wrapped caller, against the same loop unwrapped (medians of 5)."""

    class Probe:
        def noop(self) -> None:
            return None

        def calls(self, k: int) -> None:
            for _ in range(k):
                self.noop()

    def loop_cost() -> float:
        t0 = time.thread_time()
        Probe().calls(n)
        return time.thread_time() - t0

    bare = sorted(loop_cost() for _ in range(5))[2]
    _wrap(Probe, "noop", "noop", acc := collections.Counter(), stack := [])
    _wrap(Probe, "calls", "calls", acc, stack)
    inside, outside = [], []
    for _ in range(5):
        acc.clear()
        Probe().calls(n)
        inside.append(acc["noop"] / n)
        outside.append((acc["calls"] - bare) / n)
    return sorted(inside)[2], sorted(outside)[2]


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
    ticks = round(summary["sim_seconds"] / 0.01)
    per_tick = (time.thread_time() - t0) / ticks
    # a run's set-up and summary (the scene built, the orbital DEM written and read back, …): a one-tick run's
    # CPU, median of 3; the run loop's part below is what is left of run_scout's own time
    one = ScoutRunConfig(scene="lunar", seed=args.seed, route="direct", sim_seconds=0.01)
    setup = sorted(
        _cpu(lambda: run_scout(one, on_tick=on_tick(), progress=False, world=world)) for _ in range(3)
    )[1]
    overhead = _calibrate()
    acc: collections.Counter = collections.Counter()
    stack: list[float] = []
    for module, path, part in PARTS:
        owner: Any = importlib.import_module(module)
        *outer, name = path.split(".")
        for attr in outer:
            owner = getattr(owner, attr)
        _wrap(owner, name, part, acc, stack, overhead)
    importlib.import_module("scout_agent.run").run_scout(cfg, on_tick=on_tick(), progress=False, world=world)
    acc["run set-up and summary"] = setup
    acc[RUN_LOOP] -= setup
    total = sum(acc.values())
    print(f"scout loop: {1e6 * per_tick:.0f} us CPU per control tick (thread time, unwrapped run)")
    print(
        f"(a wrapper's own cost per call, taken off: {1e6 * overhead[0]:.2f} us inside, {1e6 * overhead[1]:.2f} out)"
    )
    for part, t in acc.most_common():
        print(f"{100 * t / total:5.1f} %  {1e6 * per_tick * t / total:6.0f} us  {part}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
