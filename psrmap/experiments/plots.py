"""The experiments' figures (matplotlib, Agg backend: no display needed). Every function writes one PNG and
returns its path."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.colors import LightSource  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from psrmap.experiments.maps import dense  # noqa: E402

if TYPE_CHECKING:
    from scout_agent.cells import LocalMap
    from scout_agent.sim.terrain import Terrain

__all__ = ["lunar_maps", "ramp_elevation_rmse", "ramp_profile", "slopes", "utility_bars", "utility_map"]

DPI = 110
LAYER_TITLES = {
    "elevation": "elevation [m]",
    "slip": "slip events",
    "cot": "CoT [-]",
    "giim": "GIIM [rad]",
    "giam": "GIAM [m/s²]",
}
CONDITION_STYLE = {
    "plain": ("uniform μ 0.7", "tab:blue"),
    "slippery": ("slippery down-ramp patch", "tab:red"),
}


def _save(fig: Figure, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def _nan(a: Iterable[float | None]) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in a], float)


# ------------------------------------------------------------------------------------------ ramps


def ramp_profile(
    path: Path,
    angle: float,
    profiles: dict[str, dict],
    segments: dict | None,
    exact: tuple[np.ndarray, np.ndarray],
    patch: list | None,
) -> Path:
    """The paper's lateral view: five layers along the walking direction, transitions dashed.

    Each row: the layer's value per 0.4 m column of cells (pooled over the runs), as colour-coded markers
    (cool = low, warm = high, as in the paper) joined by a line per condition."""
    rows = [
        ("elevation", "elevation"),
        ("slip", "slip_events_per_run"),
        ("cot", "cot"),
        ("giim", "giim"),
        ("giam", "giam"),
    ]
    fig, axes = plt.subplots(len(rows), 1, figsize=(8.5, 10.5), sharex=True)
    for ax, (layer, key) in zip(axes, rows, strict=True):
        for cond, prof in profiles.items():
            label, color = CONDITION_STYLE.get(cond, (cond, "k"))
            x, y = np.asarray(prof["x"]), _nan(prof[key])
            ax.plot(x, y, "-", color=color, lw=1.0, alpha=0.6, label=label)
            ok = np.isfinite(y)
            if ok.any():
                ax.scatter(
                    x[ok], y[ok], c=y[ok], cmap="coolwarm", s=28, edgecolors=color, linewidths=0.8, zorder=3
                )
            if layer in ("giim", "giam") and f"{key}_paper" in prof:
                ax.plot(
                    x,
                    _nan(prof[f"{key}_paper"]),
                    "--",
                    color=color,
                    lw=1.0,
                    alpha=0.6,
                    label=f"{label}, paper variant",
                )
        if layer == "elevation":
            ax.plot(exact[0], exact[1], "k:", lw=1.0, label="exact ramp")
        if patch is not None and "slippery" in profiles:
            ax.axvspan(patch[0], patch[2], color="tab:red", alpha=0.08, lw=0)
        if segments:
            for name in ("up", "down"):
                for xb in segments[name]:
                    ax.axvline(xb, color="0.3", ls="--", lw=0.8)
        ax.set_ylabel(LAYER_TITLES[layer] + (" / run" if layer == "slip" else ""))
        ax.grid(alpha=0.25)
    handles, labels = axes[3].get_legend_handles_labels()
    h0, l0 = axes[0].get_legend_handles_labels()
    handles += [h for h, lab in zip(h0, l0, strict=True) if lab == "exact ramp"]
    labels += ["exact ramp"] if "exact ramp" in l0 else []
    fig.legend(handles, labels, fontsize=7, loc="upper center", ncol=3, bbox_to_anchor=(0.5, 0.955))
    axes[-1].set_xlabel(
        "x along the walking direction [m] (dashed: ramp transitions; shaded: slippery patch)"
    )
    fig.suptitle(f"Ramps α = {angle:g}°: map layers in lateral view (0.4 m cells, runs pooled)")
    return _save(fig, path)


def ramp_elevation_rmse(path: Path, by_angle: dict[str, Any]) -> Path:
    fig, ax = plt.subplots(figsize=(6.5, 4))
    angles = sorted(by_angle, key=float)
    for res, marker in (("0.4", "o"), ("0.2", "s"), ("0.1", "^")):
        for key, ls, lab in (
            ("rmse_plane_m", "-", "scout's plane fit"),
            ("rmse_mean_only_m", ":", "mean (paper)"),
        ):
            ys = [by_angle[a].get("plain", {}).get("elevation", {}).get(res, {}).get(key) for a in angles]
            ax.plot([float(a) for a in angles], _nan(ys), ls, marker=marker, label=f"{res} m, {lab}")
    ax.axhline(0.0876, color="k", lw=0.8, ls="--", label="paper 0.0876 m (0.4 m)")
    ax.set_xlabel("ramp angle α [deg]")
    ax.set_ylabel("elevation RMSE [m]")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("Elevation RMSE vs the exact ramp (uniform regolith runs)")
    return _save(fig, path)


# ------------------------------------------------------------------------------------------ slopes


def slopes(path: Path, pts: list[dict], fits: dict[str, Any], metrics: tuple[str, ...]) -> Path | None:
    """CoT (red triangles), GIIM (blue circles), GIAM (green squares) vs inclination with 4th-degree fits;
    left the four-foothold margins, right the paper variant."""
    if not pts:
        return None
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), sharey=True)
    panels = (
        ("four most recent footholds (default)", "giim_mean", "giam_mean"),
        ("paper variant", "giim_paper_mean", "giam_paper_mean"),
    )
    for ax, (title, giim, giam) in zip(axes, panels, strict=True):
        for metric, color, marker, label in (
            ("cot_mean", "tab:red", "^", "CoT [-]"),
            (giim, "tab:blue", "o", "GIIM [rad]"),
            (giam, "tab:green", "s", "GIAM [m/s²]"),
        ):
            xy = np.array(
                [(p["inclination_deg"], p[metric]) for p in pts if p.get(metric) is not None], float
            )
            if len(xy):
                ax.scatter(xy[:, 0], xy[:, 1], c=color, marker=marker, s=22, alpha=0.7, label=label)
            f = fits.get(metric)
            if f:
                xs = np.linspace(float(f["x_range"][0]), float(f["x_range"][1]), 200)
                ax.plot(xs, np.polyval(f["coef_high_to_low"], xs), color=color, lw=1.5)
        ax.set_title(f"GIA margins: {title}")
        ax.set_xlabel("inclination [deg]  (negative = uphill, positive = downhill)")
        ax.axvline(0, color="0.6", lw=0.6)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("metric value (its unit)")
    axes[0].legend(fontsize=8)
    fig.suptitle("Proprioceptive metrics vs ramp inclination (segment means per run, 4th-degree fits)")
    return _save(fig, path)


# ------------------------------------------------------------------------------------------ lunar


def _hillshade(ax: Axes, terrain: Terrain) -> None:
    ls = LightSource(azdeg=315, altdeg=45)
    xa, ya, xb, yb = terrain.extent
    ax.imshow(
        ls.hillshade(terrain.z, vert_exag=2.0, dx=terrain.res, dy=terrain.res),
        cmap="gray",
        origin="lower",
        extent=(xa, xb, ya, yb),
        alpha=0.9,
    )


def _patches(ax: Axes, patches: list) -> None:
    for x0, y0, x1, y1, mu in patches:
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="magenta", lw=1.0, ls="--"))
        ax.text(x0, y1 + 0.1, f"μ{mu:.2f}", color="magenta", fontsize=6)


def lunar_maps(
    out_dir: Path, seed: int, terrain: Terrain, runs: dict[str, dict], merged: LocalMap
) -> list[Path]:
    """Per layer one PNG: the map of each trajectory (its own scout) and the merged map, over the terrain."""
    paths = []
    routes: list[str] = [r for r in ("direct", "west", "east") if r in runs]
    patches = next(iter(runs.values()))["friction"]["patches"] if runs else []
    # terrain overview
    fig, ax = plt.subplots(figsize=(6, 6))
    xa, ya, xb, yb = terrain.extent
    im = ax.imshow(terrain.z, origin="lower", extent=(xa, xb, ya, yb), cmap="terrain")
    _patches(ax, patches)
    for name in routes:
        wp = np.asarray(runs[name]["waypoints"])
        ax.plot(wp[:, 0], wp[:, 1], "--", lw=1, label=f"{name} (planned)")
        tr = runs[name]["track"]
        ax.plot(
            tr[:, 1],
            tr[:, 2],
            lw=1.4,
            label=f"{name} (walked{', FELL' if runs[name]['summary']['fell'] else ''})",
        )
    fig.colorbar(im, ax=ax, shrink=0.8, label="height [m]")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(f"Lunar terrain seed {seed}: routes and slippery patches")
    paths.append(_save(fig, out_dir / f"lunar_seed{seed}_terrain.png"))
    for layer in ("elevation", "slip", "cot", "giim", "giam"):
        what = "events" if layer == "slip" else "value"
        grids: list[tuple[str, np.ndarray]] = [
            (name, dense(runs[name]["cells"][layer], layer, what=what)) for name in routes
        ]
        grids.append(("merged", dense(merged.cells(layer), layer, what=what)))
        finite = np.concatenate([g[np.isfinite(g)] for _, g in grids]) if grids else np.array([])
        if finite.size:
            vmin, vmax = np.percentile(finite, [2, 98])
            if layer == "slip":
                vmin, vmax = 0.0, max(1.0, float(finite.max()))
        else:
            vmin, vmax = 0.0, 1.0
        fig, axes = plt.subplots(1, len(grids), figsize=(4.2 * len(grids), 4.4))
        axes = np.atleast_1d(axes)
        for ax, (name, g) in zip(axes, grids, strict=True):
            _hillshade(ax, terrain)
            im = ax.imshow(
                g,
                origin="lower",
                extent=(0, g.shape[1] * 0.4, 0, g.shape[0] * 0.4),
                cmap="viridis" if layer != "slip" else "hot_r",
                vmin=vmin,
                vmax=vmax,
                interpolation="nearest",
            )
            _patches(ax, patches)
            if name in runs:
                pts = runs[name]["slip_points"]["truth"]
                if len(pts) and layer == "slip":
                    ax.plot(pts[:, 0], pts[:, 1], "c.", ms=3, label="ground-truth slips")
                    ax.legend(fontsize=6, loc="lower right")
            ax.set_title(
                f"{name}" + (" (all trajectories)" if name == "merged" else " trajectory"), fontsize=9
            )
            ax.set_xlim(0, 20)
            ax.set_ylim(0, 20)
        fig.colorbar(im, ax=list(axes), shrink=0.8, label=LAYER_TITLES[layer])
        fig.suptitle(f"Lunar seed {seed}: {layer} layer per trajectory (0.4 m cells)")
        paths.append(_save(fig, out_dir / f"lunar_seed{seed}_{layer}.png"))
    return paths


# ------------------------------------------------------------------------------------------ utility


def utility_map(
    path: Path,
    seed: int,
    terrain: Terrain,
    scouts_local: LocalMap,
    scout_runs: list[dict],
    planned: list,
    straight: list,
    walked: dict[str, list[dict]],
) -> Path:
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.6))
    patches = scout_runs[0]["friction"]["patches"] if scout_runs else []
    for ax, layer in zip(axes, ("cot", "slip"), strict=True):
        _hillshade(ax, terrain)
        g = dense(scouts_local.cells(layer), layer, what="events" if layer == "slip" else "value")
        finite = g[np.isfinite(g)]
        vmax = (
            (np.percentile(finite, 98) if layer == "cot" else max(1.0, finite.max())) if finite.size else 1.0
        )
        vmin = np.percentile(finite, 2) if layer == "cot" and finite.size else 0.0
        im = ax.imshow(
            g,
            origin="lower",
            extent=(0, g.shape[1] * 0.4, 0, g.shape[0] * 0.4),
            cmap="viridis" if layer == "cot" else "hot_r",
            vmin=vmin,
            vmax=vmax,
            interpolation="nearest",
        )
        fig.colorbar(im, ax=ax, shrink=0.75, label=f"scouts' {LAYER_TITLES[layer]}")
        _patches(ax, patches)
        p = np.asarray(planned)
        s = np.asarray(straight)
        ax.plot(p[:, 0], p[:, 1], "--", color="deepskyblue", lw=1.2, label="planned (scouts' map)")
        ax.plot(s[:, 0], s[:, 1], "--", color="orange", lw=1.2, label="straight")
        for name, color in (("planned", "deepskyblue"), ("straight", "orange")):
            for r in walked.get(name, []):
                tr = r["track"]
                ax.plot(
                    tr[:, 1],
                    tr[:, 2],
                    "-",
                    color=color,
                    lw=2.0,
                    alpha=0.8,
                    label=f"fresh robot, {name}" + (" (FELL)" if r["summary"]["fell"] else ""),
                )
                gt = r["slip_points"]["truth"]
                if len(gt):
                    ax.plot(gt[:, 0], gt[:, 1], "x", color=color, ms=4)
        ax.set_xlim(0, 20)
        ax.set_ylim(0, 20)
        ax.set_title(f"scouts' {layer} map, routes, fresh robot (x: its true slips)", fontsize=9)
    axes[0].legend(fontsize=7, loc="upper left")
    fig.suptitle(f"Map utility, lunar seed {seed}")
    return _save(fig, path)


def utility_bars(path: Path, per_seed: dict[str, Any]) -> Path | None:
    seeds = [k for k, e in per_seed.items() if e.get("experienced")]
    if not seeds:
        return None
    metrics = (
        ("cot_whole_run", "CoT (whole walk)", "mean_cot"),
        ("gt_slips", "true slips", "expected_slip_events"),
        ("giim_mean", "GIIM mean [rad]", "mean_giim"),
        ("energy_m", "energy Σ E/(m g) [m]", None),
    )
    fig, axes = plt.subplots(1, len(metrics), figsize=(4 * len(metrics), 3.6))
    w = 0.2
    for ax, (key, title, pred) in zip(axes, metrics, strict=True):
        x = np.arange(len(seeds))
        for k, (name, color) in enumerate((("planned", "tab:blue"), ("straight", "tab:orange"))):
            exp = [(per_seed[s]["experienced"].get(name) or {}).get(key) for s in seeds]
            ax.bar(
                x + (k - 0.5) * 2 * w,
                _nan(exp),
                w * 2 if pred is None else w,
                color=color,
                label=f"{name}: experienced",
            )
            if pred is not None:
                pv = [(per_seed[s]["predicted"].get(name) or {}).get(pred) for s in seeds]
                ax.bar(
                    x + (k - 0.5) * 2 * w + w,
                    _nan(pv),
                    w,
                    color=color,
                    alpha=0.4,
                    hatch="//",
                    label=f"{name}: predicted",
                )
        ax.set_xticks(x, [f"seed {s}" for s in seeds])
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3, axis="y")
    axes[0].legend(fontsize=6)
    fig.suptitle("Map utility: predicted (scouts' map) vs experienced (fresh robot)")
    return _save(fig, path)
