"""The non-foot contact detector against the simulator's truth over a window of a `psrmap evaluate` walk.

Runs the walk through `evaluate`'s own path (`Evaluator.on_tick`, so the pilot feels what `psrmap evaluate`'s
scout feels, tick for tick) up to `--t1`, and over [`--t0`, `--t1`] reports the detector's low-passed unexplained
force (max, 99th percentile), its flagged ticks and runs of the reflex's `contact_ticks`, the ticks the truth had a
leg or the trunk on the ground, and the hazard stops. Prints one JSON object.

    python benchmarks/nonfoot_window.py --t0 620 --t1 656 -- --scene lunar --field 100 --route direct \
        --seed 35 --localize on

(Arguments after `--` are `psrmap evaluate`'s.) docs/results.md, "Contact stops from the robot's dynamics".
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from scout_agent import cli
from scout_agent.control.reflex import ReflexConfig
from scout_agent.evaluate import Evaluator
from scout_agent.run import build_world, run_scout


class _Done(Exception):
    pass


def main() -> int:
    argv = sys.argv[1:]
    rest = argv[argv.index("--") + 1 :] if "--" in argv else []
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.splitlines()[0])
    ap.add_argument("--t0", type=float, required=True, help="window start [s, simulated]")
    ap.add_argument("--t1", type=float, required=True, help="window end [s]; the walk stops there")
    args = ap.parse_args(argv[: argv.index("--")] if "--" in argv else argv)
    if not 0.0 <= args.t0 < args.t1:
        ap.error(f"--t0 {args.t0} --t1 {args.t1}: need 0 <= t0 < t1")
    sub = argparse.ArgumentParser().add_subparsers()
    cfg = cli.config_from_args(cli.register_evaluate(sub).parse_args(rest))
    ev = Evaluator()
    force: list[float] = []
    flagged: list[bool] = []
    truth: list[int] = []
    stops: list[dict] = []

    def on_tick(sample, gt, robot=None):
        est = ev.on_tick(sample, gt, robot)
        if sample.t >= args.t0:
            force.append(est.nonfoot_force_n)
            flagged.append(est.nonfoot)
            truth.append(gt.nonfoot_contacts)
        if sample.t >= args.t1:
            raise _Done
        return est

    def on_hazard(felt):
        stops.append(
            {"t": round(felt.t, 2), "x": round(felt.x, 2), "y": round(felt.y, 2), "reasons": felt.reasons}
        )
        ev.on_hazard(felt)

    try:
        run_scout(
            cfg,
            on_tick=on_tick,
            progress=False,
            world=build_world(cfg),
            on_hazard=on_hazard,
            on_fix=ev.on_fix,
        )
    except _Done:
        pass
    f, fl, tr = np.array(force), np.array(flagged, bool), np.array(truth)
    run, runs = 0, 0
    for x in fl.tolist():
        run = run + 1 if x else 0
        runs += run == ReflexConfig().contact_ticks
    print(
        json.dumps(
            {
                "window_s": [args.t0, args.t1],
                "ticks": int(len(f)),
                "force_max_n": round(float(f.max()), 2) if len(f) else None,
                "force_p99_n": round(float(np.percentile(f, 99)), 2) if len(f) else None,
                "flagged_ticks": int(fl.sum()),
                "flagged_runs": runs,
                "truth_nonfoot_ticks": int((tr > 0).sum()),
                "flagged_true_ticks": int((fl & (tr > 0)).sum()),
                "hazard_stops": [s for s in stops if s["t"] >= args.t0],
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
