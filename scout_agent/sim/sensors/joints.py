"""Joint sensors as a motor driver reports them: encoder angle, joint velocity, torque from current, energy.

Defaults (`JointSensorConfig`), and where they come from:
- Encoders: Unitree's joint motors read a 15-bit magnetic encoder on the rotor, behind a ≈ 9:1 planetary
  gearbox (Unitree A1/Aliengo motor documentation). Resolution at the joint 2π / (2¹⁵ · 9) ≈ 2.1e-5 rad; the
  default is a coarser 2π / 2¹⁶ ≈ 9.6e-5 rad, i.e. an output-side 16-bit encoder, so the figures do not lean on
  the gearbox.
- Joint velocity: the driver differentiates the encoder at its servo rate (here every physics step, 500 Hz)
  and low-pass filters it (first order, `velocity_cutoff_hz`); quantisation of the difference is what the
  filter smooths.
- Torque: τ = k_t · i · N from the measured motor current. The torque constant varies part to part (± 5 % is a
  typical tolerance for BLDC motors), so each joint gets a gain error drawn once (σ `torque_gain_error`), plus
  current-sense noise `torque_noise_nm` per sample.
- Joint zero offsets (`zero_offset_rad`, realistic profile only): a calibrated robot's encoders read each joint's
  angle with the residual error of its zero calibration (Unitree robots are zeroed by placing the legs in a
  calibration posture / fixture); σ 0.3° per joint is assumed (a fixture seats the calf to a few tenths of a
  degree; Unitree publishes no figure). Drawn once per run; the robot's software does not know it.
- Energy: the driver samples current and velocity at every physics step; the joint work Σ_i |τ_i · θ̇_i| dt is
  integrated there from the *measured* values (not once per control tick, which missed ≈ 17 % of the work).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass(frozen=True)
class JointSensorConfig:
    encoder_resolution_rad: float = 2 * math.pi / 2**16  # [rad] per count at the joint
    velocity_cutoff_hz: float = 100.0  # driver's low-pass on the differentiated encoder [Hz]
    torque_gain_error: float = 0.03  # σ of the per-joint torque-constant error (fraction)
    torque_noise_nm: float = 0.1  # σ of current-sense noise per sample [N·m]
    zero_offset_rad: float = 0.0  # σ of each joint's zero-calibration residual [rad] (realistic: 0.3°)


class JointSensors:
    """12 joints. `sample(q, tau, dt)` for a block of k physics steps ((k, 12) each) → (q, dq, tau) (k, 12)
    as the driver reports them, and the block's joint energy [J] from those measured values."""

    def __init__(self, config: JointSensorConfig, rng: np.random.Generator, q0: np.ndarray) -> None:
        self.config = c = config
        self.rng = rng
        self.gain = 1.0 + rng.normal(0.0, c.torque_gain_error, 12)
        self.zero_offset = rng.normal(0.0, c.zero_offset_rad, 12) if c.zero_offset_rad else np.zeros(12)
        self._q_prev = self.quantise(np.asarray(q0, dtype=float) + self.zero_offset)
        self._dq = np.zeros(12)

    def quantise(self, q: np.ndarray) -> np.ndarray:
        r = self.config.encoder_resolution_rad
        return np.floor(q / r + 0.5) * r

    def sample(
        self, q_true: np.ndarray, tau_true: np.ndarray, dt: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        args = self.block_args(q_true, tau_true, dt)
        energy = _joint_block(*args)
        return args[-3], args[-2], args[-1], energy

    def block_args(self, q_true: np.ndarray, tau_true: np.ndarray, dt: float) -> tuple:
        """`sample`'s draws, state and fresh (k, 12) outputs q, dq, tau (the last three), as `_joint_block`'s
        arguments (the suite's one compiled call a tick, `suite._sensor_tick`)."""
        c, k = self.config, len(q_true)
        alpha = 1.0 - math.exp(-2 * math.pi * c.velocity_cutoff_hz * dt)
        noise = self.rng.normal(0.0, c.torque_noise_nm, (k, 12))
        return (
            np.asarray(q_true, dtype=float),
            np.asarray(tau_true, dtype=float),
            self.zero_offset,
            c.encoder_resolution_rad,
            alpha,
            dt,
            self.gain,
            noise,
            self._q_prev,
            self._dq,
            np.empty((k, 12)),
            np.empty((k, 12)),
            np.empty((k, 12)),
        )


@njit(cache=True, nogil=True)
def _joint_block(
    q_true: np.ndarray,
    tau_true: np.ndarray,
    zero_offset: np.ndarray,
    resolution: float,
    alpha: float,
    dt: float,
    gain: np.ndarray,
    noise: np.ndarray,
    q_prev: np.ndarray,
    dq_filt: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    tau: np.ndarray,
) -> float:
    """`JointSensors.sample`'s arithmetic, compiled (every control tick): encoder angles `q`, the driver's
    filtered velocity `dq` and torque `tau` (k, 12) from the true block, `noise` (k, 12) the current-sense
    draws; the last angle `q_prev` and filter state `dq_filt` (12,) carry over in place. Returns the block's
    joint energy Σ|τ·q̇|dt [J] from the measured values."""
    energy = 0.0
    for s in range(q_true.shape[0]):
        for j in range(12):
            qm = np.floor((q_true[s, j] + zero_offset[j]) / resolution + 0.5) * resolution
            dq_filt[j] = dq_filt[j] + alpha * ((qm - q_prev[j]) / dt - dq_filt[j])
            q_prev[j] = qm
            q[s, j] = qm
            dq[s, j] = dq_filt[j]
            tau[s, j] = tau_true[s, j] * gain[j] + noise[s, j]
            energy += abs(tau[s, j] * dq[s, j])
    return energy * dt
