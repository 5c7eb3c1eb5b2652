"""Rerun logging of merged layers (the only module of `map_server` that imports rerun).

Each changed tile of each layer is logged as an `rr.GridMap` at `map/<layer>/<tx>_<ty>` (8-bit,
value scaled per layer, 0 = no data), at most once per `interval_s`; untouched tiles are never re-sent.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import rerun as rr

from map_server.tiles import TiledMap
from protocol.recording import APP_ID
from protocol.recording import recording_id as mission_recording_id

__all__ = ["MapViz"]

# value range mapped to 1..255 per layer (0 = unknown)
RANGES = {
    "elevation": (-2.0, 2.0),
    "slip": (0.0, 1.0),
    "cot": (0.0, 3.0),
    "giim": (0.0, 0.8),
    "giam": (0.0, 5.0),
    "contacts": (0.0, 1.0),
}


COUNT_MAX = 1000.0  # counts are shown on a log scale up to this many observations


class MapViz:
    def __init__(
        self, rrd_path: str, map_id: str, recording_id: str | None = None, interval_s: float = 1.0
    ) -> None:
        self.stream = rr.RecordingStream(
            APP_ID, recording_id=recording_id or mission_recording_id(f"psrmap-{map_id}")
        )
        self.stream.save(rrd_path)
        self.interval_s = interval_s
        self._last = 0.0
        self._pending: set[tuple[str, int, int]] = set()

    def log_tiles(
        self, tiled: TiledMap, dirty: set[tuple[str, int, int]], lock: threading.Lock, version: int = 0
    ) -> int:
        """Queue `dirty` tiles; every `interval_s` log the queued ones. Returns tiles logged."""
        self._pending |= dirty
        now = time.monotonic()
        if now - self._last < self.interval_s or not self._pending:
            return 0
        self._last = now
        pending, self._pending = self._pending, set()
        T = tiled.tile
        self.stream.set_time("version", sequence=version)
        for layer, tx, ty in sorted(pending):
            with lock:
                grid = tiled.region(tx * T, ty * T, tx * T + T - 1, ty * T + T - 1, [layer], ["value", "n"])[
                    layer
                ]
            value, count = grid["value"], grid["n"]
            lo, hi = RANGES.get(layer, (0.0, 1.0))
            self._grid_map(f"map/{layer}/{tx}_{ty}", value, lo, hi, tiled.res, tx, ty, T)
            # counts: how many observations back each cell (log scale, 1 .. COUNT_MAX)
            n = np.where(count > 0, np.log1p(count), np.nan)
            self._grid_map(
                f"map/counts/{layer}/{tx}_{ty}", n, 0.0, float(np.log1p(COUNT_MAX)), tiled.res, tx, ty, T
            )
        with lock:
            cells = tiled.cells
        self.stream.log("map/status/cells", rr.Scalars(float(cells)))
        self.stream.log("map/status/version", rr.Scalars(float(version)))
        return len(pending)

    def _grid_map(
        self, path: str, value: np.ndarray, lo: float, hi: float, res: float, tx: int, ty: int, T: int
    ) -> None:
        """One tile as an 8-bit grid map: 0 = no data, 1..255 = `lo`..`hi`."""
        img = np.zeros(value.shape, dtype=np.uint8)
        ok = np.isfinite(value)
        img[ok] = (1 + np.clip((value[ok] - lo) / (hi - lo), 0.0, 1.0) * 254).astype(np.uint8)
        fmt = rr.components.ImageFormat(width=T, height=T, color_model="L", channel_datatype="U8")
        self.stream.log(
            path,
            rr.GridMap(
                data=img.tobytes(), format=fmt, cell_size=res, translation=[tx * T * res, ty * T * res, 0.0]
            ),
        )

    def close(self) -> None:
        self.stream.flush()
        self.stream.disconnect()
