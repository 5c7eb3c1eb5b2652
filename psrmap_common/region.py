"""A box of the shared map, and following it: the region query every reader sends, and the tile-change
notices that say when to send it again. Shared by the rover planner (`consumer_planner.client`), the ROS
bridge and the scouts (`scout_agent.localization`, which match their footholds against the map around
them): services do not import each other, so this lives in `psrmap_common`.

`fetch_region(session, map_id, box, ...)`: `get(psr/<map>/map?x0=..;y0=..;x1=..;y1=..;stats=all)` through
`psrmap_common.query` with `fan_out=True` (target ALL, no consolidation), so every map-server shard owning part of
the box answers; the replies are decoded with `protocol.codec.decode` (validated) and stitched into one
`LayerGrid` (`mapcore.stitch`). Raises `NoAnswer` (no server answered) or `QueryError` (every answer was an
error, or the replies cannot be one map).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from protocol.codec import INDEX_LIMIT, decode
from protocol.errors import MAX_CLIENT_CELLS, ProtocolError
from protocol.keys import changes_pattern, map_key
from protocol.layers import cell_index
from protocol.messages import MapRegion, RegionQuery, TileChanges
from psrmap_common.errors import QueryError
from psrmap_common.query import get_replies, get_statuses
from psrmap_common.trust import Trust, TrustedIds
from psrmap_mapcore import LayerGrid, MapCoreError, stitch

__all__ = ["Box", "NoAnswer", "RegionChange", "RegionFollower", "RegionWatch", "fetch_region"]

Box = tuple[float, float, float, float]

log = logging.getLogger(__name__)


class NoAnswer(QueryError):
    """No map server answered the region query in time."""


def fetch_region(
    session: zenoh.Session,
    map_id: str,
    box: tuple[float, float, float, float],
    timeout_s: float,
    *,
    trusted: Trust | Sequence[str] = (),
    layers: Sequence[str] | None = None,
    stats: Sequence[str] = ("all",),
    x0: float = 0.0,
    y0: float = 0.0,
    max_bytes: int = 256 * 1024 * 1024,
    max_cells: int = MAX_CLIENT_CELLS,
) -> LayerGrid:
    """The map box (x0, y0, x1, y1) [m, inclusive] from every shard that answers, stitched; (x0, y0) keyword
    arguments: the map frame's origin [m]; a reply larger than `max_bytes`, outside the box or spanning more
    than `max_cells` cells is refused before anything is allocated for it."""
    q = RegionQuery(*box, layers=tuple(layers) if layers is not None else None, stats=tuple(stats))
    key = map_key(map_id)
    regions: list[MapRegion] = []
    replies = get_replies(session, f"{key}?{q.to_parameters()}", timeout_s, fan_out=True, trusted=trusted)
    errors = replies.errors
    for payload in replies.ok:
        try:
            msg = decode(payload, expected_type="map_region", max_bytes=max_bytes)
        except ProtocolError as exc:
            errors.append(f"undecodable reply: {exc}")
            continue
        assert isinstance(msg, MapRegion)
        regions.append(msg)
    if not regions:
        if errors:
            raise QueryError(f"map servers refused {key!r}: {'; '.join(errors)}")
        raise NoAnswer(f"no map server answered {key!r} within {timeout_s:g} s")
    try:
        return stitch(regions, x0, y0, box_m=box, max_cells=max_cells)
    except MapCoreError as exc:  # replies that cannot be one map (ids, cell sizes, outside the box asked)
        raise QueryError(f"bad reply: {exc}") from None


# ---------------------------------------------------------------------------------------------- changes
# Every map server (every shard) publishes a `TileChanges` after each committed batch on
# `psr/<map>/changes/<server>`; `RegionWatch` subscribes to all of them, keeps the changes that touch its box
# and remembers each shard's newest version, so a planner re-queries and replans only when its corridor
# changed (`changed()`), not on every delta anywhere on the map.


@dataclass(frozen=True)
class RegionChange:
    shard: int | None  # which shard (None: an unsharded map)
    version: int  # that shard's map version holding the change
    tiles: np.ndarray  # (n, 2) tx, ty of the changed tiles that overlap the watched box


class RegionWatch:
    """`with RegionWatch(session, map_id, res, (x0, y0, x1, y1)) as w: ... w.changed(timeout)`; box None: the
    whole map (every change).

    trust: whose notices to act on (psrmap_common.trust; a notice names its sender in its source info); others are
    ignored with a log line and counted in `ignored`."""

    def __init__(
        self,
        session: zenoh.Session,
        map_id: str,
        res: float,
        box: Box | None,
        trust: Trust | Sequence[str] = (),
    ):
        if box is None:
            self.cells = (-INDEX_LIMIT, -INDEX_LIMIT, INDEX_LIMIT, INDEX_LIMIT)
        else:
            x0, y0, x1, y1 = box
            lo = cell_index(min(x0, x1), min(y0, y1), res)
            hi = cell_index(max(x0, x1), max(y0, y1), res)
            self.cells = (int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1]))  # inclusive cell box
        self.versions: dict[
            int | None, int
        ] = {}  # newest version seen per shard (any change, in the box or not)
        self._pending: list[RegionChange] = []
        self._cond = threading.Condition()
        self.ignored = 0  # undecodable notifications, and notices from senders not trusted
        self._trusted = TrustedIds(session, map_id, Trust.of(trust))
        self._sub = session.declare_subscriber(changes_pattern(map_id), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        info = sample.source_info
        zid = str(info.source_id.zid) if info is not None else None
        if not self._trusted.believe(zid, f"a tile-change notice on {sample.key_expr}"):
            self.ignored += 1
            return
        try:
            msg = decode(sample.payload.to_bytes(), expected_type="tile_changes")
        except ProtocolError as exc:
            self.ignored += 1
            log.warning("ignoring a bad tile_changes on %s: %s", sample.key_expr, exc)
            return
        assert isinstance(msg, TileChanges)
        b = msg.boxes()
        ix0, iy0, ix1, iy1 = self.cells
        hit = (b[:, 0] <= ix1) & (b[:, 2] >= ix0) & (b[:, 1] <= iy1) & (b[:, 3] >= iy0)
        with self._cond:
            self.versions[msg.shard] = max(self.versions.get(msg.shard, -1), msg.version)
            if hit.any():
                self._pending.append(RegionChange(msg.shard, msg.version, np.asarray(msg.tiles)[hit]))
                self._cond.notify_all()

    def changed(self, timeout_s: float = 0.0) -> list[RegionChange]:
        """The changes inside the box since the previous call (waiting up to `timeout_s` for the first)."""
        with self._cond:
            if not self._pending and timeout_s > 0:
                self._cond.wait(timeout_s)
            out, self._pending = self._pending, []
        return out

    def close(self) -> None:
        self._sub.undeclare()
        self._trusted.close()

    def __enter__(self) -> RegionWatch:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RegionFollower:
    """When a box must be queried again: once at the start (as soon as a server answers), on every tile-change
    notice inside it (`RegionWatch`, every shard), and when a status poll every `resync_s` shows a server's
    version beyond what its notices told (a lost notice, or a server that publishes none). Box None: the whole
    map, whose every change counts; query `psrmap_common.query.map_extent(statuses)` then.

        follow = RegionFollower(session, map_id, box)
        while ...:
            if follow.due():
                statuses = follow.statuses()   # before the query: the query then reflects at least these
                grid = query_region(...)
                follow.done(statuses)
            wait(period)
    """

    def __init__(
        self,
        session: zenoh.Session,
        map_id: str,
        box: Box | None,
        resync_s: float = 10.0,
        timeout_s: float = 2.0,
        trusted: Trust | Sequence[str] = (),
    ) -> None:
        if not resync_s > 0:
            raise ValueError(f"resync_s={resync_s}: need a period > 0 seconds")
        self._session, self.map_id, self.box = session, map_id, box
        self.resync_s, self.timeout_s, self.trusted = resync_s, timeout_s, Trust.of(trusted)
        self.watch: RegionWatch | None = None
        self.seen: dict[int | None, int] = {}  # each shard's version the last query reflects
        self.last_changes: list[RegionChange] = []  # the notices behind the current `due`
        self.changes_in_box = 0
        self.resyncs = 0
        self._due = True
        self._next_resync = 0.0

    def statuses(self) -> list[Any]:
        return get_statuses(self._session, self.map_id, self.timeout_s, self.trusted)

    def due(self) -> bool:
        """True when the box should be queried (again); never blocks longer than one status poll."""
        now = time.monotonic()
        if self.watch is None or now >= self._next_resync:
            statuses = self.statuses()
            self._next_resync = now + self.resync_s
            if statuses and self.watch is None:  # the map's res is known now: watch the box from here on
                self.watch = RegionWatch(self._session, self.map_id, statuses[0].res, self.box, self.trusted)
            elif self.watch is not None and any(
                st.version > max(self.seen.get(st.shard, -1), self.watch.versions.get(st.shard, -1))
                for st in statuses
            ):
                self._due = True
                self.resyncs += 1
        if self.watch is not None and (hits := self.watch.changed()):
            self._due = True
            self.changes_in_box += len(hits)
            self.last_changes.extend(hits)
        return self._due and self.watch is not None

    def done(self, statuses: list[Any]) -> None:
        """The box was queried after `statuses` were read: it reflects at least their versions."""
        self.seen = {st.shard: st.version for st in statuses}
        self._due = False
        self.last_changes = []

    def close(self) -> None:
        if self.watch is not None:
            self.watch.close()
            self.watch = None

    def __enter__(self) -> RegionFollower:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
