"""How well an orbital DEM can place a scout and give it its heading, offline (evaluation only: it reads the
simulator's truth, which only scores).

`record` walks `psrmap evaluate`'s own loop (realistic sensors, surveyed start) with localization off and saves,
per settled stance, the foothold as the estimate placed it, the distance walked and the true contact point, and
every 0.2 s the estimate's pose and covariance beside the true pose. `replay` runs the DEM place and heading
fixes again on that dead-reckoned walk, every 25 m from 30 m as the localizer does, over `--draws` DEM noise
draws (draw 0 is the walk's own DEM): the corrected estimate is the dead reckoning moved by the fixes fused so
far (a rigid turn and shift, as a heading and position correction moves what odometry integrates after it),
its (x, y, heading) covariance propagated from the last fix by the recorded filter's own growth since then, each
fix fused as a Kalman update, χ²-gated at p = 0.001. Prints per draw the largest position and heading error over
the walk and the share of 0.2 s samples inside the 3σ ellipse; `--fixes none` is dead reckoning alone, `--fixes
window` the build before `trail.py` (the likelihood's moments over a window sized by the filter's σ, the last
100 m of track, covariance × the footholds shared).

`--verbose` prints each fix against the truth (the estimate's true error, the fix's posterior and σ, the information
λ it adds per direction, the correction); `--prior-scale` multiplies the recorded filter's covariance (what a tighter
filter would make of the same fixes). `bound` is what the DEM can say at all about the recorded route: the σ of a
rigid shift of the true footholds against the noise-free DEM's gradient (Fisher information), the whole route and
each 25 m piece.

    python benchmarks/dem_place_replay.py record /tmp/s33.npz --seed 33
    python benchmarks/dem_place_replay.py replay /tmp/s33.npz --draws 6 [--fixes trail|window|none] [--verbose]
    python benchmarks/dem_place_replay.py bound /tmp/s33.npz
    python benchmarks/dem_place_replay.py split /tmp/s33.npz [--along-k 0.004] [--odo-scale 0.003]

`split` says where a dead-reckoned walk's position error comes from: the error along and across the route beside
the filter's σ there, and the same error with every step of the estimate turned by the true heading error
(what the walk would have been with a perfect heading: the rest is the legs' along-track scale and sideways
slip). `--along-k K` (replay and split) re-derives the recorded filter's covariance with K instead of its
odometry scale term (`EstimatorConfig.odometry_scale_std`, recorded at `--recorded-k`): the term adds
2 k²·d·|v|dt along the velocity and nothing else depends on it without a fix, so it is rebuilt from the
recorded estimate's steps and replaced. `--odo-scale S` shortens every dead-reckoned step by the share S (an
along-track calibration of the leg odometry).
"""

from __future__ import annotations

import argparse
import collections
import json
from dataclasses import replace

import numpy as np

from scout_agent import evaluate as evaluate_module
from scout_agent.localization import DemReference, LocalizerConfig, match_track, match_trail
from scout_agent.localization.localizer import _due_feet, search_config
from scout_agent.localization.trail import bin_trail
from scout_agent.robot import constants as C
from scout_agent.run import ScoutRunConfig
from scout_agent.sim.dem import OrbitalDemConfig, orbital_dem
from scout_agent.sim.terrain import LunarConfig, make_lunar
from scout_agent.state_estimation.consistency import yaw_of_quat
from scout_agent.state_estimation.pose_update import heading

POSE_EVERY_S = 0.2
XY_YAW = [6, 7, 2]  # the error state's x, y and base-z rotation (heading on level ground)


