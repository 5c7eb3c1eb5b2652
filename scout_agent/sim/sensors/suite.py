"""`SensorSuite`: one robot's sensors, sampled every physics step, delivered once per control tick.

The simulated Aliengo (`sim/aliengo.py`) hands the suite the exact values of the k physics steps of one control
tick (`TrueBlock`); the suite returns what the robot's drivers and IMU report, the `lowlevel.LowState` the
robot's software receives. These models are part of the simulated hardware: they say what a real device reads
(noise, biases, quantisation, drift, saturation, lost packets). What the software makes of the readings (contact
flags, the state estimate) is on the robot's side (`scout_agent.onboard`, `scout_agent.state_estimation`).

Two profiles (`SensorConfig.realistic()`, the default, and `SensorConfig.ideal()`, the models as they were
before issue 23, for comparison: `psrmap scout|evaluate --sensors ideal`). Realistic adds, beside the IMU's
own errors (`imu.ImuErrors`), the joint zero offsets (`joints.py`) and the foot sensors' drift and saturation
(`foot_pressure.py`):
- **the IMU where a real one sits**: off the trunk origin at `imu_offset_m` (the Unitree Aliengo URDF puts its
  `imu_link` at the trunk origin, a placeholder; MuJoCo Menagerie's Unitree Go1 model, the same maker's next
  trunk, has its IMU site at (−0.01592, −0.06659, −0.00617) m, which is used here). The simulator moves its IMU
  site there; the state estimator knows the offset (a CAD value) and removes the lever arm;
- **link lengths** of the simulated robot differ from the nominal model the robot's software uses
  (thigh and calf, σ `link_length_std_m` = 1 mm each, assumed machining/assembly tolerance of a 0.25 m link);
- **time stamps with jitter, and dropped packets** (`LinkTiming`): the low-level state reaches the robot's
  software over UDP (Unitree legged_sdk) with a time stamp jittered by σ 0.2 ms and is lost with probability
  0.5 % (assumed: a non-real-time Linux user-space receiver; Unitree publishes none). A lost packet leaves the
  software with the previous reading (`LowState.fresh` False); its joint energy arrives with the next one
  (the driver integrates it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from scout_agent.errors import ScoutConfigError
from scout_agent.lowlevel import LowState

from .foot_pressure import ContactConfig, FootContactSensors, _readings
from .imu import ImuConfig, ImuErrors, ImuModel, _imu_block
from .joints import JointSensorConfig, JointSensors, _joint_block

SENSOR_PROFILES = ("realistic", "ideal")
GO1_IMU_OFFSET_M = (-0.01592, -0.06659, -0.00617)  # MuJoCo Menagerie unitree_go1: imu site [m], trunk frame


@dataclass(frozen=True)
class LinkTiming:
    """The low-level state's delivery to the robot's software (module docstring: sources)."""

    jitter_s: float = 2e-4  # σ of each reading's time-stamp error [s]
    packet_drop: float = 0.005  # probability a tick's reading is lost


def _realistic_joints() -> JointSensorConfig:
    return JointSensorConfig(zero_offset_rad=np.radians(0.3))


def _realistic_contact() -> ContactConfig:
    return ContactConfig(offset_walk_n=0.03, saturation_n=120.0)


@dataclass(frozen=True)
class SensorConfig:
    """Default: the realistic profile. `SensorConfig.ideal()`: none of issue 23's errors."""

    imu: ImuConfig = field(default_factory=ImuConfig)
    joints: JointSensorConfig = field(default_factory=_realistic_joints)
    contact: ContactConfig = field(default_factory=_realistic_contact)
    imu_errors: ImuErrors = field(default_factory=ImuErrors)
    timing: LinkTiming = field(default_factory=LinkTiming)
    imu_offset_m: tuple[float, float, float] = GO1_IMU_OFFSET_M  # IMU position on the trunk [m]
    link_length_std_m: float = 1e-3  # σ of each thigh/calf length's error on the simulated robot [m]
    profile: str = "realistic"  # a label: one of SENSOR_PROFILES
    seed: int = 0

    @classmethod
    def realistic(cls, **kw) -> SensorConfig:
        return cls(**kw)

    @classmethod
    def ideal(cls, **kw) -> SensorConfig:
        return cls(
            **{
                "joints": JointSensorConfig(),
                "contact": ContactConfig(),
                "imu_errors": ImuErrors.none(),
                "timing": LinkTiming(0.0, 0.0),
                "imu_offset_m": (0.0, 0.0, 0.0),
                "link_length_std_m": 0.0,
                "profile": "ideal",
                **kw,
            }
        )

    @classmethod
    def named(cls, profile: str, **kw) -> SensorConfig:
        if profile not in SENSOR_PROFILES:
            raise ScoutConfigError(
                f"sensor profile {profile!r} unknown; profiles: {', '.join(SENSOR_PROFILES)}"
            )
        return cls.ideal(**kw) if profile == "ideal" else cls.realistic(**kw)


