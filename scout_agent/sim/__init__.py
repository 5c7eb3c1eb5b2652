"""Simulation: terrains with exact ground truth, friction maps, the MuJoCo scene and `ScoutSim`."""

from scout_agent.sim.friction import FrictionMap, Patch
from scout_agent.sim.simulator import STATE_SOURCES, ScoutSim, SimConfig
from scout_agent.sim.terrain import LUNAR_ROUTES, LunarConfig, RampConfig, Terrain, make_lunar, make_ramps

__all__ = [
    "LUNAR_ROUTES",
    "STATE_SOURCES",
    "FrictionMap",
    "LunarConfig",
    "Patch",
    "RampConfig",
    "ScoutSim",
    "SimConfig",
    "Terrain",
    "make_lunar",
    "make_ramps",
]