def record(
    out: str, seed: int, field_m: float, sim_seconds: float | None = None, route: str = "direct"
) -> dict:
    cfg = ScoutRunConfig(scene="lunar", seed=seed, field_m=field_m, route=route, localize="off",
                         sim_seconds=sim_seconds)  # fmt: skip
    feet, poses = [], []
    st = {"since": np.full(4, np.inf), "taken": np.zeros(4, bool), "due": np.zeros(4, bool), "walked": 0.0,
          "prev": None, "next": 0.0}  # fmt: skip
    real_run = evaluate_module.run_scout

    def run(cfg_, on_tick=None, **kw):
        def tick(sample, truth, robot):
            e, t, due = robot.estimator.ekf, sample.t, st["due"]
            if _due_feet(np.asarray(sample.contact, bool), st["since"], st["taken"], t, 0.15, due):
                fb, _ = robot.estimator.feet.feet_base_and_vel(sample.q, sample.dq)
                pts = fb[due] @ e.R.T + e.p
                pts[:, 2] -= C.FOOT_RADIUS
                for p, q in zip(pts, truth.contact_point_world[due], strict=True):
                    feet.append([t, st["walked"], *p, *q])
                st["taken"] |= due
            if st["prev"] is not None:
                st["walked"] += float(np.hypot(e.p[0] - st["prev"][0], e.p[1] - st["prev"][1]))
            st["prev"] = (float(e.p[0]), float(e.p[1]))
            if t >= st["next"]:
                st["next"] += POSE_EVERY_S
                P = e.P[np.ix_(XY_YAW, XY_YAW)]
                poses.append([t, st["walked"], *e.p[:2], heading(e.R), *truth.base.pos[:2],
                              yaw_of_quat(truth.base.quat), *P.ravel()])  # fmt: skip
            return on_tick(sample, truth, robot) if on_tick is not None else None

        return real_run(cfg_, on_tick=tick, **kw)

    evaluate_module.run_scout = run
    try:
        res = evaluate_module.evaluate_run(cfg)
    finally:
        evaluate_module.run_scout = real_run
    np.savez_compressed(out, feet=np.array(feet), poses=np.array(poses), seed=seed, field_m=field_m)
    keys = (
        "fell",
        "reached_goal",
        "distance_m",
        "pos_error_max_m",
        "yaw_error_max_deg",
        "inside_3sigma_frac",
    )
    return {k: res.get(k) for k in keys}


