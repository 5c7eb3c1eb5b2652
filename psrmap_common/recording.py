"""The Rerun recording every process of one mission shares: ids, timeline, and how map layers are coloured.

Processes started for one mission (server, scouts, planner) each write their own .rrd, with the same
application id and the recording id taken from the `PSRMAP_RECORDING_ID` environment variable, so the files
open (or merge, `rerun rrd merge`) as one recording. A live viewer, if the mission has one, is named by
`PSRMAP_VIEWER_URL`: every process then streams to it as well as to its file.

Every process logs on one timeline, `sim_time` (mission time: the scouts' clock, which starts when they
do), so scrubbing it shows scouts, the growing map and the plans together; the server also logs `version`.

Map layers are drawn with a fixed, documented value range and colormap per layer (`LAYER_SCALES`), unknown
cells transparent (`colorize`), so a colour means the same value in every tile, process and mission. This
module only names the convention (numpy only); it does not import rerun (only the `viz` modules do).
"""

from __future__ import annotations

import os
import shutil
import socket
import sys
from dataclasses import dataclass
from urllib.parse import urlsplit

import numpy as np

from psrmap_common.errors import ViewerUnavailable
from psrmap_common.session import free_port

__all__ = [
    "APP_ID",
    "COUNT_SCALE",
    "LAYER_SCALES",
    "RECORDING_ID_ENV",
    "TIMELINE",
    "VIEWER_URL_ENV",
    "Scale",
    "ViewerUnavailable",
    "check_viewer_reachable",
    "check_viewer_url",
    "colorize",
    "legend_markdown",
    "open_stream",
    "recording_id",
    "scout_color",
    "spawn_viewer",
    "use_viewer",
    "viewer_url",
]

APP_ID = "psrmap"
RECORDING_ID_ENV = "PSRMAP_RECORDING_ID"
VIEWER_URL_ENV = "PSRMAP_VIEWER_URL"
TIMELINE = "sim_time"  # mission time [s], the scouts' clock: the timeline every process logs on


def recording_id(default: str | None = None) -> str | None:
    """The mission's recording id from the environment, else `default` (None: Rerun picks a fresh one)."""
    return os.environ.get(RECORDING_ID_ENV) or default


def viewer_url() -> str | None:
    """The live viewer (`rerun+http://host:port/proxy`) the mission streams to, if any."""
    return os.environ.get(VIEWER_URL_ENV) or None


def check_viewer_url(url: str) -> str:
    """`url` if it names a Rerun gRPC proxy, else ValueError naming the valid form."""
    if not (
        url.startswith(("rerun://", "rerun+http://", "rerun+https://")) and url.rstrip("/").endswith("/proxy")
    ):
        raise ValueError(
            f"viewer URL {url!r}: need rerun+http://HOST:PORT/proxy (e.g. rerun+http://127.0.0.1:9876/proxy)"
        )
    return url


def open_stream(path: str | None, default_id: str | None = None, explicit_id: str | None = None):
    """A Rerun stream (`rr.RecordingStream`) in recording `explicit_id`, else the mission's
    (`PSRMAP_RECORDING_ID`), else `default_id`; saved to `path` (if given) and streamed live to the viewer
    named by `PSRMAP_VIEWER_URL` (if set). rerun is imported here, only by processes that record."""
    import rerun as rr  # lazy: Rerun only in processes that record

    rec = rr.RecordingStream(APP_ID, recording_id=explicit_id or recording_id(default_id))
    sinks: list = [rr.FileSink(path)] if path else []
    if viewer_url():
        sinks.append(rr.GrpcSink(viewer_url()))
    rec.set_sinks(*sinks)
    return rec


def _no_display() -> str | None:
    """Why a viewer window cannot open here, or None (Linux needs an X11 or Wayland display)."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        return "no display here (neither DISPLAY nor WAYLAND_DISPLAY is set)"
    return None


def _listening(host: str, port: int, timeout_s: float = 3.0) -> str | None:
    """None if something accepts TCP connections on host:port within `timeout_s`, else why not."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return None
    except OSError as exc:
        return exc.strerror or type(exc).__name__


def spawn_viewer() -> str:
    """Start a local Rerun viewer on a free port, set `PSRMAP_VIEWER_URL` to it (children inherit it) and
    return its URL; `ViewerUnavailable` before anything starts when no window can open (no display, no
    `rerun` binary) or the viewer does not come up."""
    why = _no_display() or (None if shutil.which("rerun") else "the Rerun viewer `rerun` is not on PATH")
    if why:
        raise ViewerUnavailable(
            f"--viewer: {why}; the .rrd files are written anyway (open them where there is a display: "
            "rerun runs/<ts>/mission.rrd), or stream to a viewer elsewhere with --connect-viewer "
            "rerun+http://HOST:9876/proxy"
        )
    import rerun as rr  # lazy: Rerun only in processes that record

    port = free_port()
    # rr.spawn needs an enabled recording to act on (without one it only warns); it waits for the viewer
    rr.spawn(port=port, connect=False, recording=rr.RecordingStream(APP_ID, recording_id=recording_id()))
    if (why := _listening("127.0.0.1", port)) is not None:
        raise ViewerUnavailable(f"--viewer: the Rerun viewer did not start on port {port} ({why})")
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    os.environ[VIEWER_URL_ENV] = url
    return url


