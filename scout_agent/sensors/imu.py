"""IMU model: accelerometer and gyroscope with white noise, a turn-on bias and a bias random walk.

Defaults are the Bosch Sensortec BMI088 datasheet (BST-BMI088-DS001, rev. 1.x), a 6-axis MEMS IMU of the
class built into quadruped robots' main boards:
- accelerometer noise density 175 µg/√Hz (±3 g range) → 1.72e-3 m/s²/√Hz;
- gyroscope noise density 0.014 °/s/√Hz → 2.44e-4 rad/s/√Hz;
- turn-on bias: the datasheet's zero-rate offset (±1 °/s) and zero-g offset (±20 mg) are what a robot removes
  by calibration; what is left is drawn once per run: gyro σ = noise density / √(5 s) ≈ 1.1e-4 rad/s (the
  residual of averaging 5 s standing still at power-on) and accelerometer σ = 1 mg (a six-position calibration
  on the bench). Both stay unknown to the state estimator, which estimates them;
- bias instability (the datasheet gives none for the gyro's bias; ≈ 2 °/h ≈ 1e-5 rad/s is typical of the class)
  is modelled as a random walk of 1e-6 rad/s/√s (gyro: ≈ 1e-5 rad/s after 100 s) and 1e-4 m/s²/√s
  (accelerometer: ≈ 0.1 mg after 100 s).

Under lunar gravity the accelerometer's residual bias matters six times more than on Earth: the state estimator
cannot tell a horizontal bias b from a tilt b/g while the robot walks straight (1 mg → 0.35°), and that tilt
turns forward travel into height drift (≈ 0.6 % of the distance). `IMU_PRESETS["adis16495"]` is a tactical-grade
part (Analog Devices ADIS16495 datasheet, rev. B: angle random walk 0.09 °/√h, in-run gyro bias stability
0.8 °/h, velocity random walk 0.008 m/s/√h, accelerometer bias stability 3.2 µg; residual accelerometer bias
after calibration taken as 0.1 mg) for comparison: `psrmap scout|evaluate --imu adis16495`.
Discrete white noise at sample period dt has σ = density / √dt. The model reads the simulator's exact specific
force and angular velocity at the IMU site (MuJoCo `accelerometer` / `gyro` sensors), base frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_G0 = 9.80665  # [m/s²] per g (datasheet units)


@dataclass(frozen=True)
class ImuConfig:
    acc_noise_density: float = 175e-6 * _G0  # [m/s²/√Hz]
    gyro_noise_density: float = np.radians(0.014)  # [rad/s/√Hz]
    acc_turn_on_bias: float = 1e-3 * _G0  # σ per axis after calibration [m/s²]
    gyro_turn_on_bias: float = np.radians(0.014) / np.sqrt(5.0)  # σ per axis after calibration [rad/s]
    acc_bias_walk: float = 1e-4  # [m/s²/√s]
    gyro_bias_walk: float = 1e-6  # [rad/s/√s]


IMU_PRESETS: dict[str, ImuConfig] = {
    "bmi088": ImuConfig(),
    "adis16495": ImuConfig(
        acc_noise_density=0.008 / 60.0,
        gyro_noise_density=np.radians(0.09 / 60.0),
        acc_turn_on_bias=1e-4 * _G0,
        gyro_turn_on_bias=np.radians(0.09 / 60.0) / np.sqrt(5.0),
        acc_bias_walk=1e-5,
        gyro_bias_walk=1e-7,
    ),
}


class ImuModel:
    """`sample(acc_true, gyro_true, dt)` for a block of k physics steps ((k, 3) each) → noisy (k, 3) pair."""

    def __init__(self, config: ImuConfig, rng: np.random.Generator) -> None:
        self.config = c = config
        self.rng = rng
        self.acc_bias = rng.normal(0.0, c.acc_turn_on_bias, 3)
        self.gyro_bias = rng.normal(0.0, c.gyro_turn_on_bias, 3)

    def sample(self, acc_true: np.ndarray, gyro_true: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        c, k = self.config, len(acc_true)
        sq = np.sqrt(dt)
        n = self.rng.standard_normal((4, k, 3))
        # biases walk sample by sample; each sample sees the bias at its own instant
        acc_b = self.acc_bias + np.cumsum(n[0] * (c.acc_bias_walk * sq), axis=0)
        gyro_b = self.gyro_bias + np.cumsum(n[1] * (c.gyro_bias_walk * sq), axis=0)
        self.acc_bias, self.gyro_bias = acc_b[-1].copy(), gyro_b[-1].copy()
        acc = acc_true + acc_b + n[2] * (c.acc_noise_density / sq)
        gyro = gyro_true + gyro_b + n[3] * (c.gyro_noise_density / sq)
        return acc, gyro