def _turn(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _carry(d: np.ndarray) -> np.ndarray:
    """How an (x, y, heading) error moves over a displacement d: a heading error turns it."""
    F = np.eye(3)
    F[0, 2], F[1, 2] = -d[1], d[0]
    return F


def _psd(M: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh((M + M.T) / 2)
    return V @ np.diag(np.maximum(w, 0.0)) @ V.T


def _fix_line(w: float, truth: np.ndarray, fix, P: np.ndarray, corr: np.ndarray | None) -> str:
    """One accepted or refused fix against the truth: the estimate's true (x, y, heading) error (truth minus
    estimate), the fix's posterior mean and σ, the prior's σ, the information the DEM added per direction of
    the prior's whitened space (λ: the DEM cut the variance along it by 1 + λ), the posterior's normalised
    error² against the truth (3 dof), and the correction fused."""
    head = f"w {w:6.1f} m  true {truth[0]:+.2f} {truth[1]:+.2f} m {np.degrees(truth[2]):+.2f}°"
    if not fix.ok:
        return f"{head}  {fix.reason} (gain {fix.gain_nats:.2f} nats)"
    Lp = np.linalg.cholesky(P)
    lam = np.linalg.eigvalsh(Lp.T @ np.linalg.inv(fix.cov) @ Lp)
    sp = np.sqrt(np.diag(fix.posterior_cov))
    pe = fix.posterior - truth
    nees = float(pe @ np.linalg.solve(fix.posterior_cov, pe))
    sc = np.sqrt(np.diag(P))
    c = "gated" if corr is None else f"{corr[0]:+.2f} {corr[1]:+.2f} m {np.degrees(corr[2]):+.2f}°"
    return (f"{head}  posterior {fix.posterior[0]:+.2f} {fix.posterior[1]:+.2f} m {np.degrees(fix.posterior[2]):+.2f}° "
            f"σ {sp[0]:.2f} {sp[1]:.2f} m {np.degrees(sp[2]):.2f}° (prior σ {sc[0]:.2f} {sc[1]:.2f} m "
            f"{np.degrees(sc[2]):.2f}°)  λ {' '.join(f'{x:.2f}' for x in lam)}  nees {nees:.1f}  correction {c}")  # fmt: skip


def _along_term(est_xy: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(n, 3, 3) the odometry scale term's contribution to the (x, y, heading) covariance at each sample, for
    k = 1: Σ 2·d·Δd·u uᵀ over the samples so far (Δd the distance the estimate walked between two samples, u
    the direction it moved; the filter adds it every tick along the velocity, whose sway this leaves out)."""
    dp = np.diff(est_xy, axis=0)
    n = np.maximum(np.hypot(*dp.T), 1e-12)
    u = dp / n[:, None]
    q = 2.0 * w[:-1] * np.diff(w)
    Q = np.zeros((len(w), 3, 3))
    Q[1:, :2, :2] = np.cumsum(q[:, None, None] * u[:, :, None] * u[:, None, :], axis=0)
    return Q


def _adjusted(poses: np.ndarray, along_k: float | None, odo_scale: float, recorded_k: float, crab_deg: float = 0.0
              ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The recorded estimate's (x, y) and (x, y, heading) covariance, its steps shortened by `odo_scale` and
    turned by `crab_deg`, and its odometry scale term re-derived with `along_k` instead of `recorded_k` (None: as
    recorded)."""
    est_xy, w, P = poses[:, 2:4].copy(), poses[:, 1], poses[:, 8:].reshape(-1, 3, 3).copy()
    if odo_scale or crab_deg:
        steps = np.diff(est_xy, axis=0) @ ((1.0 - odo_scale) * _turn(np.radians(crab_deg))).T
        est_xy = est_xy[0] + np.vstack([np.zeros((1, 2)), np.cumsum(steps, 0)])
    if along_k is not None:
        P += (along_k**2 - recorded_k**2) * _along_term(poses[:, 2:4], w)
        P = np.array([_psd(M) for M in P])
    return est_xy, P


def split(path: str, along_k: float | None = None, odo_scale: float = 0.0, recorded_k: float = 0.01,
          crab_deg: float = 0.0) -> dict:  # fmt: skip
    """Where the dead-reckoned walk's error comes from (module doc, `split`): along and across the route (the
    line from its start to its end) with the filter's σ, the same with a perfect heading, the NEES."""
    d = np.load(path)
    poses = d["poses"]
    t, w, yaw, true_xy, true_yaw = poses[:, 0], poses[:, 1], poses[:, 4], poses[:, 5:7], poses[:, 7]
    est_xy, P = _adjusted(poses, along_k, odo_scale, recorded_k, crab_deg)
    dyaw = (true_yaw - yaw + np.pi) % (2 * np.pi) - np.pi
    steps = np.diff(est_xy, axis=0)
    c, s = np.cos(dyaw[:-1]), np.sin(dyaw[:-1])
    turned = np.column_stack([c * steps[:, 0] - s * steps[:, 1], s * steps[:, 0] + c * steps[:, 1]])
    e = est_xy - true_xy
    e_head = est_xy[0] + np.vstack([np.zeros((1, 2)), np.cumsum(turned, 0)]) - true_xy  # perfect heading
    u = true_xy[-1] - true_xy[0]
    u /= np.linalg.norm(u)
    n = np.array([-u[1], u[0]])
    sig = lambda v: np.sqrt(np.einsum("i,nij,j->n", v, P[:, :2, :2], v))  # noqa: E731
    nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(P[:, :2, :2]), e)
    rows = []
    for q in np.linspace(0, len(t) - 1, 8).astype(int)[1:]:
        rows.append({"walked_m": round(float(w[q]), 1), "along_m": round(float(e[q] @ u), 2),
                     "along_sigma_m": round(float(sig(u)[q]), 2), "across_m": round(float(e[q] @ n), 2),
                     "across_sigma_m": round(float(sig(n)[q]), 2), "perfect_heading_along_m": round(float(e_head[q] @ u), 2),
                     "perfect_heading_across_m": round(float(e_head[q] @ n), 2),
                     "yaw_deg": round(float(np.degrees(dyaw[q])), 2), "yaw_sigma_deg": round(float(np.degrees(np.sqrt(P[q, 2, 2]))), 2),
                     "nees": round(float(nees[q]), 2)})  # fmt: skip
    far = np.argmax(np.abs(e @ u))
    # the legs' along-track excess and crab angle that best explain the perfect-heading walk: the truth's way
    # from its start ≈ a·C + b·J·C with C the perfect-heading steps summed (J a quarter turn), a + ib =
    # (1 − excess)·e^{i·crab}: what `EstimatorConfig.odometry_calibration` takes off the legs' velocity
    C = np.vstack([np.zeros((1, 2)), np.cumsum(turned, 0)])
    A = np.column_stack([C.ravel(), (C @ np.array([[0.0, 1.0], [-1.0, 0.0]])).ravel()])
    (a, b), *_ = np.linalg.lstsq(A, (true_xy - true_xy[0]).ravel(), rcond=None)
    return {"rows": rows, "odometry_excess_pct": round(float(100 * (1 - np.hypot(a, b))), 3),
            "odometry_crab_deg": round(float(np.degrees(np.arctan2(b, a))), 3), "pos_error_max_m": round(float(np.hypot(*e.T).max()), 2),
            "perfect_heading_error_max_m": round(float(np.hypot(*e_head.T).max()), 2),
            "along_max_m": round(float((e @ u)[far]), 2), "along_pct_of_walk": round(float(100 * (e @ u)[-1] / w[-1]), 3),
            "nees_pos_mean": round(float(nees.mean()), 3), "inside_3sigma_frac": round(float(np.mean(nees <= 11.83)), 3),
            "nees_along_mean": round(float(np.mean((e @ u) ** 2 / sig(u) ** 2)), 3),
            "nees_yaw_mean": round(float(np.mean(dyaw**2 / P[:, 2, 2])), 3)}  # fmt: skip


def replay(path: str, draws: int, fixes: str, every_m: float = 25.0, first_m: float = 30.0,
           prior_scale: float = 1.0, verbose: bool = False, along_k: float | None = None,
           odo_scale: float = 0.0, recorded_k: float = 0.01, crab_deg: float = 0.0) -> list[dict]:  # fmt: skip
    d = np.load(path)
    feet, poses, seed = d["feet"], d["poses"], int(d["seed"])
    terrain = make_lunar(LunarConfig(seed=seed, size_m=float(d["field_m"])))
    t, w, est_yaw = poses[:, 0], poses[:, 1], poses[:, 4]
    est_xy, P_dr = _adjusted(poses, along_k, odo_scale, recorded_k, crab_deg)
    true_xy, true_yaw, P_dr = poses[:, 5:7], poses[:, 7], P_dr * prior_scale
    tf, wf, foot_xy, foot_z = feet[:, 0], feet[:, 1], feet[:, 2:4], feet[:, 4]
    lc = LocalizerConfig()
    rows = []
    for draw in range(draws):
        dem = orbital_dem(terrain, replace(OrbitalDemConfig(), seed=seed if draw == 0 else 9000 + draw))
        ref = DemReference(dem)
        R, shift, dyaw = np.eye(2), np.zeros(2), 0.0  # corrected = R · dead reckoning + shift
        k, P_k, next_fix, new_from = 0, P_dr[0].copy(), first_m, 0.0
        err, yaw_err, inside, reasons = [], [], [], collections.Counter()
        for i in range(len(t)):
            est = R @ est_xy[i] + shift
            D = _carry(est - (R @ est_xy[k] + shift))
            Ddr = _carry(est_xy[i] - est_xy[k])
            P = D @ P_k @ D.T + _psd(P_dr[i] - Ddr @ P_dr[k] @ Ddr.T)
            e = est - true_xy[i]
            ey = (est_yaw[i] + dyaw - true_yaw[i] + np.pi) % (2 * np.pi) - np.pi
            err.append(float(np.hypot(*e)))
            yaw_err.append(abs(float(np.degrees(ey))))
            inside.append(float(e @ np.linalg.solve(P[:2, :2], e)) <= 11.83)
            if fixes == "none" or w[i] < next_fix:
                continue
            next_fix = w[i] + every_m
            if fixes == "trail":
                length = max(lc.dem_trail_m, w[i] - new_from)
                sel = (tf <= t[i]) & (wf >= w[i] - length)
                pts = np.column_stack([foot_xy[sel] @ R.T + shift, foot_z[sel]])
                fix = match_trail(pts, wf[sel], ref, P, est, new_from, lc.dem_trail)
                reasons[fix.reason] += 1
                if not fix.ok:
                    if verbose:
                        print(f"  draw {draw} " + _fix_line(w[i], np.r_[-e, -ey], fix, P, None))
                    continue
                assert fix.offset is not None and fix.cov is not None
                z, Rm = fix.offset, fix.cov
            else:
                src = lc.dem
                sel = (tf <= t[i]) & (wf >= w[i] - src.track_m)
                pts = np.column_stack([foot_xy[sel] @ R.T + shift, foot_z[sel]])
                sxy = float(np.sqrt(np.linalg.eigvalsh(P[:2, :2]).max()))
                mc = search_config(lc, src, sxy, float(np.degrees(np.sqrt(P[2, 2]))))
                res = match_track(pts, ref, mc, pivot=est)
                reasons[res.reason] += 1
                if not res.ok:
                    continue
                assert res.cov is not None
                z = np.r_[res.dx, res.dy, res.dyaw]
                Rm = res.cov[np.ix_([0, 1, 3], [0, 1, 3])] * max(1.0, min(src.track_m, w[i]) / src.every_m)
            S = P + Rm
            if float(z @ np.linalg.solve(S, z)) > 16.27:
                reasons["gate"] += 1
                if verbose and fixes == "trail":
                    print(f"  draw {draw} " + _fix_line(w[i], np.r_[-e, -ey], fix, P, None))
                continue
            K = P @ np.linalg.inv(S)
            corr = K @ z
            if verbose and fixes == "trail":
                print(f"  draw {draw} " + _fix_line(w[i], np.r_[-e, -ey], fix, P, corr))
            turn = _turn(corr[2])
            R, shift, dyaw = turn @ R, est + turn @ (shift - est) + corr[:2], dyaw + corr[2]
            P_k, k, new_from = (np.eye(3) - K) @ P, i, w[i]
        rows.append({"draw": draw, "pos_error_max_m": round(max(err), 2), "pos_error_final_m": round(err[-1], 2),
                     "yaw_error_max_deg": round(max(yaw_err), 2), "inside_3sigma_frac": round(float(np.mean(inside)), 3),
                     "walked_m": round(float(w[-1]), 1), "fixes": dict(reasons)})  # fmt: skip
    return rows


def bound(path: str, samples_per_bin: tuple[float, ...] = (8.0, 4.0, 2.0), segment_m: float = 25.0) -> dict:
    """What the DEM can say at all about the recorded route: the Fisher information of a rigid shift (dx, dy) of
    the true footholds (binned per metre, as the trail fix bins them) against the noise-free DEM's gradient, each
    bin's σ the DEM's stated noise with the sub-pixel relief × `samples_per_bin` (the bins per independent DEM
    sample; the trail fix uses 8), the datum a line in the distance walked, profiled out: the σ of the
    whole route's shift along and across the route, and of each `segment_m` piece on its own datum line."""
    d = np.load(path)
    feet, seed, field_m = d["feet"], int(d["seed"]), float(d["field_m"])
    terrain = make_lunar(LunarConfig(seed=seed, size_m=field_m))
    clean = orbital_dem(
        terrain, replace(OrbitalDemConfig(), seed=seed, noise_m=0.0, bias_z_m=0.0, bias_xy_m=0.0)
    )
    cfg = OrbitalDemConfig()
    bins, s = bin_trail(feet[:, 5:8], feet[:, 1], LocalizerConfig().dem_trail.bin_m)
    eps = 0.05
    G = np.column_stack([(clean.height(bins[:, 0] + eps, bins[:, 1]) - clean.height(bins[:, 0] - eps, bins[:, 1])) / (2 * eps),
                         (clean.height(bins[:, 0], bins[:, 1] + eps) - clean.height(bins[:, 0], bins[:, 1] - eps)) / (2 * eps)])  # fmt: skip
    along = bins[-1, :2] - bins[0, :2]
    along /= np.linalg.norm(along)
    across = np.array([-along[1], along[0]])

    def info(m: np.ndarray) -> np.ndarray:
        A = np.column_stack([np.ones(int(m.sum())), s[m] - s[m].mean()])
        Gp = G[m] - A @ np.linalg.lstsq(A, G[m], rcond=None)[0]
        return Gp.T @ Gp

    var0 = cfg.noise_m**2 + DemReference(clean).subpixel_m ** 2
    out: dict = {"bins": len(bins), "grad_rms_along": round(float(np.sqrt(np.mean((G @ along) ** 2))), 3),
                 "grad_rms_across": round(float(np.sqrt(np.mean((G @ across) ** 2))), 3)}  # fmt: skip
    for spb in samples_per_bin:
        C = np.linalg.inv(info(np.ones(len(s), bool)) / (var0 * spb))
        out[f"route_sigma_m_spb{spb:g}"] = {"along": round(float(np.sqrt(along @ C @ along)), 2),
                                            "across": round(float(np.sqrt(across @ C @ across)), 2)}  # fmt: skip
    seg = []
    for a0 in np.arange(0.0, float(s.max()), segment_m):
        m = (s >= a0) & (s < a0 + segment_m)
        if m.sum() >= 8:
            lam = np.linalg.eigvalsh(info(m) / (var0 * samples_per_bin[0]))
            seg.append(round(float(1.0 / np.sqrt(max(lam.max(), 1e-12))), 1))
    out[f"segment_best_sigma_m_spb{samples_per_bin[0]:g}"] = seg
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("--seed", type=int, required=True)
    r.add_argument("--field", type=float, default=100.0)
    r.add_argument("--sim-seconds", type=float, default=None, help="stop after this much (default: the walk)")
    r.add_argument("--route", default="direct", help="the lunar route (direct, west, east)")
    p = sub.add_parser("replay")
    p.add_argument("rec")
    p.add_argument("--draws", type=int, default=6)
    p.add_argument("--fixes", choices=("trail", "window", "none"), default="trail")
    p.add_argument(
        "--prior-scale",
        type=float,
        default=1.0,
        help="multiply the recorded filter's (x, y, heading) covariance by this (what a tighter filter would do)",
    )
    p.add_argument("--verbose", action="store_true", help="each fix against the truth")
    b = sub.add_parser("bound")
    b.add_argument("rec")
    sp = sub.add_parser("split")
    sp.add_argument("rec")
    for q in (p, sp):
        q.add_argument("--along-k", type=float, default=None,
                       help="re-derive the recorded filter's covariance with this odometry scale σ [per metre]")  # fmt: skip
        q.add_argument(
            "--recorded-k", type=float, default=0.01, help="the odometry scale σ the walk ran with"
        )
        q.add_argument(
            "--odo-scale", type=float, default=0.0, help="shorten every dead-reckoned step by this share"
        )
        q.add_argument(
            "--crab-deg", type=float, default=0.0, help="turn every dead-reckoned step by this [deg]"
        )
    a = ap.parse_args()
    if a.cmd == "split":
        print(json.dumps(split(a.rec, a.along_k, a.odo_scale, a.recorded_k, a.crab_deg), indent=1))
        return
    if a.cmd == "bound":
        print(json.dumps(bound(a.rec)))
        return
    if a.cmd == "record":
        print(json.dumps(record(a.out, a.seed, a.field, a.sim_seconds, a.route)))
        return
    rows = replay(a.rec, a.draws, a.fixes, prior_scale=a.prior_scale, verbose=a.verbose, along_k=a.along_k,
                  odo_scale=a.odo_scale, recorded_k=a.recorded_k, crab_deg=a.crab_deg)  # fmt: skip
    for row in rows:
        print(json.dumps(row))
    print(json.dumps({k: round(float(np.mean([row[k] for row in rows])), 3)
                      for k in ("pos_error_max_m", "yaw_error_max_deg", "inside_3sigma_frac")} | {"mean_of": len(rows)}))  # fmt: skip


if __name__ == "__main__":
    main()
