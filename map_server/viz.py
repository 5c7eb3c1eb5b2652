"""Rerun logging of merged layers (the only module of `map_server` that imports rerun).

Each changed tile of each layer is logged as an RGBA `rr.GridMap` at `map/<layer>/<tx>_<ty>` and its
observation count at `map/counts/<layer>/<tx>_<ty>`, coloured on the layer's fixed scale
(`psrmap_common.recording.LAYER_SCALES`), unknown cells transparent, at most once per `interval_s`; untouched
tiles are never re-sent. Rerun puts a GridMap's `translation` at the image's lower-left corner and draws
image row 0 at the top, so the tile (row = iy, growing north) is flipped before it is sent.

Everything is logged on `sim_time` (the newest merged sample's scout clock: mission time) and on `version`
(the map version), so the map grows in step with the scouts when the recording is scrubbed.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import rerun as rr

from psrmap_common.recording import COUNT_SCALE, LAYER_SCALES, TIMELINE, Scale, colorize, open_stream
from psrmap_mapcore import TiledMap

__all__ = ["MapViz", "grid_map"]


OPACITY = 0.95  # below 1 the viewer blends the image's alpha, so unknown (alpha 0) cells are see-through


def grid_map(
    values: np.ndarray, scale: Scale, res: float, x0: float, y0: float, z: float = 0.0
) -> rr.GridMap:
    """`values[iy, ix]` (row 0 = southmost cells at y0) as an RGBA GridMap whose lower-left corner is (x0, y0).

    Rerun draws a GridMap with opacity 1 opaque whatever its alpha; `OPACITY` < 1 turns blending on."""
    img = np.ascontiguousarray(colorize(values, scale)[::-1])
    h, w = values.shape
    fmt = rr.components.ImageFormat(width=w, height=h, color_model="RGBA", channel_datatype="U8")
    return rr.GridMap(data=img.tobytes(), format=fmt, cell_size=res, translation=[x0, y0, z], opacity=OPACITY)


class MapViz:
    def __init__(
        self, rrd_path: str, map_id: str, recording_id: str | None = None, interval_s: float = 1.0
    ) -> None:
        self.stream = open_stream(rrd_path, f"psrmap-{map_id}", recording_id)
        self.interval_s = interval_s
        self._last = 0.0
        self._pending: set[tuple[str, int, int]] = set()
        self._t = 0.0

    def log_tiles(
        self,
        tiled: TiledMap,
        dirty: set[tuple[str, int, int]],
        lock: threading.Lock,
        version: int = 0,
        t: float | None = None,
        force: bool = False,
    ) -> int:
        """Queue `dirty` tiles; every `interval_s` log the queued ones at mission time `t` (the newest merged
        sample's clock [s]; None: the last one); `force`: now (the server stops). Returns tiles logged."""
        self._pending |= dirty
        if t is not None:
            self._t = max(self._t, float(t))
        now = time.monotonic()
        if (now - self._last < self.interval_s and not force) or not self._pending:
            return 0
        self._last = now
        pending, self._pending = self._pending, set()
        T, res = tiled.tile, tiled.res
        self.stream.set_time("version", sequence=version)
        self.stream.set_time(TIMELINE, duration=self._t)
        for layer, tx, ty in sorted(pending):
            with lock:
                grid = tiled.region(tx * T, ty * T, tx * T + T - 1, ty * T + T - 1, [layer], ["value", "n"])[
                    layer
                ]
            value, count = grid["value"], grid["n"]
            scale = LAYER_SCALES.get(layer, Scale(0.0, 1.0, "", "viridis", layer))
            x0, y0 = tx * T * res, ty * T * res
            self.stream.log(f"map/{layer}/{tx}_{ty}", grid_map(value, scale, res, x0, y0))
            n = np.where(count > 0, count, np.nan)
            self.stream.log(f"map/counts/{layer}/{tx}_{ty}", grid_map(n, COUNT_SCALE, res, x0, y0))
        with lock:
            cells = tiled.cells
        self.stream.log("map/status/cells", rr.Scalars(float(cells)))
        self.stream.log("map/status/version", rr.Scalars(float(version)))
        return len(pending)

    def close(self) -> None:
        self.stream.flush()
        self.stream.disconnect()
