"""The Unitree Aliengo: constants, the MJCF built in code, and leg kinematics (Pinocchio + closed form)."""

from scout_agent.robot.constants import FOOT_RADIUS, HOME_Q, TOTAL_MASS
from scout_agent.robot.kinematics import LegKinematics
from scout_agent.robot.model import aliengo_mjcf, build_aliengo_spec

__all__ = ["FOOT_RADIUS", "HOME_Q", "TOTAL_MASS", "LegKinematics", "aliengo_mjcf", "build_aliengo_spec"]
