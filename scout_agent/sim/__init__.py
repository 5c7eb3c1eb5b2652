"""The simulated world and hardware: terrains with exact ground truth, friction maps, the orbiter's DEM, the
MuJoCo scene, the sensor models (`sensors`) and `SimulatedAliengo` (`aliengo.py`: `lowlevel.LowCmd` in,
`lowlevel.LowState` out, `signals.GroundTruth` on the evaluation channel). Nothing here imports the robot's
software; `scout_agent.loop` joins the two."""

from scout_agent.sim.aliengo import HardwareConfig, SimulatedAliengo
from scout_agent.sim.friction import FrictionMap, Patch
from scout_agent.sim.terrain import LUNAR_ROUTES, LunarConfig, RampConfig, Terrain, make_lunar, make_ramps

__all__ = [
    "LUNAR_ROUTES",
    "FrictionMap",
    "HardwareConfig",
    "LunarConfig",
    "Patch",
    "RampConfig",
    "SimulatedAliengo",
    "Terrain",
    "make_lunar",
    "make_ramps",
]
