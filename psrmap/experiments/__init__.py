"""The seed paper's experiments, reproduced and extended: `psrmap experiment {ramps,slopes,lunar,utility,all}`.

    psrmap experiment ramps   [--seeds 0] [--runs 4] [--angles 5,10,15,20] [--out DIR]
    psrmap experiment slopes  [--seeds 0] [--runs 4] [--out DIR]
    psrmap experiment lunar   [--seeds 0,1,2,3,4] [--runs 1] [--slippery-patches 4] [--out DIR]
    psrmap experiment utility [--seeds 0,1,2,3,4] [--runs 1] [--scouts west,east] [--unknown infer]
                              [--slip-spread 0.8] [--out DIR]
    psrmap experiment all     [--out DIR]        # each experiment in DIR/<name>/, runs shared

Without `--out`, the folder is `runs/<timestamp>-<experiment>/`. Each writes `results.json` (every figure
quoted in docs/results.md) and PNG figures into its folder, with a tqdm bar over the runs. Independent runs
go to `--workers` spawn processes (default 2); every run is cached in `<out>/runs/`, so a second experiment
needing the same walk reads it instead (`--fresh` ignores the cache).

Modules: `config` (the options), `psrmap_common` (a run's spec, the worker, the pool), `maps` (runs' cells merged,
saved for the planner, laid out densely), one module per experiment, `plots` and `report`. The simulator
(MuJoCo, Pinocchio), the planner (numba) and matplotlib are imported inside the functions that walk, plan or
draw, so `psrmap experiment --help` loads numpy and the map code only.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import Any

from psrmap.experiments import lunar, ramps, slopes, utility
from psrmap.experiments.common import RunPool, write_json
from psrmap.experiments.config import ExperimentConfig, ExperimentError, from_args
from psrmap_common.cli_parser import Subparsers, positive_int
from psrmap_common.errors import UsageError

__all__ = ["EXPERIMENTS", "register", "run_experiment"]

EXPERIMENTS = {"ramps": ramps, "slopes": slopes, "lunar": lunar, "utility": utility}
OPTIONS_FROM = {"ramps": (ramps,), "slopes": (ramps, slopes), "lunar": (lunar,), "utility": (lunar, utility)}


def _seeds(text: str) -> list[int]:
    try:
        vals = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--seeds {text!r}: give integers separated by commas, e.g. 0,1,2"
        ) from None
    if not vals or any(v < 0 for v in vals):
        raise argparse.ArgumentTypeError(f"--seeds {text!r}: need at least one seed ≥ 0")
    return vals


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--out",
        metavar="DIR",
        help="output folder (results.json, PNGs, run cache); default runs/<timestamp>-<experiment>/",
    )
    p.add_argument(
        "--seeds",
        type=_seeds,
        metavar="S,...",
        help="seeds (ramps/slopes: noise seeds ×100 + run; lunar/utility: terrain seeds); "
        "default per experiment: ramps/slopes 0, lunar/utility 0,1,2,3,4",
    )
    p.add_argument(
        "--runs",
        type=positive_int,
        metavar="N",
        help="runs per seed and condition (default: ramps/slopes 4, lunar/utility 1)",
    )
    p.add_argument(
        "--workers", type=positive_int, default=2, help="parallel simulation processes (default 2)"
    )
    p.add_argument(
        "--sim-seconds",
        type=float,
        metavar="S",
        help="cap on each run's simulated time (reduced sets; default: the whole path)",
    )
    p.add_argument(
        "--sensors",
        choices=("realistic", "ideal"),
        help="sensor profile of every walk (default realistic; ideal: the models before issue 23)",
    )
    p.add_argument(
        "--launch",
        choices=("survey", "exact"),
        help="start given to every scout: a lander survey (default) or the exact pose (comparison only)",
    )
    p.add_argument("--fresh", action="store_true", help="walk every run again instead of reading the cache")
    p.add_argument(
        "--cache", metavar="DIR", help="run cache folder (default OUT/runs); share it between --out folders"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def register(subparsers: Subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "experiment",
        help="reproduce the seed paper's experiments (and the map-utility one)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="experiment", metavar="EXPERIMENT", required=True)
    for name in (*EXPERIMENTS, "all"):
        mod = EXPERIMENTS.get(name)
        doc = (
            (mod.__doc__ or name) if mod else "every experiment in turn, runs shared, each in DIR/<name>/"
        ).strip()
        q = sub.add_parser(
            name,
            help=doc.splitlines()[0],
            description=doc,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        _add_common(q)
        for m in EXPERIMENTS.values() if name == "all" else OPTIONS_FROM[name]:
            m.add_arguments(q)
        q.set_defaults(func=_cmd)
    return p


def _resolved(args: argparse.Namespace, mod: ModuleType) -> ExperimentConfig:
    return from_args(args, tuple(_seeds(mod.DEFAULT_SEEDS)), mod.DEFAULT_RUNS)


def run_experiment(name: str, args: argparse.Namespace, pool: RunPool, out_dir: Path) -> dict[str, Any]:
    """Run one experiment into `out_dir` (results.json + PNGs); returns its results."""
    mod = EXPERIMENTS[name]
    ns = dataclasses.replace(_resolved(args, mod), experiment=name)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    walked0, ws0 = pool.walked, pool.worker_seconds
    res = mod.run(ns, pool, out_dir)
    res["timing"] = {
        "wall_seconds": round(time.perf_counter() - t0, 1),
        "runs_walked": pool.walked - walked0,
        "worker_seconds": round(pool.worker_seconds - ws0, 1),
        "workers": pool.workers,
    }
    res["command"] = _command(args)
    write_json(out_dir / "results.json", res)
    return res


def _command(args: argparse.Namespace) -> str:
    return (
        "psrmap " + " ".join(sys.argv[1:])
        if sys.argv and "experiment" in sys.argv
        else f"experiment {args.experiment}"
    )


def _cmd(args: argparse.Namespace) -> int:
    if args.sim_seconds is not None and not args.sim_seconds > 0:
        raise UsageError(f"--sim-seconds {args.sim_seconds}: need > 0")
    out = Path(args.out or f"runs/{time.strftime('%Y%m%d-%H%M%S')}-{args.experiment}")
    cache = Path(args.cache) if args.cache else out / "runs"
    pool = RunPool(cache, workers=args.workers, progress=not args.quiet, fresh=args.fresh)
    try:
        return _run(args, out, pool)
    except ExperimentError as exc:
        raise UsageError(str(exc)) from None


def _run(args: argparse.Namespace, out: Path, pool: RunPool) -> int:
    t0 = time.perf_counter()
    if args.experiment != "all":
        res = run_experiment(args.experiment, args, pool, out)
        print(f"{args.experiment}: {res['timing']['wall_seconds']} s, results in {out / 'results.json'}")
        return 0
    # every run known up front in one pool, so both workers stay busy across experiments
    everything = [
        s
        for name, mod in EXPERIMENTS.items()
        for s in mod.specs(dataclasses.replace(_resolved(args, mod), experiment=name))
    ]
    pool.run(everything, desc="all runs")
    summary: dict[str, Any] = {"experiments": {}}
    for name in EXPERIMENTS:
        res = run_experiment(name, args, pool, out / name)
        summary["experiments"][name] = {
            "results": f"{name}/results.json",
            "timing": res["timing"],
            "figures": res.get("figures", []),
        }
    summary["timing"] = {
        "wall_seconds": round(time.perf_counter() - t0, 1),
        "runs_walked": pool.walked,
        "worker_seconds": round(pool.worker_seconds, 1),
        "workers": pool.workers,
    }
    summary["machine"] = {
        "python": platform.python_version(),
        "cpus": _cpus(),
        "platform": platform.platform(),
    }
    summary["command"] = _command(args)
    write_json(out / "results.json", summary)
    print(f"all: {summary['timing']['wall_seconds']} s wall, {pool.walked} runs walked; results in {out}")
    return 0


def _cpus() -> int | None:
    return os.cpu_count()
