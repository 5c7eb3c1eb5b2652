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
force and angular velocity at the IMU site (MuJoCo `accelerometer` / `gyro` sensors), trunk frame.

`ImuErrors` (on by default in the scout, `--sensors realistic`; `ImuErrors.none()` is the ideal model above) adds
what a real part on a real robot also does, each drawn once per run from the run seed:
- **bias that drifts with temperature**: the power-on calibration removes the offset at the power-on
  temperature; the board then warms (`ImuTemperature`: a first-order warm-up plus a slow change) and each
  axis's offset moves by its temperature coefficient (TCO), drawn N(0, datasheet TCO²) per axis (Bosch gives
  typical values as 1σ). BMI088 datasheet: gyro TCO ±0.015 °/s/K, accelerometer TCO < 0.2 mg/K;
- **scale factor** and **cross-axis sensitivity** (off-diagonal terms): gyro 1 % each (BMI088 sensitivity
  tolerance ±1 %; the ≈ 1 % class of MEMS IMUs; a rate table is needed to calibrate them, so they stay);
  accelerometer 0.1 % each, the residual of the same six-position bench calibration that leaves its 1 mg bias
  (assumed: that calibration fits scale and cross-axis along with the offset);
- **mounting misalignment** of the sensor frame on the trunk: σ 0.1° about roll and pitch (the residual of a
  level-stand calibration, gravity against the leg kinematics; assumed) and 0.3° about yaw (not calibrated that
  way: PCB and board mounting tolerance; assumed); the estimator does not know it;
- **g-sensitivity** of the gyro: BMI088 0.1 °/s/g, per matrix element N(0, that²), on the specific force's
  change since the power-on calibration (which absorbed the standing value);
- **quantisation**: 16-bit outputs, gyro range ±1000 °/s (0.0305 °/s per LSB), accelerometer ±3 g
  (0.092 mg per LSB) (BMI088 register map: signed 16-bit, range set in GYRO_RANGE / ACC_RANGE);
- **dropped samples**: each 500 Hz sample is lost with probability 0.2 % (assumed: FIFO/SPI read misses on a
  busy board); the tick's mean is over the samples that arrived;
