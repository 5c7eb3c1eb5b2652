"""How well an orbital DEM can give a scout its height, offline (evaluation only: it reads the simulator's truth).

`record` walks one scout of a field mission's default routes alone (the DEM its only reference) and saves, per
settled stance, the foothold as the estimate placed it and the true contact point, the distance walked, the
filter's horizontal σ, and every height correction the localizer fused. `replay` takes the corrections back
out (leg odometry's own height error along the walk: the estimate's error less the fixes) and runs the DEM
height fixes again against the saved footholds, every 25 m from 30 m and at the end, as the localizer does:

- `track`: the height from the last 100 m alone (`match_height`, a line in the distance walked with a 2 cm/m
  prior), its variance × the footholds it shares with the previous fix, fused into a filter whose height σ grows
  0.06 m/√m, held samples corrected by the smoother's gain (the build before `height_track.py`);
- `walk`: the whole walk's datum and drift with each DEM pixel's error counted once (`HeightTrack`), the held
  footholds set to its datum along the walk (`PoseFix.height_profile`);
- `hindsight`: the whole walk's datum at its end applied to every foothold (what no hold can beat).

For each it prints the footholds' height error against the truth (RMS, mean) after the samples `--hold` m
behind a fix were corrected, and each fix's normalised error² (its σ's honesty). Only the vertical: the
footholds' horizontal misplacement is what `benchmarks/map_heights.py` calls "horizontal".

    python benchmarks/height_replay.py record --field 100 --seed 33 --scout 0 --out /tmp/rec0.npz
    python benchmarks/height_replay.py replay /tmp/rec0.npz --hold 30
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from psrmap.mission.components import scout_sensor_seed
from psrmap.mission.config import MissionConfig, field_scouts
from scout_agent.holding import PoseFix
from scout_agent.localization import MatchConfig
from scout_agent.localization.height_track import HeightTrack
from scout_agent.localization.matcher import match_height
from scout_agent.robot import constants as C
from scout_agent.run import ScoutRunConfig, build_world, dem_reference, run_scout

SETTLE_S = 0.15  # a stance's foothold once its contact has lasted this long (LocalizerConfig.settle_s)


def _run_config(field_m: float, seed: int, index: int) -> ScoutRunConfig:
    plan = field_scouts(field_m)[index]
    return ScoutRunConfig(
        scene="lunar", seed=seed, sensor_seed=scout_sensor_seed(seed, index), field_m=field_m,
        start=tuple(plan.start), goal=tuple(plan.goal), via=tuple(tuple(v) for v in plan.via),  # type: ignore[arg-type]
        speed=MissionConfig().speed, scout_id=plan.id,
    )  # fmt: skip


def record(field_m: float, seed: int, index: int, out: Path) -> None:
    cfg = _run_config(field_m, seed, index)
    feet: list[tuple[float, ...]] = []  # walked, t, est x y z, true z, σ_xy, true x y
    fixes: list[tuple[float, float]] = []  # t, height correction
    ticks: list[tuple[float, ...]] = []  # t, walked, est z, true z
    since, taken = np.full(4, np.inf), np.zeros(4, bool)
    state = {"walked": 0.0, "prev": None}

    def on_tick(sample, truth, robot):
        e = robot.estimator.ekf
        x, y = float(e.p[0]), float(e.p[1])
        if state["prev"] is not None:
            state["walked"] += float(np.hypot(x - state["prev"][0], y - state["prev"][1]))
        state["prev"] = (x, y)
        contact = np.asarray(sample.contact, bool)
        since[:] = np.where(contact, np.minimum(since, sample.t), np.inf)
        taken[:] &= contact
        due = contact & ~taken & (sample.t - since >= SETTLE_S) & np.isfinite(truth.contact_point_world[:, 2])
        if due.any():
            fb, _ = robot.estimator.feet.feet_base_and_vel(sample.q, sample.dq)
            pts = fb[due] @ e.R.T + e.p
            sig = float(np.sqrt(max(np.linalg.eigvalsh(e.P[6:8, 6:8]).max(), 0.0)))
            for p, tp in zip(pts, truth.contact_point_world[due], strict=True):
                feet.append(
                    (state["walked"], sample.t, p[0], p[1], p[2] - C.FOOT_RADIUS, tp[2], sig, tp[0], tp[1])
                )
            taken[:] |= due
        if len(ticks) == 0 or sample.t - ticks[-1][0] >= 0.05:
            ticks.append((sample.t, state["walked"], float(e.p[2]), float(truth.base.pos[2])))

    def on_fix(fix: PoseFix) -> None:
        fixes.append((ticks[-1][0] if ticks else 0.0, float(fix.correction[2])))

    summary = run_scout(cfg, on_tick=on_tick, on_fix=on_fix)
    np.savez(out, feet=np.array(feet), fixes=np.array(fixes).reshape(-1, 2), ticks=np.array(ticks),
             field_m=field_m, seed=seed, index=index)  # fmt: skip
    print(f"{cfg.scout_id}: {summary['distance_m']} m, fell {summary['fell']}, {len(feet)} footholds, "
          f"{len(fixes)} fixes -> {out}")  # fmt: skip


def replay(path: Path, hold_m: float) -> None:
    d = np.load(path)
    cfg = _run_config(float(d["field_m"]), int(d["seed"]), int(d["index"]))
    dem = dem_reference(cfg, build_world(cfg))
    assert dem is not None
    F, fx = d["feet"], d["fixes"]
    applied = lambda t: float(fx[fx[:, 0] < t, 1].sum()) if len(fx) else 0.0  # noqa: E731
    raw = F[:, 4] - np.array([applied(t) for t in F[:, 1]])  # each foothold without the fixes' corrections
    err_raw = raw - F[:, 5]
    A = np.c_[np.ones(len(F)), F[:, 0]]
    coef, *_ = np.linalg.lstsq(A, err_raw, rcond=None)
    print(f"leg odometry's height error: {coef[0]:+.3f} m at launch, {100 * coef[1]:+.2f} cm/m, "
          f"{np.std(err_raw - A @ coef):.3f} m RMS about that line ({F[-1, 0]:.0f} m walked)")  # fmt: skip
    end = float(F[-1, 0])
    at = [*np.arange(30.0, end, 25.0), end]
    for method in ("track", "walk"):
        final, z2, var = _replay(method, F, raw, at, dem, hold_m)
        e = final - F[:, 5]
        print(f"{method:9s} hold {hold_m:4.0f} m: footholds' height error {np.sqrt(np.mean(e**2)):.3f} m RMS, mean "
              f"{e.mean():+.3f}; fixes' normalised error² {np.mean(z2):.2f} ({len(z2)} fixes)")  # fmt: skip
        ok = np.isfinite(var)
        if ok.any():  # the footholds' vertical σ as published (`PoseFix.height_profile_var`)
            print(f"{'':9s} stated σ: median {np.sqrt(np.median(var[ok])):.3f} m (5–95 % "
                  f"{np.sqrt(np.percentile(var[ok], 5)):.3f}–{np.sqrt(np.percentile(var[ok], 95)):.3f}); "
                  f"footholds' normalised error² {np.mean(e[ok] ** 2 / var[ok]):.2f}")  # fmt: skip
    ht = HeightTrack()
    for k in range(len(F)):
        ht.add(np.array([[F[k, 2], F[k, 3], raw[k]]]), F[k, 0], F[k, 6])
    prof = ht.profile(dem.dem, dem.subpixel_m, end, F[:, 0])
    assert prof is not None
    e = raw + prof - F[:, 5]
    print(
        f"hindsight           : footholds' height error {np.sqrt(np.mean(e**2)):.3f} m RMS, mean {e.mean():+.3f}"
    )


def _replay(method, F, raw, at, dem, hold_m):
    """Footholds' heights after the fixes at distances `at` and the held samples' corrections; the fixes'
    normalised errors²; `walk`: each foothold's vertical variance as published (the last whole-walk fix's
    posterior at its distance walked, + the DEM's bias; NaN for `track`)."""
    ht = HeightTrack()
    C_ = 0.0  # the corrections so far
    P, last = 0.3**2, 0.0  # `track`: the filter's height variance, the last fix's distance
    final = raw.copy()
    var_out = np.full(len(F), np.nan)
    z2, hist = [], []
    k = 0
    for s_fix in at:
        while k < len(F) and F[k, 0] <= s_fix:
            final[k] = raw[k] + C_
            ht.add(np.array([[F[k, 2], F[k, 3], raw[k] + C_]]), F[k, 0], F[k, 6])
            k += 1
        err_now = final[k - 1] - F[k - 1, 5]
        if method == "walk":
            fix = ht.fix(dem.dem, dem.subpixel_m, s_fix)
            if fix is None:
                continue
            held = F[:k, 0] > s_fix - hold_m
            final[:k][held] = raw[:k][held] + C_ + ht.last_profile(F[:k, 0][held] - s_fix)
            assert ht.last_profile_var is not None
            var_out[:k][held] = ht.last_profile_var(F[:k, 0][held] - s_fix) + 0.03**2
            corr, var = fix.dz, fix.var_m2 + 0.03**2
            ht.shift(np.zeros(3), np.array([0.0, 0.0, corr]), 0.0)
        else:
            m = F[:k, 0] >= s_fix - 100.0
            pts = np.c_[F[:k, 2:4][m], raw[:k][m] + C_]
            fix = match_height(
                pts, dem, float(F[k - 1, 6]), MatchConfig(step_m=0.5, max_points=200), F[:k, 0][m], 0.02
            )
            if fix is None:
                continue
            P += 0.06**2 * (s_fix - last)
            v = (fix.var_m2 + 0.03**2) * max(1.0, min(100.0, s_fix) / 25.0)
            gain = P / (P + v)
            corr = gain * fix.dz
            P *= 1.0 - gain
            var = P
            held = (F[:k, 0] > s_fix - hold_m) & (F[:k, 0] > last)
            g = np.clip((F[:k, 0][held] - last) / max(s_fix - last, 1e-9), 0.0, 1.0)
            final[:k][held] += g * corr
        z2.append((err_now + corr) ** 2 / var)
        hist.append(s_fix)
        C_ += corr
        last = s_fix
    final[k:] = raw[k:] + C_
    return final, np.array(z2), var_out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="walk one scout of the field mission, the DEM its only reference")
    r.add_argument("--field", type=float, default=100.0)
    r.add_argument("--seed", type=int, default=33)
    r.add_argument("--scout", type=int, default=0, help="index of the mission's default scout (0, 1, 2)")
    r.add_argument("--out", type=Path, required=True)
    q = sub.add_parser("replay", help="the DEM height fixes again, against the truth")
    q.add_argument("recording", type=Path)
    q.add_argument("--hold", type=float, default=30.0, help="held samples this far behind a fix [m] (30)")
    a = p.parse_args(argv)
    if a.cmd == "record":
        record(a.field, a.seed, a.scout, a.out)
    else:
        replay(a.recording, a.hold)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
