"""The Aliengo description, built in code as MJCF: one source for MuJoCo and Pinocchio.

Each joint carries two actuators: a torque motor (`*_tau`, feed-forward from the controller) and a joint
PD servo (`*_pd`, `ctrl` = target angle, gains set per tick by the controller) that MuJoCo evaluates at
every physics step, implicitly in velocity. Their sum is clamped at the joint to the motor torque limit
(`actuatorfrcrange`), so `qfrc_actuator` is the torque a real Aliengo motor would apply.
"""

from __future__ import annotations

import mujoco

from scout_agent.robot import constants as C
from scout_agent.signals import LEG_NAMES


def _v(values) -> str:
    return " ".join(f"{v:.9g}" for v in values)


def _inertial(mass: float, com, inertia) -> str:
    return f'<inertial pos="{_v(com)}" mass="{mass}" fullinertia="{_v(inertia)}"/>'


def _leg(leg: str, sx: int, sy: int) -> str:
    hip_com = (sx * C.HIP_COM[0], sy * C.HIP_COM[1], C.HIP_COM[2])
    hip_inertia = list(C.HIP_INERTIA)
    hip_inertia[3] *= sx * sy  # xy
    hip_inertia[4] *= sx  # xz
    hip_inertia[5] *= sy  # yz
    thigh_com = (C.THIGH_COM[0], sy * C.THIGH_COM[1], C.THIGH_COM[2])
    thigh_inertia = list(C.THIGH_INERTIA)
    thigh_inertia[3] *= sy
    thigh_inertia[5] *= sy
    lo_h, hi_h = C.JOINT_RANGES[0]
    lo_t, hi_t = C.JOINT_RANGES[1]
    lo_c, hi_c = C.JOINT_RANGES[2]
    t = C.TORQUE_LIMITS
    return f"""
      <body name="{leg}_hip" pos="{sx * C.HIP_X} {sy * C.HIP_Y} 0">
        {_inertial(C.HIP_MASS, hip_com, hip_inertia)}
        <joint name="{leg}_hip_joint" axis="1 0 0" range="{lo_h} {hi_h}" actuatorfrcrange="{-t[0]} {t[0]}"/>
        <geom name="{leg}_hip" type="cylinder" size="0.046 0.0209" pos="0 {sy * 0.083} 0" zaxis="0 1 0"
              contype="0" conaffinity="0" group="1"/>
        <body name="{leg}_thigh" pos="0 {sy * C.THIGH_OFFSET} 0">
          {_inertial(C.THIGH_MASS, thigh_com, thigh_inertia)}
          <joint name="{leg}_thigh_joint" axis="0 1 0" range="{lo_t} {hi_t}" actuatorfrcrange="{-t[1]} {t[1]}"/>
          <geom name="{leg}_thigh" type="capsule" fromto="0 0 -0.03 0 0 -0.22" size="0.02" class="body"/>
          <body name="{leg}_calf" pos="0 0 {-C.THIGH_LENGTH}">
            {_inertial(C.CALF_MASS, C.CALF_COM, C.CALF_INERTIA)}
            <joint name="{leg}_calf_joint" axis="0 1 0" range="{lo_c} {hi_c}" actuatorfrcrange="{-t[2]} {t[2]}"/>
            <geom name="{leg}_calf" type="capsule" fromto="0 0 -0.02 0 0 -0.20" size="0.012" class="body"/>
            <body name="{leg}_foot" pos="0 0 {-C.CALF_LENGTH}">
              {_inertial(C.FOOT_MASS, (0, 0, 0), [C.FOOT_INERTIA] * 3 + [0, 0, 0])}
              <geom name="{leg}_foot" type="sphere" size="{C.FOOT_RADIUS}" class="foot"/>
            </body>
          </body>
        </body>
      </body>"""


def aliengo_mjcf() -> str:
    """The robot alone (trunk with a free joint, 4 legs, actuators, IMU sensors) as an MJCF string."""
    legs = "".join(_leg(leg, sx, sy) for leg, (sx, sy) in zip(LEG_NAMES, C.LEG_SIGNS, strict=True))
    actuators = []
    for i, leg in enumerate(LEG_NAMES):
        for j, part in enumerate(("hip", "thigh", "calf")):
            lim = C.TORQUE_LIMITS[3 * i + j]
            actuators.append(
                f'<motor name="{leg}_{part}_tau" joint="{leg}_{part}_joint" ctrlrange="{-lim} {lim}"/>'
            )
    for leg in LEG_NAMES:
        for part in ("hip", "thigh", "calf"):
            actuators.append(
                f'<general name="{leg}_{part}_pd" joint="{leg}_{part}_joint" gainprm="0" biasprm="0 0 0"'
                ' biastype="affine" ctrllimited="false"/>'
            )
    return f"""<mujoco model="aliengo">
  <compiler angle="radian" autolimits="true"/>
  <default>
    <joint damping="{C.JOINT_DAMPING}" armature="{C.ARMATURE}"/>
    <geom rgba="0.3 0.3 0.35 1"/>
    <default class="body"><geom contype="1" conaffinity="1" condim="3" friction="0.7 0.005 0.0001"/></default>
    <default class="foot"><geom contype="1" conaffinity="1" condim="3" priority="1"
        friction="0.7 0.005 0.0001" rgba="0.1 0.1 0.1 1"/></default>
  </default>
  <worldbody>
    <body name="{C.TRUNK_BODY}" pos="0 0 0.38">
      <freejoint name="root"/>
      {_inertial(C.TRUNK_MASS, C.TRUNK_COM, C.TRUNK_INERTIA)}
      <geom name="trunk" type="box" size="{_v(s / 2 for s in C.TRUNK_SIZE)}" class="body" rgba="0.9 0.45 0.1 1"/>
      <site name="{C.IMU_SITE}" pos="0 0 0"/>{legs}
    </body>
  </worldbody>
  <actuator>
    {chr(10).join("    " + a for a in actuators)}
  </actuator>
  <sensor>
    <accelerometer name="imu_acc" site="{C.IMU_SITE}"/>
    <gyro name="imu_gyro" site="{C.IMU_SITE}"/>
  </sensor>
</mujoco>
"""


def build_aliengo_spec() -> mujoco.MjSpec:
    """The robot as an editable `MjSpec` (the scene adds terrain, options and lights to it)."""
    return mujoco.MjSpec.from_string(aliengo_mjcf())
