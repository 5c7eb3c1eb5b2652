"""The scout's state estimator: base orientation, velocity and position from the IMU, leg kinematics and contacts.

`StateEstimator` (estimator.py) runs every control tick inside the scout loop on sensor readings only
(`scout_agent.onboard.drivers.SensorTick`) and the mission's launch pose; `ErrorStateEKF` (ekf.py) is its filter and
`leg_odometry.py` turns encoders + gyro into base-velocity measurements from the stance feet.
"""

from __future__ import annotations

from .ekf import ErrorStateEKF, NoiseConfig
from .estimator import EstimatorConfig, LaunchPose, StateEstimate, StateEstimator
from .leg_odometry import stance_velocity_measurements

__all__ = [
    "ErrorStateEKF",
    "EstimatorConfig",
    "LaunchPose",
    "NoiseConfig",
    "StateEstimate",
    "StateEstimator",
    "stance_velocity_measurements",
]
