"""`StateEstimator`: the scout's base state from its own sensors, every control tick.

Inputs, and where each comes from on a real Aliengo:
- the IMU's specific force and angular rate (tick means of the 500 Hz samples; the model: `scout_agent.sim.sensors.imu`),
- the joint encoders and driver velocities (`scout_agent.sim.sensors.joints`) through the leg kinematics
  (Pinocchio, the same model the simulator runs),
- the foot contact flags (`scout_agent.onboard.drivers`),
- the launch pose the scout is given in the shared map frame (launch.py: a lander's survey of x, y, heading
  with its σ, and a ground height from a DEM, the shared map, or declared 0 with a large σ; docs/design.md,
  "Frames and grid"): the filter starts with exactly that covariance; the height is anchored once, when two
  feet first stand settled on that ground, with the datum's σ (the robot is dropped from a few mm and its feet
  sink in, so anchoring at power-on left a 1 cm offset in every elevation it mapped).
Nothing here reads the simulator.

Filter (ekf.py): IMU propagation once per tick with the tick's mean rates; one 3-row base-velocity update per
stance foot (leg_odometry.py) whose contact flag has been on for `stance_settle_s` (touchdown impact and the
foot still sinking in excluded: in the first 0.1 s of stance its centre still moves down ≈ 5 cm/s), gated by a
χ² test so a slipping foot does not drag the estimate. The ground normal of the rolling term is the plane
through the four latest footholds (on a 20° ramp, taking it vertical biased the climb rate by ≈ 9 mm/s).

Tuning: the process noise is the IMU datasheet's (BMI088) densities ×3 (covers the tick averaging and model
error), bias walks ×10 the sensor model's (the filter must not be over-confident in its biases; the gyro's z offset ×3, so the standstills it averages are kept: ekf.py); the initial
gyro-bias σ is 5e-4 rad/s, ≈ 4.5× what the power-on calibration leaves (1.1e-4 rad/s, sensors/imu.py). It was
0.01 rad/s, and then a sliding foot, whose leg odometry disagrees with the gripping foot's across a 0.5 m lever
arm exactly like a turn the gyro does not see, moved the yaw-rate bias, which integrated into heading: 2–3°
at the goal of the lunar routes, 42° in 10 s of a 5 cm/s slide in the unit test; and the robot balancing on
that estimate fell on 3 of 4 walks over the 5° ramp's μ 0.15 patch (none since). Leg velocity noise 0.04 m/s per axis (encoder-velocity noise through a 0.5 m leg is ≈ 5 mm/s; the rest is touchdown
transients and foot rolling off the sphere model); gate at χ²₃ = 7.8 (p = 0.05), so a fast slip is dropped.

Observable: roll, pitch, velocity, gyro bias about horizontal axes. Not observable while walking, so drifting: yaw
(the gyro bias about gravity integrates into heading; standing still on four feet observes it, standstill.py,
and the localizer's heading reaches it through the covariance), position (integrated velocity
error), and the accelerometer's horizontal bias, which the filter cannot tell from a tilt while the robot walks
straight (a 1 mg bias is a 0.35° tilt error under lunar gravity). `psrmap evaluate` reports the drift.

The legs' climb: their kinematics' calibration residuals (joint zero offsets, link lengths) turn the odometry's
velocity about the base y axis, and the height climbs or sinks by a fraction of the distance that neither the IMU
nor a standstill observes; a hind foot stepping where a front foot stood does (climb_calibration.py), and the
odometry update turns the calibrated bias back (leg_odometry.odometry_rows).

Heading: a stance foot measures the base velocity in the base frame, Rᵀv, which is the same whatever the heading
(turn R and v together about gravity). The EKF's update, linearised at an estimate that moves between ticks (the
trot's wobble), nonetheless finds heading information there: its heading σ shrank and a slip on a slope, the feet
reporting a sideways velocity the base did not have, turned the heading by 12° within 1 s on a 100 m walk. The
odometry update is therefore a Schmidt (consider) update of heading (`odometry_holds_heading`; kernels.update): the
gain's row for the rotation about world z is zeroed, the Joseph form keeps the covariance true for that gain; only
the standstills (through the bias) and the localizer's pose updates move heading (cf. the observability-constrained
EKF, Hesch et al. 2014; Bloesch et al. 2013 for legged robots).

Timing: the leg odometry joins the gyro's ω with the encoders' angles and velocities at one instant. The
tick's IMU reading is the mean of its samples over the tick (the 5 samples of 10 ms, each latched a servo
step after it was sensed), so on average `gyro_age_s` (6 ms) older than the encoder angle, the tick's last
sample. In a trot the trunk pitches with the stance phase, and the odometry uses each foot in the same part of
its stance every step, so the stale rate does not average out: with ideal sensors ω × r ran ahead of the true
base velocity by 1.0 % along track, the whole of the 1.1 % the estimate ran ahead (10° ramp, exact start,
simulator truth; issue 23). The odometry takes the reading carried forward to the encoders' instant along its
change since the previous reading, ω̄ₖ + (ω̄ₖ − ω̄ₖ₋₁)·age/Δt (Δt the stamped interval); the propagation keeps
the mean, which is what integrates over the tick.

IMU lever arm: the IMU sits off the trunk origin (`imu_offset_m`, a CAD value; sensors/suite.py); the
accelerometer there reads ω̇ × r + ω × (ω × r) more than at the origin (≈ 0.2 m/s² in a trot's roll at 7 cm,
an eighth of lunar g), which the estimator subtracts, with ω̇ from the difference of consecutive fresh rates over
the time between them. (Until issue 23's legcal helper the simulated IMU never left the trunk origin, a MuJoCo
compile flag, sim/aliengo.py, and this subtraction was the only lever arm there was: after a 15° turn at the start
of a ramp walk the roll was 1.3° off and the height drifted 1 % of the distance.)
Lost packets (`SensorTick.fresh` False): the last reading is held for propagation, no leg update; a fresh reading
is integrated over its stamped interval less the time held. The held specific force at the base origin is the last
fresh tick's (lever arm included); the lever arm's ω̇ then spans both ticks. Before, the held tick recomputed ω̇
as 0 and the next fresh tick divided two ticks' change of rate by one: at a touchdown that subtracted 1.8 m/s² too
much for 10 ms, a 2 cm/s velocity error the filter then blamed on its tilt and accelerometer bias, moving the
height 5–7 cm in a second (a 10° ramp walk, noise seed 100, simulator truth). What the lost tick's own specific
force was is unknown: the velocity variance grows by (σ·dt)², σ = `lost_tick_acc_std_mps2` (the RMS change of
the tick's reading from one tick to the next in a trot), so the legs correct the velocity, not the tilt.

Consistency (issue 23: the covariance must contain the true error; `psrmap evaluate` reports NEES and 3σ
containment). Four error sources have no state in the 15-state filter; each widens the covariance by what it
can do, from what the robot knows:
- the IMU's bias drifts with temperature by a coefficient the robot does not know, but the thermometer tells it
  the temperature change ΔT since the bias was last measured (the gyro's: the last zero-rate update, else power-on;
  the accelerometer's: power-on): the bias variances grow by TCO² · d(ΔT²), TCO the datasheet's (BMI088
  0.015 °/s/K, 0.2 mg/K), so σ_b = TCO·|ΔT|, what the sensor model draws; the gyro's also by its g-sensitivity
  (0.1 °/s/g) times the change of gravity's direction in the IMU since the last zero-rate update;
- leg odometry's along-track error is a fraction of the distance (1–2 % in the literature, docs/physics.md; foot
  rolling, compliance, link lengths): the horizontal position variance grows along the velocity by
  2 k² d·|v| dt, so σ = k·d with k = `odometry_scale_std` (measured since the gyro timing, realistic sensors
  from the exact start: +0.3 % on the ramps, +0.3–1.2 % on the 20 m lunar routes' rougher ground; −0.01…+0.51 %
  on six 100 m walks, RMS 0.36 %): k = 0.5 % (a calibration of its mean, `odometry_calibration`, exists and is
  off: docs/results.md, "Honest odometry terms"); the legs' crab (their velocity turned 0.3–0.46° from the true motion, its sign
  the route's: not calibrated) grows the variance across the velocity the same way, k = `odometry_crab_std`
  (0.6 %). It was 1 % along and nothing across: three times the along-track error of the 100 m walks, none of
  their sideways 0.5–0.8 %;
- the gyro's scale and cross-axis error turn heading by a constant fraction of the net turn: the heading variance
  is raised to k²·max|ψ − ψ_ref|² with k = `gyro_scale_std` (1.4 %, BMI088 ±1 % each), the reference restarting
  when a measurement halved the heading variance (a pose fix); it is added about world z (`ErrorStateEKF.add_heading_variance`);
- a foot the χ² gate refused was slipping; its neighbours may slip too, under the gate: each refusal adds
  `slip_pos_std_m`² (5 mm) to the horizontal position variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from scout_agent.estimators.feet import PinocchioFeet
from scout_agent.onboard.drivers import SensorTick
from scout_agent.robot import constants as C

from . import kernels
from .bias_temperature import GyroTempco
from .climb_calibration import ClimbCalibration, ClimbCalibrationConfig
from .ekf import ErrorStateEKF, NoiseConfig
from .launch import LaunchPose
from .standstill import StandstillConfig, ZeroRateWindow
from .tick_kernel import estimate_arrays, matrix_to_quat, odometry_tick

_EZ = np.array([0.0, 0.0, 1.0])
_ALL4 = np.ones(4, bool)


@dataclass(frozen=True)
class EstimatorConfig:
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    leg_vel_std: float = 0.04  # [m/s] per axis per stance foot
    stance_settle_s: float = 0.1  # a contact counts for odometry after this long [s] (foot still sinking in)
    gate_chi2: float = 7.8  # χ²(3) at p = 0.05
    anchor_std_m: float = 0.003  # how well the feet stand on the surveyed launch ground height [m]
    # share of the planned stance whose leg odometry is used: the foot sinks into the ground while it loads
    # and rises while it unloads; using the loaded middle symmetrically keeps that from biasing the height
    odometry_stance: tuple[float, float] = (0.3, 0.8)
    gravity_mps2: float = C.LUNAR_G
    foot_radius_m: float = C.FOOT_RADIUS
    imu_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # IMU position on the trunk (CAD) [m]
    # what the filter knows of the IMU's temperature behaviour: the datasheet's TCO as a σ (sensors/imu.py)
    gyro_tempco_std: float = float(np.radians(0.015))  # [rad/s/K]
    # learn the gyro's temperature coefficient from the standstills' zero-rate windows (bias_temperature.py): the
    # bias nominal follows k̂·ΔT and its variance grows by σ_k̂² instead of the datasheet's TCO². False: as before
    gyro_tempco_learn: bool = True
    acc_tempco_std: float = 0.2e-3 * 9.80665  # [m/s²/K]
    gyro_scale_std: float = 0.014  # heading error per radian of net turn: scale ⊕ cross-axis (1 % each)
    gyro_g_sens_std: float = float(np.radians(0.1) / 9.80665)  # BMI088 0.1 °/s/g per element [rad/s per m/s²]
    # the legs' along-track excess (share of the distance) and crab angle [rad], calibrated the way a team
    # calibrates odometry before a mission: walks of a surveyed course against its truth (benchmarks/
    # dem_place_replay.py `split` on two 100 m-field routes no goal walk uses: seed 41 west −0.01 %, seed 43 east
    # +0.51 %; docs/results.md, "Honest odometry terms"); the odometry's horizontal velocity is scaled by
    # 1 − excess and turned by the crab (leg_odometry.odometry_rows). The crab is not calibrated: +0.30…+0.45° on
    # the direct and west routes, −0.46° on the east one (the ground's, not the robot's). Off by default, (0, 0):
    # at (0.25 %, 0) the four 100 m goal walks, one each on the same base, came out worse on six of eight (on and
    # off; the walks are chaotic: a 0.25 % change of the velocity changes the path, the pauses' creep and the
    # heading) while the recorded walks replayed with it gained 0.01–0.09 m
    odometry_calibration: tuple[float, float] = (0.0, 0.0)
    # the legs' along-track error per metre walked (the excess measured −0.01…+0.51 % on six 100 m walks, RMS
    # 0.36 %), and sideways (the crab, RMS 0.39° = 0.68 %) [m/m]. The along-track σ was 1 % (the literature's
    # 1–2 % class), two to seven times the error on the 100 m walks, and nothing stood for the crab
    odometry_scale_std: float = 0.005
    odometry_crab_std: float = 0.006
    # how much older the tick's IMU reading is than its encoder angles [s] ("Timing" in the module docstring):
    # the driver reports the mean of the tick's 5 IMU samples (10 ms), each latched one servo step (2 ms) after
    # it was sensed, against the encoders' last sample: (5 + 1) / 2 × 2 ms. 0: the gyro as read
    gyro_age_s: float = 0.006
    # leg odometry's height error, a random walk in the distance walked [m/√m]: σ_z² grows by k² per metre.
    # On the 100 m missions the height drifts ~1 cm per metre walked between DEM height fixes 25 m apart, so
    # k = 0.06 (σ 0.3 m after 25 m); with the filter's z untouched by walking its height fixes moved it by
    # 2–5 cm where its error was 0.3–1 m (docs/results.md, "The map's heights at mission scale")
    odometry_height_std: float = 0.06
    slip_pos_std_m: float = 0.005  # horizontal position σ added per foot update the gate rejected [m]
    # a lost packet's held IMU reading is off by the tick's change of specific force: its RMS in a trot, per base
    # axis, is 0.11 / 0.05 / 0.35 m/s² (10° ramp, realistic sensors); the velocity variance grows by (σ·dt)² per
    # lost tick ("Lost packets" in the module docstring)
    lost_tick_acc_std_mps2: float = 0.35
    # the legs' climb bias, calibrated where a hind foot steps on a front foot's foothold (climb_calibration.py)
    climb: ClimbCalibrationConfig = field(default_factory=ClimbCalibrationConfig)
    # leg odometry measures the base-frame velocity, which says nothing of heading; its updates leave heading
    # alone (a Schmidt update; "Heading" in the module docstring). False: the plain EKF update
    odometry_holds_heading: bool = True
    standstill: StandstillConfig = field(default_factory=StandstillConfig)  # standstill.py


class Inflation(NamedTuple):
    """The running quantities of `StateEstimator._inflate` (kernels.inflate takes and returns them in order)."""

    temp0: float  # IMU temperature at the first reading (the power-on calibration's) [°C]
    gyro_temp0: float  # IMU temperature at the last ZARU (the gyro bias's reference) [°C]
    dtemp_prev: float  # the accelerometer's ΔT at the last tick [K]
    gyro_dtemp_prev: float  # the gyro's ΔT at the last tick [K]
    temp_prev: float  # the last tick's IMU temperature [°C]
    du2_peak: float  # the largest |Δu|² of gravity's direction since the last ZARU [(m/s²)²]
    bias_heading_rad: float  # ∫σ_bz dt since the last ZARU: heading σ the gyro bias may have added
    walked_m: float  # horizontal distance by the estimate [m]
    turn_net_rad: float  # net heading turned by the estimate since the scale term's reference [rad]
    turn_peak_rad: float  # the largest |turn_net_rad| since then [rad]
    heading_var_prev: float  # heading variance after the last tick's inflation [rad²]


class StateEstimate(NamedTuple):
    t: float
    pos: np.ndarray  # (3,) base origin, world [m]
    R: np.ndarray  # (3, 3) world_R_base
    quat: np.ndarray  # (4,) wxyz of R
    vel: np.ndarray  # (3,) world [m/s]
    omega: np.ndarray  # (3,) bias-corrected angular velocity, base frame [rad/s]


class StateEstimator:
    def __init__(
        self,
        launch: LaunchPose,
        q0: np.ndarray,
        config: EstimatorConfig = EstimatorConfig(),
        feet: PinocchioFeet | None = None,
    ) -> None:
        self.config = c = config
        self.feet = feet or PinocchioFeet()
        c_, s_ = np.cos(launch.yaw), np.sin(launch.yaw)
        R0 = np.array([[c_, -s_, 0.0], [s_, c_, 0.0], [0.0, 0.0, 1.0]])
        fb, _ = self.feet.feet_base_and_vel(q0, np.zeros(12))
        # feet on the surveyed ground: the lowest foot sphere's bottom at ground_z
        z0 = launch.ground_z + c.foot_radius_m - float(np.min((fb @ R0.T)[:, 2]))
        self.ekf = ErrorStateEKF(
            R0,
            np.zeros(3),
            np.array([launch.x, launch.y, z0]),
            np.array([0.0, 0.0, -c.gravity_mps2]),
            c.noise,
        )
        # the start's stated uncertainty (launch.py): survey σ on x, y, heading; the height's σ is the datum's
        P = self.ekf.P
        P[6, 6] = P[7, 7] = c.noise.init_pos**2 + launch.sigma_xy_m**2
        P[2, 2] = c.noise.init_yaw**2 + launch.sigma_yaw_rad**2
        P[8, 8] = c.noise.init_pos**2 + launch.sigma_z_m**2
        self._r_imu = np.asarray(c.imu_offset_m, dtype=float)
        self._lever = bool(np.any(self._r_imu))
        self._w_prev = np.zeros(3)
        self._f_base = np.zeros(3)  # the tick's specific force at the base origin [m/s²] (filled in place)
        self._gyro_fresh: np.ndarray | None = None  # the last fresh gyro reading [rad/s] (timing, docstring)
        self._stamp_prev = 0.0
        self._held_s = 0.0  # time propagated on lost packets since the last fresh reading [s]
        self.tempco = GyroTempco(c.gyro_tempco_std)  # the gyro's temperature coefficient, learnt standing
        self._tempco_k = np.zeros(3)  # its estimate [rad/s/K] and σ, per axis (the datasheet's before a fit)
        self._tempco_sd = np.full(3, c.gyro_tempco_std)
        self._u_first: np.ndarray | None = None  # gravity in the base frame at the first ZARU [m/s²]
        self._u_zaru: np.ndarray | None = None  # gravity in the base frame at the last ZARU [m/s²]
        self._stand_since: float | None = None  # standing on four settled feet since [s]
        self._zaru: ZeroRateWindow | None = None  # the standstill's open window (standstill.py)
        self.zaru_updates = 0  # zero-rate updates fused
        self.zaru_refused = 0  # windows refused (feet moved against each other, or the χ² gate)
        self.standstill_s = 0.0  # time stood with standstill updates [s]
        self.standstills = (
            0  # standstills begun (each is one draw of the stance's creep: bias_temperature.py)
        )
        self._inflation = Inflation(
            temp0=math.nan,
            gyro_temp0=math.nan,
            dtemp_prev=0.0,
            gyro_dtemp_prev=0.0,
            temp_prev=math.nan,
            du2_peak=0.0,
            bias_heading_rad=0.0,
            walked_m=0.0,
            turn_net_rad=0.0,
            turn_peak_rad=0.0,
            heading_var_prev=math.inf,
        )
        # the squared σ's `_inflate` adds with (kernels.inflate's `coef`)
        self._inflate_coef = np.array(
            [
                c.gyro_g_sens_std**2,
                c.acc_tempco_std**2,
                c.odometry_scale_std**2,
                c.odometry_height_std**2,
                c.gyro_scale_std**2,
                c.slip_pos_std_m**2,
                c.odometry_crab_std**2,
            ]
        )
        self._contact_since = np.full(4, np.inf)
        self._settled = np.zeros(4, bool)
        self._use = np.zeros(4, bool)
        self._leg_var = np.full(12, c.leg_vel_std**2)  # one variance per velocity row (4 feet × 3)
        self._footholds = fb @ R0.T + self.ekf.p  # (4, 3) each foot's latest stance position, world [m]
        self._was_contact = np.zeros(4, bool)
        self._normal_w = _EZ.copy()  # ground normal under the feet, world (plane through the footholds)
        self.t = 0.0
        self.rejected = 0  # stance-foot updates refused by the gate (slips, impacts)
        self.launch = launch
        self.anchored = False  # the height has been anchored to the launch ground once all feet stood on it
        self.climb = ClimbCalibration(c.climb)  # the legs' climb bias from revisited footholds
        self.estimate = self._estimate(np.zeros(3))

    @property
    def specific_force_base(self) -> np.ndarray:
        """The last tick's specific force at the base origin (the IMU's less its lever arm), base frame [m/s²];
        a view the next tick overwrites."""
        return self._f_base

    def _specific_force(self, tick: SensorTick, dt: float) -> np.ndarray:
        """The specific force at the base origin: the IMU's, less its lever arm (ω̇ × r + ω × (ω × r))."""
        if not self._lever:
            return tick.imu_acc
        return kernels.imu_to_base(tick.imu_acc, tick.imu_gyro, self.ekf.bg, self._w_prev, self._r_imu, dt)

    def _gyro_at_encoders(self, gyro: np.ndarray, since_s: float) -> np.ndarray:
        """The angular rate at the encoders' instant (module docstring, "Timing"): the tick's mean reading
        carried forward by `gyro_age_s` along its change since the last fresh reading, `since_s` ago [s]."""
        prev, self._gyro_fresh = self._gyro_fresh, gyro.copy()
        age = self.config.gyro_age_s
        if prev is None or age <= 0.0 or since_s <= 0.0:
            return gyro
        return gyro + (gyro - prev) * (age / since_s)

    def _inflate(self, tick: SensorTick, dt: float, n_rejected: int) -> None:
        """Process noise the 15-state model has no state for (module docstring, "Consistency"); the arithmetic
        compiled in `kernels.inflate`, whose lines say, in order:
        - bias change with temperature: TCO² × d(ΔT²), ΔT since the bias was last measured (the accelerometer's
          since power-on: no standstill separates its bias; the gyro's since the last zero-rate update); the
          gyro's offset follows the learnt coefficient, what is left of it is the fit's σ (the datasheet's TCO
          until the standstills have measured it: bias_temperature.py);
        - g-sensitivity: the gyro's offset moves with the specific force's direction in the IMU (tilt on a
          slope), by G·Δu since the last zero-rate update, u = Rᵀ(−g): the bias variance is raised to
          gs² × max|Δu|² (the largest shift so far bounds it). Adding gs² × |d|Δu|²| every tick instead summed
          the trot's roll and pitch wobble, up and down, into a variance growing without bound (1e-9 (rad/s)²/s
          on a 100 m walk, ten times the bias walk's), which spent the standstills' heading budget;
        - the bias variances: the temperature terms (when the thermometer reads), then the g-sensitivity's;
        - along-track odometry scale: σ = k·distance (d σ² = 2 k² d·|v| dt); the height's error grows from the
          launch ground's anchor on;
        - heading from the gyro's scale/cross-axis error: a constant factor s of the net turn, s·(ψ − ψ_ref), so
          the heading variance is raised to k²·max|ψ − ψ_ref|² (k = `gyro_scale_std`; the largest net turn so
          far bounds it whatever the turns' order). Counting every turn's magnitude (k × the angle turned) made
          the σ grow without bound as a robot turned back and forth at hazard stops (16° after 660 s, error 3°).
          The reference restarts when a measurement at least halved the heading variance (a pose fix: what it
          left is mostly the fix's own error, and from there on the scale's is s times the turn since); not on
          the small reductions of a standstill's bias correction, which would split one growing error into
          segments whose variances add to less than its own. Added about world z (u = Rᵀe_z), not base z: on a
          slope the base-z variance was also tilt, fully correlated with heading, and the gravity update then
          turned the heading by cot(slope) × its tilt residual (3.8° in 0.4 s at a hazard stop on a 12° slope
          of a 100 m walk; ekf.add_heading_variance);
        - the gate refused a foot: the others may be sliding too, undetected (slip σ² per refusal)."""
        e = self.ekf
        if self._u_zaru is None:
            self._u_zaru = e.R.T @ -e.g
        vx, vy, _ = e.v.tolist()
        self._inflation = Inflation._make(
            kernels.inflate(
                e.R,
                e.g,
                e.bg,
                e.P,
                tick.imu_gyro,
                self._u_zaru,
                self._tempco_k,
                self._tempco_sd,
                self._inflate_coef,
                float(tick.imu_temp_c),
                math.hypot(vx, vy),
                vx,
                vy,
                dt,
                n_rejected,
                self.anchored,
                tuple(self._inflation),  # a plain tuple: numba types a NamedTuple argument 1.5 µs slower
            )
        )

    @property
    def bias_heading_rad(self) -> float:
        """∫σ_bz dt since the last zero-rate update: the heading σ the gyro bias may have added [rad]."""
        return self._inflation.bias_heading_rad

    @property
    def gyro_tempco_sd_z(self) -> float:
        """σ of the gyro z offset's temperature coefficient as learnt so far (the datasheet's before) [rad/s/K]."""
        return float(self._tempco_sd[2])

    @property
    def imu_temp_c(self) -> float:
        """The IMU thermometer's last reading [°C] (NaN before one)."""
        return self._inflation.temp_prev

    @property
    def walked_m(self) -> float:
        """Horizontal distance walked by the estimate [m]."""
        return self._inflation.walked_m

    @property
    def turn_net_rad(self) -> float:
        """Net heading turned by the estimate since the gyro scale term's reference [rad]."""
        return self._inflation.turn_net_rad

    def position_covariance(self) -> np.ndarray:
        """(3, 3) covariance of the base position, world frame [m²]."""
        return self.ekf.P[6:9, 6:9].copy()

    def heading_variance(self) -> float:
        """Variance of the heading (rotation about world z) [rad²]: the rotation error's covariance, kept in the
        base frame, turned into the world frame."""
        return self.ekf.heading_variance()

    def _estimate(self, omega: np.ndarray) -> StateEstimate:
        e = self.ekf
        return StateEstimate(self.t, e.p.copy(), e.R.copy(), matrix_to_quat(e.R), e.v.copy(), omega)

    def _finish(self, tick: SensorTick, any_contact: bool) -> StateEstimate:
        """The tick's footholds (a new one refits the ground plane) and its `StateEstimate`, in one compiled
        call (tick_kernel.estimate_arrays; `_estimate`'s arithmetic)."""
        e = self.ekf
        arrays = estimate_arrays(
            (tick.contact, self._was_contact, self.feet.buffers()[0], self._footholds, self._normal_w),
            (e.R, e.p, e.v, e.bg, tick.imu_gyro),
            any_contact,
        )
        self._was_contact = tick.contact
        self.estimate = StateEstimate(self.t, *arrays)
        return self.estimate

    def _odometry_tick(
        self, t: float, tick: SensorTick, dt: float, mid_stance: np.ndarray | None, stand: bool
    ) -> tuple[float, float, int, int, int]:
        """`tick_kernel.odometry_tick` on this estimator's arrays: (dt, stamp_prev, feet in contact, settled,
        refused by the gate)."""
        c, e = self.config, self.ekf
        has_prev = self._gyro_fresh is not None
        gyro_fresh = (
            np.zeros(3) if self._gyro_fresh is None else self._gyro_fresh
        )  # (written on a fresh tick)
        if tick.fresh:
            self._gyro_fresh = gyro_fresh
        return odometry_tick(
            (e.R, e.v, e.p, e.bg, e.ba, e.P, e.g, e.process_noise),
            (
                tick.imu_acc,
                tick.imu_gyro,
                np.ascontiguousarray(tick.q, dtype=float),
                np.ascontiguousarray(tick.dq, dtype=float),
                tick.contact,
            ),
            self.feet.buffers(),
            (
                self._contact_since,
                self._settled,
                self._use,
                _ALL4 if mid_stance is None or stand else mid_stance,
            ),
            (self._r_imu, self._w_prev, gyro_fresh, self._f_base),
            self._normal_w,
            self._leg_var,
            (
                t,
                dt,
                tick.stamp_s,
                self._stamp_prev,
                self._held_s,
                c.gyro_age_s,
                c.stance_settle_s,
                c.foot_radius_m,
                c.gate_chi2,
                c.lost_tick_acc_std_mps2,
                self.climb.bias,
                c.odometry_calibration[0],
                c.odometry_calibration[1],
            ),
            (bool(tick.fresh), self._lever, has_prev, stand, c.odometry_holds_heading),
        )

    def update(
        self,
        t: float,
        tick: SensorTick,
        dt: float,
        mid_stance: np.ndarray | None = None,
        standing: bool = False,
    ) -> StateEstimate:
        """One tick. `mid_stance` (4,) bool, optional: the gait schedule puts the leg in the middle of its stance
        (the robot's own controller knows its schedule); odometry then uses only those feet. `standing`: the
        controller holds the robot still on four feet (its gait frozen); with every foot settled the tick
        brings the standstill's updates (standstill.py)."""
        c, e = self.config, self.ekf
        self.t = t
        # the controller froze its gait with every foot down (a contact flag may still flicker on a lightly
        # loaded foot; the zero-rate window checks that the feet kept their places): every settled foot
        # planted, each one's odometry is a zero-velocity update
        stand = standing and c.standstill.enabled
        if not tick.fresh:  # a lost packet: hold the last reading, no measurement
            # (tick_kernel.odometry_tick: `_specific_force` and the propagation, compiled)
            self._odometry_tick(t, tick, dt, mid_stance, stand)
            self._held_s += dt
            if self._zaru is not None:
                self._zaru.add(tick.imu_gyro, dt)
            self._inflate(tick, dt, 0)
            return self._finish(tick, False)
        # compiled (tick_kernel.odometry_tick, the same operations in the same order): the stamped interval
        # (less what was held), the gyro at the encoders' instant (`_gyro_at_encoders`), the specific force at
        # the base origin (`_specific_force`), the IMU propagation, the settled feet, the feet's kinematics,
        # and the leg-odometry update of the settled feet in mid-stance (χ²-gated, heading held)
        dt, self._stamp_prev, n_contact, n_settled, n_rejected = self._odometry_tick(
            t, tick, dt, mid_stance, stand
        )
        f_base = self._f_base
        self._held_s = 0.0
        settled = self._settled
        any_contact = n_contact > 0
        fb = self.feet.buffers()[0]
        self.rejected += n_rejected
        # the feet in use this tick (their kinematics are fresh): their footholds calibrate the legs' climb
        self.climb.stance_tick(self._use, fb, e.R, e.p, self._normal_w)
        self._inflate(tick, dt, n_rejected)
        if not self.anchored and n_settled >= 2:
            # settled feet stand on the launch ground: the one height the mission knows (its survey)
            feet_z = float(np.mean((fb[settled] @ e.R.T)[:, 2]))
            z_meas = self.launch.ground_z + c.foot_radius_m - feet_z
            # the start height and this measurement share the datum's error (both are ground_z plus a leg height,
            # launch.py): the update corrects what the power-on guess added (the drop onto the ground, the feet
            # sinking in) and the height keeps the datum's σ. Taken as independent, as before, the update met the
            # prior halfway and left half the 1 cm drop, 5 mm low, in every height the scout mapped
            datum_var = self.launch.sigma_z_m**2
            e.P[8, 8] -= datum_var
            e.update(np.array([z_meas - e.p[2]]), e.position_z_rows(), np.array([c.anchor_std_m**2]))
            e.P[8, 8] += datum_var
            self.anchored = True
        self._standstill(t, stand, tick, f_base, fb if any_contact or stand else None, dt)
        return self._finish(
            tick, any_contact
        )  # footholds (a new one: the ground plane refitted), the estimate

    def _standstill(
        self, t: float, stand: bool, tick: SensorTick, f_base: np.ndarray, fb: np.ndarray | None, dt: float
    ) -> None:
        """Gravity and zero-rate updates while the robot stands on four settled feet (standstill.py)."""
        if not stand or fb is None:
            self._stand_since = None
            self._zaru = None
            return
        ss, e = self.config.standstill, self.ekf
        if self._stand_since is None:
            self._stand_since = t
            self.standstills += 1
        if t - self._stand_since < ss.settle_s:
            return
        self.standstill_s += dt
        if ss.level_std_mps2 > 0:  # gravity: roll, pitch and the accelerometer bias (heading held)
            e.gravity_update(f_base, ss.level_std_mps2, ss.gate_chi2)
        if self._zaru is None:
            self._zaru = ZeroRateWindow(t, fb)
            return
        self._zaru.add(tick.imu_gyro, dt)
        if self._zaru.span_s < ss.window_s - 1e-9:
            return
        win, span = self._zaru, self._zaru.span_s
        z = win.close(fb, ss.feet_rms_max_m, ss.turn_max_rad)
        self._zaru = ZeroRateWindow(t, fb)
        if z is None:
            self.zaru_refused += 1
            return
        H = np.zeros((3, 15))
        H[:, 9:12] = np.eye(3)
        var = ss.zaru_var(span, win.turned_rad)
        keep = e.update(
            z - e.bg, H, np.full(3, var), hold_heading=ss.zaru_holds_heading
        )  # no χ² gate: a bias
        if not keep[
            0
        ]:  # larger than believed (the feet check above refuses a slip; a gate would lock it out)
            self.zaru_refused += 1
            return
        self.zaru_updates += 1
        self._inflation = self._inflation._replace(bias_heading_rad=0.0)
        temp = tick.imu_temp_c
        u = e.R.T @ -e.g
        if temp == temp:  # the bias's temperature drift restarts from here
            self._inflation = self._inflation._replace(gyro_temp0=temp, gyro_dtemp_prev=0.0)
            if (
                self.config.gyro_tempco_learn
            ):  # and the window joins the temperature fit, its variance widened by
                if self._u_first is None:  # what the g-sensitivity may have moved since the first window
                    self._u_first = u
                gs2 = self.config.gyro_g_sens_std**2 * float(np.sum((u - self._u_first) ** 2))
                # the creep and the g-sensitivity: one draw per standstill, its windows' random intercept
                own = ss.zaru_var(span, win.turned_rad, creep=False)
                self.tempco.add(temp, z, np.full(3, own), self.standstills, ss.creep_std_rad_s**2 + gs2)
                self._tempco_k, self._tempco_sd = self.tempco.slope()
        self._u_zaru = u  # and its g-sensitivity from this attitude
        self._inflation = self._inflation._replace(du2_peak=0.0)
