"""The mission's map as a picture: the shared layers with the scouts' routes and the planned path (PNG)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

# (layer, how to read it from a LayerGrid, title, colour map, fixed range or None)
PANELS = (
    ("elevation", "value", "elevation [m]", "terrain", None),
    ("slope", "slope", "slope from plane fit [°]", "magma", (0.0, 30.0)),
    ("slip", "rate", "slip rate [events / stance]", "Reds", (0.0, 0.5)),
    ("cot", "value", "cost of transport", "viridis", (0.0, 3.0)),
    ("giim", "value", "GIIM mean [rad]", "RdYlGn", (0.0, 0.6)),
    ("giam", "value", "GIAM mean [m/s²]", "RdYlGn", (0.0, 1.2)),
)


def _layer(grid, layer: str, how: str) -> np.ndarray:
    if how == "slope":
        return grid.slope_deg()
    if how == "rate":
        return grid.slip_rate()
    return grid.value(layer)


def plot_map(
    grid,
    routes: Mapping[str, Sequence[Sequence[float]]],
    out: str | Path,
    title: str = "",
    planned: Sequence[Sequence[float]] | None = None,
) -> Path:
    """Write a 2×3 panel PNG of the map's layers with `routes` (name → [[x, y], ...]) and `planned` drawn."""
    import matplotlib  # lazy: matplotlib only when a picture is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xa, ya, xb, yb = grid.bounds_m()
    fig, axes = plt.subplots(2, 3, figsize=(15, 9.5), constrained_layout=True)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (layer, how, name, cmap, rng) in zip(axes.ravel(), PANELS, strict=True):
        data = _layer(grid, layer, how)
        kw = {"vmin": rng[0], "vmax": rng[1]} if rng else {}
        im = ax.imshow(
            data, origin="lower", extent=(xa, xb, ya, yb), cmap=cmap, interpolation="nearest", **kw
        )
        fig.colorbar(im, ax=ax, shrink=0.8)
        for i, (rname, pts) in enumerate(routes.items()):
            p = np.asarray(pts, dtype=float)
            ax.plot(p[:, 0], p[:, 1], "--", lw=1.0, color=colors[i % len(colors)], label=rname)
        if planned is not None and len(planned):
            p = np.asarray(planned, dtype=float)
            ax.plot(p[:, 0], p[:, 1], "-", lw=2.0, color="black", label="planned")
        ax.set_title(name)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal")
    axes[0, 0].legend(loc="upper left", fontsize=8)
    if title:
        fig.suptitle(title)
    out = Path(out)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
