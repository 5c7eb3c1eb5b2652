"""Per-foot friction estimate from what the scout feels: the slip detector's events and the force ratios.

Each stance foot's ground force comes from its joint torques (f = −J⁻ᵀτ, `robot.statics.leg_forces_from_torques`:
an Aliengo has no 3-axis foot force sensors); split along the controller's foothold-plane normal n̂ it gives
the ratio ρ = |f_t| / f_n the ground is bearing. A foot that slips was asking for more than the ground holds:
while it slides the ground bears its kinetic friction, so the ratio filtered over the last ticks before the
slip event (`ratio_tau_s`) is an observation of μ. A stance that ends without a slip proves the ground held
at least the largest ratio it bore. So, per foot:

- slip event: the largest ρ_filtered of the stance so far is a candidate (the ratio at the event tick itself
  read 0.06 on a μ 0.14 patch: the foot creeps on at a lower ratio);
- the foot lost its hold: the slip detector's ΔP in this stance grew past `lost_dp_m` (well past the 2 cm of
  its slip event): μ̂ ← clip(candidate, `floor_mu`, μ̂) (never raised by a slip); where the candidate reached
  the stance QP's cone for that foot (`at_cone`), the foot slid at the QP's own ask and the candidate says
  nothing of the ground: μ̂ ← `lost_decay` · μ̂ too (else a foot the QP credits with the prior slides on at the
  prior, its "observations" confirming the cone). A stance whose slip stayed
  below that is *creep*: MuJoCo's soft contact (like loose regolith) lets a loaded foot creep a few cm at
  ratios well inside its cone, and on holdable patches those creeping slips read μ̂ 0.05–0.1 below the truth
  and made 7 of 10 holdable walks stop (docs/results.md). Creep leaves μ̂ as it was (no recovery either);
- stance ended without a slip: μ̂ ← max(μ̂ + `recover` · (prior − μ̂), what that stance proved it held —
  `proven` below, its ratios past the touchdown; `recover_proven` False: the largest filtered ρ, touchdown
  included), capped at the prior: the estimate recovers over a few clean stances once the ground grips again.

A floor from the ground's side: the trunk's accelerometer says what all the feet together bore. Its specific
force f (world) times the mass is the sum of the ground's forces on the feet (the legs' own accelerations
average out over a gait cycle), so the ratio ρ_G = |f̄_t| / f̄_n of its low-passed mean (`ground_tau_s`, about a
trot cycle) along the foothold plane's normal is the ratio the ground bore under the stance feet together: where
they all stand on one patch, its μ is at least ρ_G (standing, ρ_G ≈ tan θ; sliding, ρ_G ≈ μ). A lost hold never
takes a foot's μ̂ below `ground_share` · ρ_G. Without it `lost_decay` compounds: a foot whose cone the decay
lowered below what the slope asks slides at that cone again, stance after stance, and its μ̂ spirals to the floor
while the others' stay (lunar seed 6 east: a hind foot at μ̂ 0.02 for 15 s on μ 0.16 ground while ρ_G read
0.1–0.26; the stance QP then asked all the tangential force of its diagonal partner, which slid, and the trunk
rolled over them, docs/results.md "The ground's side").

`area_mu` is the smallest of the four: the feet stand within 0.5 m of each other, on the same patch of ground.

`proven` (4,) (read by `adaptation` only with its `qp_proven`, off by default) is what each foot has shown it holds where it stands now: the `proven_quantile` of the force
ratios its last stance bore, when that stance ended without a slip (the first `proven_skip` of its ticks left
out: the touchdown's impact reads any ratio); NaN after a stance that slipped, or before any. A foot whose own μ̂
is still at the prior has felt nothing, but where another foot lost its hold it may stand on the same ground:
the stance QP credits it with the area's estimate or what it proved, whichever is more (`adaptation`), not the
prior. (Lunar seed 4 west: the fore feet lost their hold on a μ 0.18 patch, the hind feet followed them onto
it credited with 0.6, the QP asked them for ratios 0.5–0.7, they slid 0.2–0.5 m a stance and the trunk rolled
over, docs/results.md.)
The estimate uses only the torques, encoders, contact flags, the slip detector and the controller's own
plane — the robot's side of `signals.ProprioSample`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from scout_agent.robot import kinematics as K
from scout_agent.robot.statics import leg_forces_from_torques

__all__ = ["FrictionEstimate", "FrictionEstimateConfig"]

_ZERO12 = np.zeros(12)
_STANCE_TICKS = 256  # force ratios kept per stance (a trot's stance is ≈ 43 ticks, the sway crawl's 360)


@dataclass(frozen=True)
class FrictionEstimateConfig:
    prior_mu: float = 0.6  # what the scout assumes before it felt anything (the stance QP's old constant)
    floor_mu: float = 0.02  # never believe less than this
    min_normal_n: float = 8.0  # force ratios only from feet bearing at least this much [N]
    ratio_tau_s: float = 0.03  # low-pass of the force ratio within a stance [s]
    recover: float = 0.15  # share of the way back to the prior after each clean stance
    lost_dp_m: float = 0.05  # a stance's slip ΔP beyond this: the foot lost its hold (below: creep) [m]
    # a foot that loses its hold while its largest ratio reached `at_cone` of the friction the stance QP gave it
    # slid at the QP's own ask: the torques then say what the leg pushed, not what the ground held (lunar seed
    # 4 west: a hind foot slid 0.4 m on μ 0.18 "bearing" 0.62–0.73, so μ̂ stayed at the prior 0.6 and the QP
    # went on asking 0.6 of it). Its μ̂ then falls to `lost_decay` of what it was, at each such lost hold
    # (1: off. On main 669f4d2, with the pilot's slide mode, 0.7 took the falls matrices from 7 to 3 of 30
    # (lunar) and 2 to 1 of 50 (ramps); before the slide mode it left the scout sliding on the short 20° ramp's
    # μ 0.26 patch instead of backing off, docs/results.md "What the feet can hold")
    at_cone: float = 0.9
    lost_decay: float = 0.7
    # the ground-side floor (None: off): a lost hold leaves μ̂ at least ground_share · ρ_G, ρ_G the ratio of the
    # accelerometer's specific force low-passed over ground_tau_s along the foothold plane's normal
    ground_share: float | None = 0.9
    ground_tau_s: float = 0.7
    # a clean stance raises μ̂ to at least what it proved it held (`proven`: its ratios past the touchdown) rather
    # than the largest ratio it bore (False: the largest, touchdown included — on lunar seed 6 east a hind foot's
    # μ̂ went 0.04 → 0.53 on μ 0.16 ground after one such stance, the QP then asked 0.45 of it and it slid 0.3 m)
    recover_proven: bool = True
    proven_quantile: float = 90.0  # percentile of a clean stance's force ratios a foot has proven it holds
    proven_skip: float = 0.2  # share of a stance's first ticks left out of it (the touchdown)


@njit(cache=True, nogil=True)
def _force_ratios(f: np.ndarray, fn: np.ndarray, normal: np.ndarray, min_normal_n: float) -> np.ndarray:
    """|f − f_n n̂| / f_n per foot from forces `f` (4, 3) and their normal parts `fn` (4,); NaN where f_n is
    below `min_normal_n` (compiled: numpy's norm, where and errstate cost ≈ 15 µs a tick)."""
    out = np.empty(4)
    for i in range(4):
        t0 = f[i, 0] - fn[i] * normal[0]
        t1 = f[i, 1] - fn[i] * normal[1]
        t2 = f[i, 2] - fn[i] * normal[2]
        out[i] = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2) / fn[i] if fn[i] >= min_normal_n else np.nan
    return out


