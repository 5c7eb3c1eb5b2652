"""Sensor models: what a real Aliengo's sensors report, made from the simulator's exact state.

Every field of `scout_agent.signals.ProprioSample` comes from one of these models (and the state estimator,
`scout_agent.state_estimation`, for the base state); the simulator's exact state is read here and nowhere else on
the robot's side. Each model is seeded, and its defaults name the real part they are taken from.

| module | sensor | rate |
|---|---|---|
| `imu.py` | accelerometer + gyroscope: white noise, turn-on bias, bias random walk | every physics step (500 Hz) |
| `joints.py` | joint encoders (quantised), driver joint velocity, joint torque from motor current, driver energy | every physics step |
| `foot_pressure.py` | 1-D foot pressure sensors → contact flags with hysteresis; contact from joint torques (option) | control tick |
| `suite.py` | `SensorSuite`: all of them for one robot, one `SensorTick` per control tick; the realistic and ideal profiles, IMU mounting offset, link-length errors, time stamps and lost packets | |
"""

from __future__ import annotations

from .foot_pressure import ContactConfig, FootContactSensors, leg_forces_from_torques
from .imu import IMU_PRESETS, ImuConfig, ImuErrors, ImuModel, ImuTemperature
from .joints import JointSensorConfig, JointSensors
from .suite import SENSOR_PROFILES, LinkTiming, SensorConfig, SensorSuite, SensorTick

__all__ = [
    "ContactConfig",
    "FootContactSensors",
    "IMU_PRESETS",
    "ImuConfig",
    "ImuErrors",
    "ImuTemperature",
    "LinkTiming",
    "SENSOR_PROFILES",
    "ImuModel",
    "JointSensorConfig",
    "JointSensors",
    "SensorConfig",
    "SensorSuite",
    "SensorTick",
    "leg_forces_from_torques",
]
