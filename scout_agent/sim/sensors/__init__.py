"""Sensor models, part of the simulated hardware: what a real Aliengo's sensors report, made from the
simulator's exact state.

Every raw reading of `scout_agent.lowlevel.LowState` comes from one of these models; the simulated Aliengo
(`scout_agent.sim.aliengo`) feeds them the exact values and hands their `LowState` to the robot's software.
Each model is seeded, and its defaults name the real part they are taken from. What the software computes from
the readings (contact flags: `scout_agent.onboard.drivers`; the base state: `scout_agent.state_estimation`) is
not here.

| module | sensor | rate |
|---|---|---|
| `imu.py` | accelerometer + gyroscope: white noise, turn-on bias, bias random walk | every physics step (500 Hz) |
| `joints.py` | joint encoders (quantised), driver joint velocity, joint torque from motor current, driver energy | every physics step |
| `foot_pressure.py` | 1-D foot pressure sensors: gain, offset, noise, drift, saturation | control tick |
| `suite.py` | `SensorSuite`: all of them for one robot, one `LowState` per control tick; the realistic and ideal profiles, IMU mounting offset, link-length errors, time stamps and lost packets | |
"""

from __future__ import annotations

from .foot_pressure import ContactConfig, FootContactSensors
from .imu import IMU_PRESETS, ImuConfig, ImuErrors, ImuModel, ImuTemperature
from .joints import JointSensorConfig, JointSensors
from .suite import SENSOR_PROFILES, LinkTiming, SensorConfig, SensorSuite

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
]
