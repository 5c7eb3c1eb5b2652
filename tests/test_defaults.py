"""One source of truth: every entry point's defaults agree with `psrmap_common.defaults` and with each other."""

from __future__ import annotations

import argparse
import dataclasses

from consumer_planner.cost_config import Weights
from map_server.service import ServerConfig
from psrmap.cli import build_parser
from psrmap.mission.config import MissionConfig, load_config
from psrmap_common.defaults import DEFAULT_DELTA_HZ, DEFAULT_MAP_ID, DEFAULT_RES_M, DEFAULT_SEED, DEFAULT_TILE
from scout_agent.component import ScoutConfig
from scout_agent.mapping import MapperConfig
from scout_agent.run import ScoutRunConfig

# a flag's destination -> the one default every command that has it must show
SHARED = {
    "res": DEFAULT_RES_M,
    "seed": DEFAULT_SEED,
    "tile": DEFAULT_TILE,
    "map_id": DEFAULT_MAP_ID,
    "delta_hz": DEFAULT_DELTA_HZ,
}


def _subparsers(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield name, sub
                for sub_name, subsub in _subparsers(sub):
                    yield f"{name} {sub_name}", subsub


def test_every_command_flag_shares_one_default() -> None:
    checked = []
    for name, sub in _subparsers(build_parser([], full=True)):
        for action in sub._actions:
            if action.dest in SHARED and action.default is not None:
                assert action.default == SHARED[action.dest], (
                    f"psrmap {name} --{action.dest.replace('_', '-')} defaults to {action.default!r}, "
                    f"psrmap_common.defaults says {SHARED[action.dest]!r}"
                )
                checked.append((name, action.dest))
    commands_with_res = {n for n, d in checked if d == "res"}
    assert {"scout", "server", "evaluate"} <= commands_with_res, checked


def test_component_configs_and_mission_toml_share_the_defaults() -> None:
    run = ScoutRunConfig()
    assert run.seed == DEFAULT_SEED
    assert ScoutConfig(run=run).res == MapperConfig().res == ServerConfig().res == DEFAULT_RES_M
    assert ScoutConfig(run=run).delta_hz == MapperConfig().delta_hz == DEFAULT_DELTA_HZ
    assert ServerConfig().tile == MissionConfig().tile == DEFAULT_TILE
    assert ServerConfig().map_id == MissionConfig().map == DEFAULT_MAP_ID
    toml = load_config()  # the embedded default mission
    assert (toml.res, toml.tile, toml.seed, toml.rate_hz, toml.map) == (
        DEFAULT_RES_M,
        DEFAULT_TILE,
        DEFAULT_SEED,
        DEFAULT_DELTA_HZ,
        DEFAULT_MAP_ID,
    )


def test_plan_and_mission_plan_with_the_same_weights() -> None:
    """`psrmap plan` uses `Weights()`; the default mission must not override any of them."""
    assert load_config().weights == {}
    w = Weights()
    assert all(v >= 0 for v in dataclasses.asdict(w).values())
