"""One datum problem for a whole fleet, offline (evaluation only: it scores against the simulator's truth).

Takes `height_replay.py record` recordings of a mission's scouts (each walked alone, the DEM its only
reference), takes the localizer's fixes back out of their footholds' heights, and fits the DEM's height along
each walk in hindsight twice: each scout alone, and all of them in one least-squares problem. The problem is
`localization/height_track.py`'s per scout (datum, drift per metre walked, a random walk about that line, the
footholds' misplacement per 10 m with the DEM's gradient), with two unknowns shared by every scout: each DEM
pixel's error (σ the DEM's stated noise) and the relief below the DEM's resolution as a field on a `--cell` grid
(σ `DemReference.subpixel_m`), read bilinearly where the estimate placed the footholds — so two scouts that
stand on the same ground read the same pixels and the same relief and are tied through them. Prints each
walk's footholds' height error (RMS against their true contact points), the fleet's, and for the first two
recordings how their errors compare along the first one's walk (10 m means: their difference, their
correlation, the RMS of their mean: what they share). `--true-place` puts every foothold where it really was
(what perfect placement would allow).

    python benchmarks/height_replay.py record --field 100 --seed 33 --scout I --out recI.npz   # I = 0, 1, 2
    python benchmarks/fleet_datum.py rec0.npz rec1.npz rec2.npz [--true-place]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from height_replay import _run_config
from scipy.sparse import csr_matrix, diags
from scipy.sparse.linalg import spsolve

from scout_agent.localization.height_track import HeightTrack, HeightTrackConfig, _bilinear, _walk_rows
from scout_agent.run import build_world, dem_reference

_HT = HeightTrackConfig()


def _load(path: Path, true_place: bool, dems: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, object]:
    """Bins (walked, n, x, y, z, σ_xy²) of the footholds without the fixes' corrections, the footholds, their
    heights without the corrections, the DEM (one per field and seed, in `dems`)."""
    d = np.load(path)
    key = (float(d["field_m"]), int(d["seed"]))
    if key not in dems:
        cfg = _run_config(key[0], key[1], int(d["index"]))
        dems[key] = dem_reference(cfg, build_world(cfg))
    dem = dems[key]
    F, fx = d["feet"], d["fixes"]
    if F.shape[1] < 9 and true_place:
        raise SystemExit(f"{path}: recorded without the footholds' true x, y (record again for --true-place)")
    raw = F[:, 4] - np.array([float(fx[fx[:, 0] < t, 1].sum()) if len(fx) else 0.0 for t in F[:, 1]])
    ht = HeightTrack()
    for k in range(len(F)):
        x, y = (F[k, 7], F[k, 8]) if true_place else (F[k, 2], F[k, 3])
        ht.add(np.array([[x, y, raw[k]]]), F[k, 0], 0.05 if true_place else F[k, 6])
    return ht._bins[: ht._n].copy(), F, raw, dem


def _grid_bilinear(x: np.ndarray, y: np.ndarray, cell: float, nx: int) -> tuple[np.ndarray, np.ndarray]:
    u, v = x / cell - 0.5, y / cell - 0.5
    i0, j0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - i0, v - j0
    idx = np.stack([j0 * nx + i0, j0 * nx + i0 + 1, (j0 + 1) * nx + i0, (j0 + 1) * nx + i0 + 1], 1)
    return idx, np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], 1)


def solve(tracks: list[np.ndarray], dem, cell: float, bin_noise: float, c: HeightTrackConfig = _HT):
    """Each track's datum along its walk (a function of the distance before its end, ≤ 0) from one problem."""
    g = dem.dem
    nxr = int(np.ceil(max(float(b[:, 2].max()) for b in tracks) / cell)) + 3
    blocks, off = [], 0
    for b in tracks:
        rel = b[:, 0] - b[:, 0].max()
        nk = max(1, int(np.ceil(-rel.min() / c.knot_m + 1e-9)))
        seg = np.floor((b[:, 0] - b[:, 0].min()) / c.segment_m).astype(np.int64)
        blocks.append({"off": off, "nk": nk, "ns": int(seg.max()) + 1, "seg": seg, "rel": rel})
        off += 2 + nk + 2 * (int(seg.max()) + 1)
    pix = [_bilinear(g, b[:, 2], b[:, 3]) for b in tracks]
    rel_cells = [_grid_bilinear(b[:, 2], b[:, 3], cell, nxr) for b in tracks]
    upix = np.unique(np.concatenate([p.ravel() for p, _ in pix]))
    urel = np.unique(np.concatenate([p.ravel() for p, _ in rel_cells]))
    o_p, o_r = off, off + len(upix)
    n_u = o_r + len(urel)
    rows, cols, vals, yv = [], [], [], []
    prior = np.zeros(n_u)
    r0 = 0
    for b, blk, (pp, pw), (rp, rw) in zip(tracks, blocks, pix, rel_cells, strict=True):
        m, o, nk = len(b), blk["off"], blk["nk"]
        ri = r0 + np.arange(m)

        def add(ci: np.ndarray, vi: np.ndarray, ri: np.ndarray = ri) -> None:
            rows.append(np.repeat(ri, ci.shape[1]) if ci.ndim == 2 else ri)
            cols.append(ci.ravel())
            vals.append(vi.ravel())

        add(np.full(m, o), np.ones(m))
        add(np.full(m, o + 1), blk["rel"])
        add(o + 2 + np.tile(np.arange(nk), (m, 1)), _walk_rows(blk["rel"], c.knot_m, nk))
        add(o_p + np.searchsorted(upix, pp), pw)
        add(o_r + np.searchsorted(urel, rp), rw)
        x, y = b[:, 2], b[:, 3]
        gx = np.nan_to_num((g.height(x + g.pixel_m, y) - g.height(x - g.pixel_m, y)) / (2 * g.pixel_m))
        gy = np.nan_to_num((g.height(x, y + g.pixel_m) - g.height(x, y - g.pixel_m)) / (2 * g.pixel_m))
        od = o + 2 + nk
        add(od + 2 * blk["seg"], gx)
        add(od + 2 * blk["seg"] + 1, gy)
        yv.append(g.height(x, y) - b[:, 4])
        seg_var = np.zeros(blk["ns"])
        np.maximum.at(seg_var, blk["seg"], b[:, 5])
        prior[o], prior[o + 1] = 1e-8, 1.0 / c.rate_sigma**2
        prior[o + 2 : o + 2 + nk] = 1.0 / (c.walk_sigma**2 * c.knot_m)
        prior[od : od + 2 * blk["ns"]] = np.repeat(1.0 / np.maximum(seg_var, 1e-4), 2)
        r0 += m
    prior[o_p:o_r] = 1.0 / g.noise_m**2
    prior[o_r:] = 1.0 / dem.subpixel_m**2
    A = csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, n_u))
    y_all = np.concatenate(yv)
    theta = spsolve((A.T @ A / bin_noise**2 + diags(prior)).tocsc(), A.T @ y_all / bin_noise**2)
    out = []
    for blk in blocks:
        t, nk = theta[blk["off"] : blk["off"] + 2 + blk["nk"]], blk["nk"]
        out.append(
            lambda r, t=t, nk=nk: t[0] + t[1] * np.clip(r, -nk * c.knot_m, 0)
            + _walk_rows(np.clip(r, -nk * c.knot_m, 0), c.knot_m, nk) @ t[2:]
        )  # fmt: skip
    return out