@njit(cache=True, nogil=True)
def _low_pass_rotated(f: np.ndarray, R: np.ndarray, v: np.ndarray, a: float) -> None:
    """f ← f + a · (R v − f), in place (compiled: numpy's matmul and arithmetic cost ≈ 8 µs a tick)."""
    for j in range(3):
        f[j] += a * (R[j, 0] * v[0] + R[j, 1] * v[1] + R[j, 2] * v[2] - f[j])


class FrictionEstimate:
    """`update(sample, slip_events, stance_end, slipped, normal, dt)` once per tick; `mu` (4,) per foot."""

    def __init__(self, config: FrictionEstimateConfig = FrictionEstimateConfig()) -> None:
        self.config = config
        self.mu = np.full(4, config.prior_mu)
        self._ratio = np.full(4, np.nan)  # filtered force ratio of the current stance
        self._held = np.zeros(4)  # largest filtered ratio borne in the current stance
        self._candidate = np.full(4, np.nan)  # the held ratio at this stance's slip event
        self.proven = np.full(4, np.nan)  # ratio each foot held through its last clean stance (NaN: none)
        self._stance_rho = np.empty((4, _STANCE_TICKS))  # this stance's force ratios, each foot
        self._n_rho = [0, 0, 0, 0]
        self._force = np.zeros(3)  # low-passed specific force, world (∝ the ground's force on all feet)
        self.observations = 0  # stances that lost their hold and set an estimate
        self.creeps = 0  # stances whose slip stayed creep

    @property
    def area_mu(self) -> float:
        return float(self.mu.min())

    def ground_ratio(self, normal: np.ndarray) -> float:
        """ρ_G: |f̄_t| / f̄_n of the low-passed specific force along `normal` (0 before any reading or with no
        normal part): the friction ratio the ground bore under all stance feet together."""
        f = self._force
        fn = float(f[0] * normal[0] + f[1] * normal[1] + f[2] * normal[2])
        if fn <= 0.0:
            return 0.0
        t0, t1, t2 = f[0] - fn * normal[0], f[1] - fn * normal[1], f[2] - fn * normal[2]
        return math.sqrt(t0 * t0 + t1 * t1 + t2 * t2) / fn

    def feel_ground(self, imu_acc: np.ndarray, R: np.ndarray, dt: float) -> None:
        """Low-pass the accelerometer's specific force `imu_acc` (base frame), rotated into the world by `R`."""
        a = dt / (self.config.ground_tau_s + dt) if dt > 0 else 1.0
        _low_pass_rotated(self._force, R, np.asarray(imu_acc, dtype=float), a)

    def ratios(
        self,
        q: np.ndarray,
        tau: np.ndarray,
        R: np.ndarray,
        normal: np.ndarray,
        forces_w: np.ndarray | None = None,
    ) -> np.ndarray:
        """(4,) |f_t| / f_n of each foot's torque-estimated ground force (NaN below `min_normal_n`);
        `forces_w` (4, 3): those forces, world, when the estimators already computed them this tick."""
        f = leg_forces_from_torques(K.jacobians(q), tau, _ZERO12) @ R.T if forces_w is None else forces_w
        return _force_ratios(f, f @ normal, normal, self.config.min_normal_n)

    def update(
        self,
        q: np.ndarray,
        tau: np.ndarray,
        R: np.ndarray,
        contact: np.ndarray,
        normal: np.ndarray,
        slip_event: tuple[bool, ...],
        stance_end: tuple[bool, ...],
        slipped: tuple[bool, ...],
        dp: tuple[float, ...],
        dt: float,
        forces_w: np.ndarray | None = None,
        cone: np.ndarray | None = None,
        imu_acc: np.ndarray | None = None,
    ) -> bool:
        """One tick; `dp` (4,): the slip detector's ΔP per foot this tick [m] (NaN where not settled);
        `forces_w` as in `ratios` (feet out of `contact` may read anything there); `cone` (4,): the friction
        the stance QP gives each foot now (None: unknown); `imu_acc` (3,): the accelerometer's specific force, base
        frame (None: no ground-side floor). True when a foot lost its hold this tick."""
        c = self.config
        if imu_acc is not None and c.ground_share is not None:
            self.feel_ground(imu_acc, R, dt)
        rho = self.ratios(q, tau, R, normal, forces_w)
        a = dt / (c.ratio_tau_s + dt) if dt > 0 else 1.0
        lost = False
        for i in range(4):
            r = rho[i]
            if contact[i] and r == r:
                prev = self._ratio[i]
                self._ratio[i] = r if prev != prev else prev + a * (r - prev)
                self._held[i] = max(self._held[i], self._ratio[i])
                n = self._n_rho[i]
                self._stance_rho[i, n % _STANCE_TICKS] = r
                self._n_rho[i] = n + 1
            if slip_event[i] and self._held[i] > 0:
                # the largest ratio this stance bore before the event: where it started to slide (by the time
                # the detector declares the slip, 2 cm later, a creeping foot bears less)
                self._candidate[i] = self._held[i]
            cand = self._candidate[i]
            if cand == cand and dp[i] == dp[i] and dp[i] > c.lost_dp_m:
                mu = min(self.mu[i], float(cand))
                if cone is not None and c.lost_decay < 1.0 and cand >= c.at_cone * cone[i]:
                    # it slid bearing what the QP gave it: the ratio is the QP's own ask, not the ground's
                    mu = min(mu, c.lost_decay * self.mu[i])
                if imu_acc is not None and c.ground_share is not None:
                    # never below what the ground was seen to bear under all the feet together
                    mu = max(mu, min(float(self.mu[i]), c.ground_share * self.ground_ratio(normal)))
                self.mu[i] = max(c.floor_mu, mu)
                self.observations += 1
                self._candidate[i] = np.nan  # once per stance
                lost = True
            if stance_end[i]:
                if slipped[i] and self._candidate[i] == self._candidate[i]:
                    self.creeps += 1
                self.proven[i] = np.nan if slipped[i] else self._proven(i)
                if not slipped[i]:
                    up = self.mu[i] + c.recover * (c.prior_mu - self.mu[i])
                    held = float(self._held[i])
                    if c.recover_proven:
                        held = float(self.proven[i]) if self.proven[i] == self.proven[i] else 0.0
                    self.mu[i] = min(c.prior_mu, max(up, held))
                self._n_rho[i] = 0
                self._ratio[i] = np.nan
                self._held[i] = 0.0
                self._candidate[i] = np.nan
        return lost

    def _proven(self, i: int) -> float:
        """The ratio foot i held through the stance that just ended (NaN: too few ticks to say)."""
        c = self.config
        n = min(self._n_rho[i], _STANCE_TICKS)
        r = self._stance_rho[i, int(c.proven_skip * n) : n]
        return float(np.percentile(r, c.proven_quantile)) if len(r) >= 5 else np.nan
