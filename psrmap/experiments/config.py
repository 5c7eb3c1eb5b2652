"""The experiments' options as one frozen config: `ExperimentConfig`, built once from the command line.

Every experiment module (`ramps`, `slopes`, `lunar`, `utility`) reads its options from this config, never
from `argparse`; a bad value is an `ExperimentError` naming what would be valid (the CLI prints it).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from typing import Any

from psrmap.errors import PsrmapError

__all__ = ["ExperimentConfig", "ExperimentError", "from_args"]


class ExperimentError(PsrmapError, ValueError):
    """An experiment option that cannot run; the message names the valid values."""


@dataclass(frozen=True)
class ExperimentConfig:
    experiment: str  # ramps | slopes | lunar | utility | all
    seeds: tuple[int, ...]
    runs: int
    sim_seconds: float | None = None  # cap on each run's simulated time (reduced sets)
    sensors: str = "realistic"  # sensor profile of every walk (scout_agent.sim.sensors.SENSOR_PROFILES)
    launch: str = "survey"  # the start every walk is given (state_estimation.launch.LAUNCH_MODES)
    # ramps / slopes
    angles: tuple[float, ...] = (5.0, 10.0, 15.0, 20.0)
    slippery: dict[float, float] = field(default_factory=dict)  # down-ramp patch μ per angle
    no_slippery: bool = False
    # lunar / utility
    slippery_patches: int = 4
    lunar_seconds: float | None = None  # cap on the lunar scouts' simulated time (None: sim_seconds)
    scouts: str = "west,east"
    utility_from: tuple[float, float] = (1.5, 1.5)
    utility_to: tuple[float, float] = (18.5, 18.5)
    unknown: str = "infer"
    weights: str = ""
    slip_spread: float | None = None  # None: the planner's default


def from_args(
    args: argparse.Namespace, default_seeds: tuple[int, ...], default_runs: int
) -> ExperimentConfig:
    """The parsed options (with the experiment's own defaults for seeds and runs) as a config."""
    names = set(ExperimentConfig.__dataclass_fields__)
    given: dict[str, Any] = {k: v for k, v in vars(args).items() if k in names and v is not None}
    given["experiment"] = args.experiment
    given["seeds"] = tuple(args.seeds) if args.seeds is not None else default_seeds
    given["runs"] = args.runs if args.runs is not None else default_runs
    if "angles" in given:
        given["angles"] = tuple(given["angles"])
    return ExperimentConfig(**given)