def link_length_errors(config: SensorConfig) -> np.ndarray:
    """(4, 2) thigh and calf length errors [m] of the simulated robot (its own seeded stream)."""
    if not config.link_length_std_m:
        return np.zeros((4, 2))
    return np.random.default_rng([config.seed, 0x11AC]).normal(0.0, config.link_length_std_m, (4, 2))


class TrueBlock(NamedTuple):
    """Exact values over the k physics steps of one tick (what the physical sensors sense)."""

    dt: float  # physics step [s]
    acc: np.ndarray  # (k, 3) specific force at the IMU site, base frame [m/s²]
    gyro: np.ndarray  # (k, 3) angular velocity, base frame [rad/s]
    q: np.ndarray  # (k, 12) joint angles [rad]
    tau: np.ndarray  # (k, 12) actuator joint torques [N·m]
    foot_normal_n: np.ndarray  # (4,) normal ground force on each foot at the tick's end [N]


class SensorSuite:
    def __init__(self, config: SensorConfig, q0: np.ndarray) -> None:
        self.config = config
        rng = np.random.default_rng([config.seed, 0x5E45])
        self.imu = ImuModel(config.imu, rng, config.imu_errors)
        self.joints = JointSensors(config.joints, rng, q0)
        self.feet = FootContactSensors(config.contact, rng)
        self._link_rng = np.random.default_rng([config.seed, 0x7173])  # timing: its own stream
        self.t = 0.0  # true time of the last reading [s]
        self._last: LowState | None = None
        self._energy_pending = 0.0  # joint energy of lost packets, delivered with the next one [J]
        self.dropped = 0  # packets lost so far

    def read(self, block: TrueBlock) -> LowState:
        cfg = self.config
        k = len(block.q)
        self.t += k * block.dt
        # the three models' draws in their order, then their arithmetic in one compiled call
        imu_args = self.imu.block_args(block.acc, block.gyro, block.dt)
        joint_args = self.joints.block_args(block.q, block.tau, block.dt)
        feet_args = self.feet.reading_args(block.foot_normal_n, k * block.dt)
        acc, gyro, energy, pressure = _sensor_tick(imu_args, joint_args, feet_args)
        q, dq, tau = joint_args[-3], joint_args[-2], joint_args[-1]
        tm = cfg.timing
        if tm.packet_drop and self._last is not None and self._link_rng.random() < tm.packet_drop:
            self.dropped += 1
            self._energy_pending += energy
            return self._last._replace(joint_energy_j=0.0, fresh=False)
        stamp = self.t + (self._link_rng.normal(0.0, tm.jitter_s) if tm.jitter_s else 0.0)
        tick = LowState(
            acc,
            gyro,
            q[-1],
            dq[-1],
            tau[-1],
            energy + self._energy_pending,
            pressure,
            stamp,
            True,
            self.imu.temperature_c() if cfg.profile != "ideal" else math.nan,
        )
        self._energy_pending = 0.0
        self._last = tick
        return tick


@njit(cache=True, nogil=True)
def _sensor_tick(imu: tuple, joints: tuple, feet: tuple) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The tick's sensor arithmetic in one compiled call (one dispatch instead of six): the IMU block's tick
    means (accelerometer, gyroscope), the joints' block (its q, dq, tau land in the last three arrays of
    `joints`) and energy [J], the foot pressure readings; each model's own kernel on its `*_args` tuple."""
    acc, gyro = _imu_block(*imu)
    energy = _joint_block(*joints)
    return _mean_rows(acc), _mean_rows(gyro), energy, _readings(*feet)


@njit(cache=True, nogil=True)
def _mean_rows(a: np.ndarray) -> np.ndarray:
    """Column means of a (k, 3) block (the tick's mean reading), compiled: twice every tick."""
    out = np.zeros(3)
    for r in range(a.shape[0]):
        for j in range(3):
            out[j] += a[r, j]
    return out / a.shape[0]