- the on-chip **thermometer** (BMI088: 11-bit, 0.125 K per LSB) is read, so the robot knows the temperature
  change, not the coefficients: the state estimator widens its bias uncertainty by TCO × ΔT (estimator.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

_G0 = 9.80665  # [m/s²] per g (datasheet units)
_DEG = np.pi / 180.0


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


@dataclass(frozen=True)
class ImuTemperature:
    """The IMU's temperature change since power-on: a warm-up of `warmup_k` with time constant `warmup_tau_s`,
    plus a slow change of `rate_k_per_h` (assumed values: the IMU sits on the main board beside the motor
    drivers and computer, which warm it by several kelvin over the first tens of minutes; the robot then moves
    between sunlit and shadowed ground). Time from power-on [s]."""

    warmup_k: float = 8.0  # [K]
    warmup_tau_s: float = 600.0  # [s]
    rate_k_per_h: float = 2.0  # [K/h]

    def delta_k(self, t_s: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        return self.warmup_k * (1.0 - np.exp(-t / self.warmup_tau_s)) + self.rate_k_per_h * t / 3600.0

    def delta_k_steps(self, t0_s: float, dt_s: float, k: int) -> np.ndarray:
        """`delta_k` at t0 + dt, …, t0 + k·dt [s] (compiled: the IMU samples k steps every tick; libm's exp,
        which may differ from numpy's vectorised one in the last bit, far below the 16-bit quantisation)."""
        return _temperature_steps(t0_s, dt_s, k, self.warmup_k, self.warmup_tau_s, self.rate_k_per_h)

    def delta_k_at(self, t_s: float) -> float:
        """`delta_k` at one time [s] (scalar arithmetic: the thermometer is read every tick)."""
        return self.warmup_k * (1.0 - math.exp(-t_s / self.warmup_tau_s)) + self.rate_k_per_h * t_s / 3600.0


@dataclass(frozen=True)
class ImuErrors:
    """Errors a real IMU on a real robot has beyond noise and bias walk (module docstring: sources)."""

    gyro_tempco: float = 0.015 * _DEG  # σ per axis of the zero-rate offset's TCO [rad/s/K] (BMI088)
    acc_tempco: float = 0.2e-3 * _G0  # σ per axis of the zero-g offset's TCO [m/s²/K] (BMI088)
    temperature: ImuTemperature = field(default_factory=ImuTemperature)
    temp_lsb_k: float = 0.125  # on-chip thermometer resolution [K] (BMI088)
    start_temp_c: float = 20.0  # board temperature at power-on [°C]
    gyro_scale: float = 0.01  # σ of the sensitivity error per axis (BMI088 ±1 %)
    acc_scale: float = 0.001  # σ after the six-position calibration (assumed)
    gyro_cross_axis: float = 0.01  # σ of each off-diagonal coupling
    acc_cross_axis: float = 0.001
    misalignment_rad: tuple[float, float, float] = (0.1 * _DEG, 0.1 * _DEG, 0.3 * _DEG)  # σ roll, pitch, yaw
    gyro_g_sensitivity: float = 0.1 * _DEG / _G0  # σ per element [rad/s per m/s²] (BMI088 0.1 °/s/g)
    gyro_lsb: float = 1000.0 * _DEG / 32768.0  # [rad/s] (±1000 °/s, 16 bit)
    acc_lsb: float = 3.0 * _G0 / 32768.0  # [m/s²] (±3 g, 16 bit)
    sample_drop: float = 0.002  # probability one 500 Hz sample is lost (assumed)

    @classmethod
    def none(cls) -> ImuErrors:
        """The ideal model: none of these errors (`--sensors ideal`)."""
        return cls(
            gyro_tempco=0.0,
            acc_tempco=0.0,
            temperature=ImuTemperature(0.0, 600.0, 0.0),
            temp_lsb_k=0.0,
            gyro_scale=0.0,
            acc_scale=0.0,
            gyro_cross_axis=0.0,
            acc_cross_axis=0.0,
            misalignment_rad=(0.0, 0.0, 0.0),
            gyro_g_sensitivity=0.0,
            gyro_lsb=0.0,
            acc_lsb=0.0,
            sample_drop=0.0,
        )


# the realistic errors of each preset's part. The ADIS16495 is calibrated by its maker over temperature, scale and
# alignment (its datasheet lists the residuals in other terms); taken here as a tenth of the BMI088's temperature
# coefficients and 0.1 % scale / cross-axis (assumed), on the same board, mounting and 16-bit quantisation
IMU_ERROR_PRESETS: dict[str, ImuErrors] = {
    "bmi088": ImuErrors(),
    "adis16495": ImuErrors(
        gyro_tempco=0.0015 * _DEG,
        acc_tempco=0.02e-3 * _G0,
        gyro_scale=0.001,
        gyro_cross_axis=0.001,
        gyro_g_sensitivity=0.01 * _DEG / _G0,
    ),
}


def _rotation(rv: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(rv))
    if th < 1e-12:
        return np.eye(3)
    k = rv / th
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * (K @ K)


def _gain_matrix(rng: np.random.Generator, scale: float, cross: float) -> np.ndarray:
    m = np.eye(3) + np.diag(rng.normal(0.0, scale, 3)) if scale else np.eye(3)
    if cross:
        off = rng.normal(0.0, cross, (3, 3))
        np.fill_diagonal(off, 0.0)
        m = m + off
    return m


class ImuModel:
    """`sample(acc_true, gyro_true, dt)` for a block of k physics steps ((k, 3) each) → noisy (k', 3) pair
    (k' ≤ k: the samples that arrived); `temperature_c()` the on-chip thermometer's reading."""

    def __init__(self, config: ImuConfig, rng: np.random.Generator, errors: ImuErrors | None = None) -> None:
        self.config = c = config
        self.errors = e = errors if errors is not None else ImuErrors.none()
        self.rng = rng
        self.acc_bias = rng.normal(0.0, c.acc_turn_on_bias, 3)
        self.gyro_bias = rng.normal(0.0, c.gyro_turn_on_bias, 3)
        # drawn once per part / per mounting (fixed order of draws: reproducible from the seed)
        self.gyro_tc = rng.normal(0.0, e.gyro_tempco, 3) if e.gyro_tempco else np.zeros(3)
        self.acc_tc = rng.normal(0.0, e.acc_tempco, 3) if e.acc_tempco else np.zeros(3)
        mis_std = np.asarray(e.misalignment_rad, dtype=float)
        mis = _rotation(rng.normal(0.0, 1.0, 3) * mis_std if mis_std.any() else np.zeros(3))
        self.gyro_M = _gain_matrix(rng, e.gyro_scale, e.gyro_cross_axis) @ mis.T  # trunk → sensor reading
        self.acc_M = _gain_matrix(rng, e.acc_scale, e.acc_cross_axis) @ mis.T
        self.gyro_G = rng.normal(0.0, e.gyro_g_sensitivity, (3, 3)) if e.gyro_g_sensitivity else None
        self._f_cal: np.ndarray | None = None  # specific force at the power-on calibration
        self.t = 0.0  # time since power-on [s]
        self._ideal = errors is None or errors == ImuErrors.none()

    def temperature_c(self) -> float:
        e = self.errors
        temp = e.start_temp_c + e.temperature.delta_k_at(self.t)
        return math.floor(temp / e.temp_lsb_k + 0.5) * e.temp_lsb_k if e.temp_lsb_k > 0 else temp

    def sample(self, acc_true: np.ndarray, gyro_true: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        return _imu_block(*self.block_args(acc_true, gyro_true, dt))

    def block_args(self, acc_true: np.ndarray, gyro_true: np.ndarray, dt: float) -> tuple:
        """`sample`'s random draws and state, as `_imu_block`'s arguments (the suite hands them to its one
        compiled call a tick, `suite._sensor_tick`): draws the tick's normals (and lost samples) and advances
        the IMU's clock."""
        c, k = self.config, len(acc_true)
        sq = math.sqrt(dt)  # a Python float: numpy scalar arithmetic costs ~1 µs here
        n = self.rng.standard_normal((4, k, 3))
        e, tc = self.errors, self.errors.temperature
        # the samples lost: those whose uniform draw u falls below `drop`
        u, drop = (_ALL_KEPT if k <= len(_ALL_KEPT) else np.ones(k)), 0.0
        if not self._ideal:
            if self._f_cal is None:
                self._f_cal = np.array(acc_true[0], dtype=float)
            # (a tick with every sample lost keeps its last one, p ≈ 3e-14: `_imu_block`)
            if e.sample_drop > 0:
                u, drop = self.rng.random(k), e.sample_drop
        t0 = self.t
        self.t += k * dt
        return (
            np.asarray(acc_true, dtype=float),
            np.asarray(gyro_true, dtype=float),
            n,
            self.acc_bias,
            self.gyro_bias,
            c.acc_bias_walk * sq,
            c.gyro_bias_walk * sq,
            c.acc_noise_density / sq,
            c.gyro_noise_density / sq,
            self._ideal,
            self.acc_M,
            self.gyro_M,
            self.acc_tc,
            self.gyro_tc,
            t0,
            dt,
            tc.warmup_k,
            tc.warmup_tau_s,
            tc.rate_k_per_h,
            self.gyro_G if self.gyro_G is not None else _NO_G,
            self._f_cal if self._f_cal is not None else _NO_F,
            e.acc_lsb,
            e.gyro_lsb,
            u,
            drop,
        )


@njit(cache=True, nogil=True)
def _temperature_steps(
    t0: float, dt: float, k: int, warmup_k: float, tau_s: float, rate_k_per_h: float
) -> np.ndarray:
    """`ImuTemperature.delta_k` at t0 + (s + 1)·dt for s < k [K]."""
    out = np.empty(k)
    for s in range(k):
        t = t0 + dt * (s + 1)
        out[s] = warmup_k * (1.0 - np.exp(-t / tau_s)) + rate_k_per_h * t / 3600.0
    return out


_ALL_KEPT = np.ones(64)  # uniform draws ≥ 0: no sample lost (up to 64 physics steps a tick)
_NO_G = np.zeros((3, 3))
_NO_F = np.zeros(3)


@njit(cache=True, nogil=True)
def _imu_block(
    acc_true: np.ndarray,
    gyro_true: np.ndarray,
    n: np.ndarray,
    acc_bias: np.ndarray,
    gyro_bias: np.ndarray,
    acc_walk: float,
    gyro_walk: float,
    acc_noise: float,
    gyro_noise: float,
    ideal: bool,
    acc_M: np.ndarray,
    gyro_M: np.ndarray,
    acc_tc: np.ndarray,
    gyro_tc: np.ndarray,
    t0: float,
    dt: float,
    warmup_k: float,
    warmup_tau_s: float,
    rate_k_per_h: float,
    gyro_G: np.ndarray,
    f_cal: np.ndarray,
    acc_lsb: float,
    gyro_lsb: float,
    u: np.ndarray,
    drop: float,
) -> tuple[np.ndarray, np.ndarray]:
    """`ImuModel.sample`'s arithmetic, compiled (the scout calls it every control tick): `n` (4, k, 3) the
    standard normal draws (bias walks, white noise); the samples that arrived are those with u ≥ `drop` (none:
    the last one); the biases walk in place. Ideal: truth + bias + noise; otherwise through the
    gain/misalignment matrices, temperature offsets (`ImuTemperature.delta_k` at t0 + dt, …, t0 + k·dt, its
    warm-up and rate), g-sensitivity and quantisation (module docstring)."""
    k = acc_true.shape[0]
    kept = np.empty(k, np.bool_)
    m = 0
    for s in range(k):
        kept[s] = u[s] >= drop
        m += kept[s]
    if m == 0:  # every sample of the tick lost: keep its last one
        kept[k - 1] = True
        m = 1
    dtemp = _temperature_steps(t0, dt, k, warmup_k, warmup_tau_s, rate_k_per_h)  # (unused when ideal)
    acc = np.empty((m, 3))
    gyro = np.empty((m, 3))
    walk_a = np.zeros(3)
    walk_g = np.zeros(3)
    row = 0
    for s in range(k):
        for j in range(3):
            walk_a[j] += n[0, s, j] * acc_walk
            walk_g[j] += n[1, s, j] * gyro_walk
        if not kept[s]:
            continue
        for j in range(3):
            ab, gb = acc_bias[j] + walk_a[j], gyro_bias[j] + walk_g[j]
            if ideal:
                acc[row, j] = acc_true[s, j] + ab + n[2, s, j] * acc_noise
                gyro[row, j] = gyro_true[s, j] + gb + n[3, s, j] * gyro_noise
                continue
            a = acc_true[s, 0] * acc_M[j, 0] + acc_true[s, 1] * acc_M[j, 1] + acc_true[s, 2] * acc_M[j, 2]
            g = (
                gyro_true[s, 0] * gyro_M[j, 0]
                + gyro_true[s, 1] * gyro_M[j, 1]
                + gyro_true[s, 2] * gyro_M[j, 2]
            )
            a = a + ab + acc_tc[j] * dtemp[s] + n[2, s, j] * acc_noise
            g = g + gb + gyro_tc[j] * dtemp[s] + n[3, s, j] * gyro_noise
            g += (
                (acc_true[s, 0] - f_cal[0]) * gyro_G[j, 0]
                + (acc_true[s, 1] - f_cal[1]) * gyro_G[j, 1]
                + (acc_true[s, 2] - f_cal[2]) * gyro_G[j, 2]
            )
            if acc_lsb > 0:
                a = np.floor(a / acc_lsb + 0.5) * acc_lsb
            if gyro_lsb > 0:
                g = np.floor(g / gyro_lsb + 0.5) * gyro_lsb
            acc[row, j] = a
            gyro[row, j] = g
        row += 1
    for j in range(3):
        acc_bias[j] += walk_a[j]
        gyro_bias[j] += walk_g[j]
    return acc, gyro
