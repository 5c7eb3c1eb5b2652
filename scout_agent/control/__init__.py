"""Locomotion: trot schedule, QP stance forces, swing trajectories, path follower, the trot controller."""

from scout_agent.control.controller import ControllerConfig, ControlOutput, RobotState, TrotController
from scout_agent.control.follower import FollowerConfig, PathFollower
from scout_agent.control.gait import GaitConfig, TrotGait

__all__ = [
    "ControlOutput",
    "ControllerConfig",
    "FollowerConfig",
    "GaitConfig",
    "PathFollower",
    "RobotState",
    "TrotController",
    "TrotGait",
]