def _along(F0: np.ndarray, F1: np.ndarray, e0: np.ndarray, e1: np.ndarray) -> tuple[int, float, float, float]:
    """Two walks' errors in 10 m means along the first (the second's footholds given the first's distance
    walked at its nearest foothold, by their true places): how many, RMS of the difference, of the mean,
    their correlation."""
    s0 = np.floor(F0[:, 0] / 10.0)
    near = np.array([np.argmin(np.hypot(F0[:, 7] - x, F0[:, 8] - y)) for x, y in F1[::20, 7:9]])
    s1 = np.floor(F0[near, 0] / 10.0)
    keys = sorted(set(s0) & set(s1))
    m0 = np.array([e0[s0 == k].mean() for k in keys])
    m1 = np.array([e1[::20][s1 == k].mean() for k in keys])
    return len(keys), _rms(m0 - m1), _rms((m0 + m1) / 2), float(np.corrcoef(m0, m1)[0, 1])


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "recordings", type=Path, nargs="+", help="height_replay.py recordings of one mission's scouts"
    )
    p.add_argument("--cell", type=float, default=2.5, help="the relief field's grid [m] (default 2.5)")
    p.add_argument("--bin-noise", type=float, default=0.05, help="a 1 m bin's own height noise [m] (0.05)")
    p.add_argument("--true-place", action="store_true", help="the footholds where they really were")
    a = p.parse_args(argv)
    dems: dict = {}
    loaded = [_load(r, a.true_place, dems) for r in a.recordings]
    dem = loaded[0][3]
    errs = {}
    for label, fits in (
        ("alone", [solve([b], dem, a.cell, a.bin_noise)[0] for b, *_ in loaded]),
        ("joint", solve([b for b, *_ in loaded], dem, a.cell, a.bin_noise)),
    ):
        errs[label] = [
            raw + f(F[:, 0] - b[:, 0].max()) - F[:, 5] for (b, F, raw, _), f in zip(loaded, fits, strict=True)
        ]
        e = errs[label]
        print(f"{label}: footholds' height error {', '.join(f'{_rms(x):.3f}' for x in e)} m; the fleet's "
              f"{_rms(np.concatenate(e)):.3f} m")  # fmt: skip
    if len(loaded) >= 2 and loaded[0][1].shape[1] >= 9 and loaded[1][1].shape[1] >= 9:
        for label, e in errs.items():
            n, diff, mean, corr = _along(loaded[0][1], loaded[1][1], e[0], e[1])
            print(f"  {label}, the first two along the first's walk ({n} × 10 m): difference {diff:.3f} m, "
                  f"their mean {mean:.3f} m, correlated {corr:+.2f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
