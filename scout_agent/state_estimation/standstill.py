"""Standstills: what a legged robot learns about its gyro while it stands on four feet, and when to stand.

A gyro's zero-rate offset drifts with the board's temperature (BMI088: 0.015 °/s/K, sensors/imu.py), and
nothing a walking robot feels separates that bias about the vertical from a turn: heading drifts by the bias's
integral. Standing still, the bias is what the gyro reads. Three measurements while the robot stands on four
settled feet (`StateEstimator.update(..., standing=True)`, the controller's gait frozen with every foot down):

- **zero angular rate (ZARU)**, 3 axes, once per `window_s`: the gyro's mean over the window less the trunk's
  rotation over it from the leg kinematics (the four feet's positions in the base frame at the window's two
  ends, aligned by `scipy.spatial.transform.Rotation.align_vectors`, Kabsch: feet that stay put turn in the
  base frame exactly as the trunk turns over them). The kinematic term matters: the balance controller holds
  the *estimated* heading, so with a wrong bias the trunk really turns on its planted legs at the bias error and
  the gyro alone would confirm the wrong bias. The Moon's rotation, 2.66e-6 rad/s (sidereal month 27.32 d), is
  2 % of the 1.1e-4 rad/s the 5 s power-on calibration leaves and below what a window resolves: neglected.
  Noise per window: the gyro's white noise over the window (datasheet density × `gyro_density_margin`) and
  the kinematic rotation's (`kin_std_rad` at each end, encoder quantisation through a 0.4 m stance);
  refused when the feet moved against each other (`feet_rms_max_m`: a foot slipped) or the trunk rocked
  (`turn_max_rad`), its kinematic term weighted by how far the trunk turned (legs' compliance: `kin_turn_frac`),
  never by a χ² gate (a unit whose bias is larger than the filter believes would be locked out for good);
  **the stance creeping as a whole**: MuJoCo's soft contacts (like loose regolith) let loaded feet creep, and
  the stance then turns in the world with the trunk on it, which no leg kinematics sees and the gyro reads as
  bias (each foot slides down its own facet of the ground under its vertical load; the ground holds no net torque
  and no standing force distribution cancels the slides: docs/results.md, "Why a standing robot's feet creep").
  Measured against the simulator's truth (100 m field, seed 31, realistic sensors): steady over a pause,
  0.0–4.6e-4 rad/s from one pause to the next (1.6e-4 rms per pause once the windows' white noise is taken
  out), level ground or not (0.84° and 0.43° slopes read 3e-4 and 4e-4 off), the same whatever the filter's
  bias error (an injected ±3e-4 rad/s changed nothing). It is one draw per standstill shared by its windows
  (`creep_std_rad_s`, counted `creep_windows` times in each window), so averaging a pause's windows does not
  average it away; only more pauses do;
- **zero velocity**: the leg odometry of all four feet (not only mid-stance ones);
- **gravity** (roll and pitch): the accelerometer reads −g in the base frame plus its bias.

After a ZARU the bias's temperature term restarts from the temperature it was measured at (estimator.py).

`StandstillConfig` also sets when the robot stands: `start_s` at power-on before it walks, and a pause of
`pause_s` whenever the heading σ the gyro-bias uncertainty has added since the last standstill,
∫σ_bz dt (a fully correlated bias error: the bound), passes `heading_budget_deg`. Both cost mission time;
`psrmap evaluate` reports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["StandstillConfig", "StandstillPlanner", "ZeroRateWindow", "start_standstill_s"]

MOON_ROTATION_RAD_S = 2.0 * math.pi / (27.321661 * 86400.0)  # sidereal: 2.66e-6 rad/s (neglected, above)


def start_standstill_s(
    gyro_density: float = math.radians(0.014),
    gyro_tempco: float = math.radians(0.015),
    warmup_k: float = 8.0,
    warmup_tau_s: float = 600.0,
) -> float:
    """How long to stand at power-on [s]: averaging the gyro for T leaves a bias error density/√T while the
    warm-up moves the bias by tempco·(warmup_k/τ)·T; past the T where the two are equal, standing longer
    buys nothing until the board has warmed (several τ: tens of minutes). T = (density·τ/(tempco·warmup_k))^(2/3):
    17 s for the BMI088 (0.014 °/s/√Hz, 0.015 °/s/K) on a board warming 8 K with τ 10 min (sensors/imu.py's
    assumed profile; a robot's maker measures its own board's)."""
    return float((gyro_density * warmup_tau_s / (gyro_tempco * warmup_k)) ** (2.0 / 3.0))


@dataclass(frozen=True)
class StandstillConfig:
    enabled: bool = True  # False: never stand on purpose, no standstill updates (the build before)
    start_s: float = 20.0  # stand at power-on: this much of fused windows [s] (start_standstill_s() = 17 s)
    # and on, up to `start_max_s` [s] from the stop command, while the offset's drift the temperature
    # coefficient's σ leaves, σ_k̂z·|dT/dt| (the thermometer's rate over the standstill), exceeds
    # `start_drift_max` [rad/s per s]. The power-on ground is the launch site's level pad, and a creep is one
    # steady draw per standstill, so the warming board's windows measure k there (bias_temperature.py): on the
    # 100 m walk of seed 33 (k_z 3.8e-4 rad/s/K, 1.5σ) the offset ran 3.4–4.8e-4 rad/s ahead of the estimate
    # over the first 190 s, pauses and all, and the heading 2.3° off by 35 m (docs/results.md, "heading5").
    # 1e-6: under 6e-5 rad/s of unexplained drift per minute walked, a third of a pause's creep. 0: as before
    start_drift_max: float = 1e-6
    start_max_s: float = 150.0
    pause_s: float = 6.0  # each pause: this much of fused zero-rate windows [s]
    # pause when ∫σ_bz dt since the last standstill passes this [deg]: 0.3, not 0.5, because each pause's
    # creep (above) is a new error of the bias, and more pauses average it (docs/results.md, "Heading at 100 m")
    heading_budget_deg: float = 0.3
    settle_s: float = 1.0  # after the gait froze, before the first window (the trunk still rocks) [s]
    window_s: float = 3.0  # one ZARU per window [s] (longer windows: less of the kinematic error per second)
    gyro_density_margin: float = 1.0  # × the datasheet's white-noise density
    gyro_density: float = math.radians(0.014)  # BMI088 [rad/s/√Hz]
    kin_std_rad: float = 3e-4  # σ of the kinematic rotation at each window end, per axis [rad] (the feet's
    # fit residual after a walk is ≈ 0.4 mm over a 0.4 m stance: encoders, compliance, the ball feet rolling)
    feet_rms_max_m: float = 0.003  # the feet moved against each other more than this: a slip, refuse [m]
    # the stance turning as a whole, feet creeping (module docstring): σ of one standstill's draw [rad/s]
    creep_std_rad_s: float = 1.6e-4
    creep_windows: int = 2  # the creep is one draw per standstill: each window counts it this many times
    # (a pause's windows: pause_s / window_s), so their average keeps its whole variance
    turn_max_rad: float = 1e-2  # the trunk turned more than this over a window: not still, refuse [rad]
    kin_turn_frac: float = 0.15  # the kinematic turn's error as a share of the turn (measured 0.1–0.15 of
    # 6–9e-3 rad twists: leg compliance, feet rolling and creeping)
    gate_chi2: float = 16.3  # the gravity update's χ²(3) gate at p = 0.001 (the trunk accelerating)
    level_std_mps2: float = 0.05  # gravity update's σ per axis: tick noise 0.017 m/s² + the trunk's sway
    # True: the zero-rate update corrects the offset, not the heading (a Schmidt update of heading). Through the
    # filter's heading-offset correlation each window's innovation, mostly the pause's creep, turns into a heading
    # correction as if it were offset the walk had integrated (seed 35 at 100 m: -2.14° of a -3.32° error).
    # Replayed on two recorded walks it helped (3.26 -> 1.23°, 1.24 -> 1.16°), walked again it did not (seed 35
    # 3.32 -> 3.22°, seed 33 4.18° and a fall -> 5.75° and a give-up): off (docs/results.md, "Why a standing
    # robot's feet creep")
    zaru_holds_heading: bool = False
    min_walk_s: float = 10.0  # at least this long between two pauses [s]
    timeout_s: float = 10.0  # give a pause up this long past its length (windows refused: rocking, slips) [s]

    def zaru_var(self, window_s: float, turned_rad: float = 0.0, creep: bool = True) -> float:
        """Variance of one window's bias measurement, per axis [(rad/s)²], the trunk having turned by
        `turned_rad` over it; the creep counted `creep_windows` times (one draw shared by the standstill's
        windows). `creep` False: the window's own variance alone (white noise, kinematics), for a fit that
        models the creep as one draw per standstill (bias_temperature.py)."""
        g = self.gyro_density * self.gyro_density_margin
        kin = 2.0 * self.kin_std_rad**2 + (self.kin_turn_frac * turned_rad) ** 2
        own = g * g / window_s + kin / window_s**2
        return own + max(self.creep_windows, 1) * self.creep_std_rad_s**2 if creep else own


class ZeroRateWindow:
    """One window of a standstill: the gyro's integral and the feet at its start; `close` gives the bias
    measurement (3,) [rad/s], or None when the feet moved against each other."""

    def __init__(self, t: float, feet_b: np.ndarray) -> None:
        self.t0 = t
        self.feet0 = np.array(feet_b, dtype=float)
        self.gyro_int = np.zeros(3)  # ∫ω_m dt [rad]
        self.span_s = 0.0
        self.turned_rad = 0.0  # how far the trunk turned over its feet in the window (set by `close`) [rad]

    def add(self, gyro: np.ndarray, dt: float) -> None:
        self.gyro_int += gyro * dt
        self.span_s += dt

    def close(self, feet_b: np.ndarray, feet_rms_max_m: float, turn_max_rad: float) -> np.ndarray | None:
        a = np.asarray(feet_b, dtype=float)
        a = a - a.mean(axis=0)
        b = self.feet0 - self.feet0.mean(axis=0)
        rot, rssd = Rotation.align_vectors(a, b)  # feet now = Q · feet then (base frame)
        if rssd / 2.0 > feet_rms_max_m:  # rssd = √Σ|·|², four feet: rms = rssd / 2
            return None
        # the trunk turned by Qᵀ over the window (in its frame at the window's start)
        turned = rot.inv().as_rotvec()
        self.turned_rad = float(np.linalg.norm(turned))
        if self.turned_rad > turn_max_rad:  # rocking: the gyro's 1 % scale and cross-axis
            return None  # errors and the legs' compliance then exceed the bias (0.5° twists, 4e-4 rad/s off)
        return (self.gyro_int - turned) / self.span_s


class StandstillState(Protocol):
    """What the planner reads of the state estimator (estimator.StateEstimator)."""

    standstill_s: float
    zaru_updates: int

    @property
    def bias_heading_rad(self) -> float: ...

    @property
    def gyro_tempco_sd_z(self) -> float: ...

    @property
    def imu_temp_c(self) -> float: ...


class StandstillPlanner:
    """When the robot stands: `hold(t)` True while the pilot should keep it standing (the start-up standstill,
    then a pause whenever the bias's heading budget is spent); `summary()` their count and time cost."""

    def __init__(self, estimator: StandstillState, config: StandstillConfig) -> None:
        self.est = estimator
        self.config = config
        self.stands: list[dict] = []
        self._open: tuple[str, float, float, int, float] | None = None  # reason, t0, stood0, zaru0, need
        self._started = False
        self._t_end = -math.inf
        self._temp0: tuple[float, float] | None = None  # (t, °C) where the power-on standstill began

    def hold(self, t: float) -> bool:
        c, e = self.config, self.est
        if not c.enabled:
            return False
        if self._open is None:
            if not self._started:
                self._started = True
                if c.start_s <= 0:
                    return False
                self._open = ("start", t, e.standstill_s, e.zaru_updates, c.start_s)
            elif (
                c.pause_s > 0
                and t - self._t_end >= c.min_walk_s
                and math.degrees(e.bias_heading_rad) > c.heading_budget_deg
            ):
                self._open = ("heading", t, e.standstill_s, e.zaru_updates, c.pause_s)
            else:
                return False
        reason, t0, stood0, zaru0, need = self._open
        if reason == "start" and (self._temp0 is None or self._temp0[1] != self._temp0[1]):
            self._temp0 = (t, e.imu_temp_c)  # the thermometer's first reading (none before the first tick)
        stood = e.standstill_s - stood0
        fused_s = (e.zaru_updates - zaru0) * c.window_s  # windows the estimator fused
        if fused_s < need - 1e-9 and t - t0 < need + c.timeout_s:
            return True
        if (
            reason == "start"
            and c.start_drift_max > 0
            and t - t0 < c.start_max_s
            and self.start_drift(t) > c.start_drift_max
        ):
            return True
        self.stands.append(
            {
                "t": round(t0, 2),
                "s": round(t - t0, 2),
                "stood_s": round(stood, 2),
                "zaru": e.zaru_updates - zaru0,
                "reason": reason,
            }
        )
        self._open = None
        self._t_end = t
        return False

    @property
    def start_extension_s(self) -> float:
        """The most the power-on standstill may stand beyond `start_s` [s] (a walk's time limit allows it)."""
        c = self.config
        return max(c.start_max_s - c.start_s, 0.0) if c.enabled and c.start_drift_max > 0 else 0.0

    def start_drift(self, t: float) -> float:
        """σ_k̂z·|dT/dt| [rad/s per s]: how fast the offset may move unexplained while the board warms at the
        thermometer's rate since the power-on standstill began (the temperature coefficient's σ left); 0 when
        the thermometer reads nothing or no time has passed."""
        if self._temp0 is None:
            return 0.0
        t0, temp0 = self._temp0
        temp = self.est.imu_temp_c
        if not (t > t0 and temp == temp and temp0 == temp0):
            return 0.0
        return float(self.est.gyro_tempco_sd_z * abs(temp - temp0) / (t - t0))

    def summary(self) -> dict:
        """The standstills' count and mission time cost [s] (from the stop command to walking on)."""
        start = [s["s"] for s in self.stands if s["reason"] == "start"]
        pauses = [s["s"] for s in self.stands if s["reason"] != "start"]
        return {
            "start_s": round(sum(start), 2),
            "pauses": len(pauses),
            "pause_s": round(sum(pauses), 2),
            "total_s": round(sum(start) + sum(pauses), 2),
            "zaru_updates": int(sum(s["zaru"] for s in self.stands)),
        }