def check_viewer_reachable(url: str) -> str:
    """`url` (a valid viewer URL) if a viewer listens there, else `ViewerUnavailable` within a few seconds."""
    parts = urlsplit(check_viewer_url(url).replace("rerun://", "rerun+http://", 1))
    host, port = parts.hostname or "127.0.0.1", parts.port or 9876
    if (why := _listening(host, port)) is not None:
        raise ViewerUnavailable(
            f"--connect-viewer {url}: no Rerun viewer answers at {host}:{port} ({why}); start one there "
            "(`rerun`, it listens on 9876) or use --viewer for a local one"
        )
    return url


def use_viewer(spawn: bool, url: str | None) -> str | None:
    """The CLI's `--viewer` / `--connect-viewer URL`: make every stream this process (and its children)
    opens go live to that viewer too. Returns the URL in use; `ViewerUnavailable` (one line saying what to do
    instead) when there is no display to spawn one on or nothing listens at `url`."""
    if url:
        os.environ[VIEWER_URL_ENV] = check_viewer_reachable(url)
        return url
    return spawn_viewer() if spawn else None


# colormap anchors (value 0, 1/8, ..., 1): matplotlib's viridis and magma sampled at 9 points
_CMAPS = {
    "viridis": [(68, 1, 84), (71, 44, 122), (59, 81, 139), (44, 113, 142), (33, 144, 141),
                (39, 173, 129), (92, 200, 99), (170, 220, 50), (253, 231, 37)],
    "magma": [(0, 0, 4), (28, 16, 68), (79, 18, 123), (129, 37, 129), (181, 54, 122),
              (229, 80, 100), (251, 135, 97), (254, 194, 135), (252, 253, 191)],
}  # fmt: skip


@dataclass(frozen=True)
class Scale:
    """How one layer is drawn: values `lo`..`hi` [unit] spread over `cmap` (clipped outside), `log`: on
    log(1 + value) instead; NaN (no observation) is transparent."""

    lo: float
    hi: float
    unit: str
    cmap: str
    meaning: str
    log: bool = False


LAYER_SCALES: dict[str, Scale] = {
    "elevation": Scale(-1.5, 1.5, "m", "viridis", "terrain height (plane fit at the cell centre)"),
    "slip": Scale(0.0, 1.0, "events per stance", "magma", "slip rate: bright = slips often"),
    "cot": Scale(0.0, 3.0, "1", "viridis", "cost of transport: bright = dear to walk"),
    "giim": Scale(-0.3, 0.6, "rad", "viridis", "mean GIIM: dark = close to tipping"),
    "giam": Scale(-1.0, 1.5, "m/s²", "viridis", "mean GIAM: dark = close to tipping"),
    "contacts": Scale(0.0, 1.0, "fraction of samples", "magma", "non-foot body contacts"),
    "hazard": Scale(0.0, 3.0, "reports", "magma", "hazard stops: ground a scout could not hold"),
    "placement": Scale(0.0, 1.0, "m", "magma", "placement σ: bright = placed by a scout unsure where it was"),
}
COUNT_SCALE = Scale(0.0, 1000.0, "observations", "viridis", "observations behind each cell", log=True)


def colorize(values: np.ndarray, scale: Scale) -> np.ndarray:
    """(h, w) values -> (h, w, 4) RGBA uint8 on `scale`; NaN cells fully transparent."""
    v = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(v)
    lo, hi = scale.lo, scale.hi
    if scale.log:
        v, lo, hi = np.log1p(np.maximum(v, 0.0)), np.log1p(lo), np.log1p(hi)
    u = np.clip((np.where(ok, v, lo) - lo) / (hi - lo), 0.0, 1.0)
    anchors = np.asarray(_CMAPS[scale.cmap], dtype=np.float64)
    pos = np.linspace(0.0, 1.0, len(anchors))
    out = np.empty((*v.shape, 4), dtype=np.uint8)
    for c in range(3):
        out[..., c] = np.round(np.interp(u, pos, anchors[:, c])).astype(np.uint8)
    out[..., 3] = np.where(ok, 230, 0)
    return out


def legend_markdown() -> str:
    """The layers' colour scales as a Markdown table (the recording's legend panel)."""
    rows = [
        "| layer | range (clipped) | unit | colormap (dark → bright) | meaning |",
        "|---|---|---|---|---|",
    ]
    for name, s in [*LAYER_SCALES.items(), ("counts", COUNT_SCALE)]:
        rng = f"{s.lo:g} … {s.hi:g}" + (" (log)" if s.log else "")
        rows.append(f"| {name} | {rng} | {s.unit} | {s.cmap} | {s.meaning} |")
    rows.append("")
    rows.append(
        "Unknown cells (never observed) are transparent. Planner cost: cheapest passable cell dark, "
        "dearest bright (viridis over the plan's own cost range), impassable cells red."
    )
    return "\n".join(rows)


# distinct, colour-blind-friendly scout colours (Okabe–Ito), by scout number when the id ends in one
_SCOUT_COLORS = [(230, 159, 0), (86, 180, 233), (0, 158, 115), (240, 228, 66), (0, 114, 178),
                 (213, 94, 0), (204, 121, 167), (255, 255, 255)]  # fmt: skip


def scout_color(scout_id: str) -> tuple[int, int, int]:
    """A stable colour per scout: `scoutN` gets the N-th palette colour, other ids one by their hash."""
    digits = "".join(ch for ch in scout_id if ch.isdigit())
    k = int(digits) - 1 if digits else sum(scout_id.encode())
    return _SCOUT_COLORS[k % len(_SCOUT_COLORS)]
