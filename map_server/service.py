"""The map server on Zenoh (the only module of `map_server` that imports zenoh).

Deltas arrive on `psr/<map>/delta/*` into a bounded `FifoChannel`; one merge worker thread drains it
in batches (validate, deduplicate, merge, commit to SQLite, then ack). Queries (`map`, `status`) are
handed by their callbacks to a query thread. The server holds a liveliness token and tracks scouts'.
"""

from __future__ import annotations

import logging
import queue
import sqlite3
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from typing import IO, Any

import msgpack
import numpy as np
import zenoh

from map_server.errors import MapServerConfigError
from map_server.limits import Limits, default_tile_budget_mib, tile_bytes
from map_server.merge import IngestResult, Merger
from map_server.paging import TilePager
from map_server.removal import RemovalError, hold_lock
from map_server.store import MapStore
from protocol.codec import INDEX_LIMIT, encode
from protocol.errors import ProtocolError
from protocol.keys import (
    ack_key,
    alive_key,
    alive_pattern,
    changes_key,
    delta_key,
    delta_pattern,
    map_key,
    parse_alive_key,
    partition_key,
    server_id_key,
    server_who,
    status_key,
)
from protocol.layers import cell_index
from protocol.messages import MapRegion, RegionQuery, ScoutStatus, Status, TileChanges
from protocol.partition import Partition
from psrmap_common.defaults import DEFAULT_MAP_ID, DEFAULT_RES_M, DEFAULT_TILE
from psrmap_common.session import open_session, zenoh_config
from psrmap_mapcore import TiledMap

__all__ = ["MapService", "ServerConfig"]

log = logging.getLogger(__name__)


class _Stopped(Exception):
    """The service stopped while the worker waited for the store."""


_WAKE = "--wake--"  # scout id of the self-addressed sample that wakes the worker at shutdown
IDLE_STEP_PAUSE_S = 0.002  # pause after a snapshot slice written in an idle gap
FORCED_STEP_S = 0.1  # a snapshot round writes a slice at least this often, even with no idle gap
ACK_PRIORITY = zenoh.Priority.INTERACTIVE_HIGH
QUERY_YIELD_S = 0.2  # a query waits at most this long for a gap between delta batches
SWITCH_INTERVAL_S = 0.0005  # the GIL passes between threads at least this often (Python's default: 5 ms)


@dataclass(frozen=True)
class ServerConfig:
    """map_id, res [m], db: SQLite path (None: memory only), tile [cells], Zenoh endpoints and mode."""

    map_id: str = DEFAULT_MAP_ID
    res: float = DEFAULT_RES_M
    db: str | None = None
    tile: int = DEFAULT_TILE
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    mode: str = "peer"
    channel_capacity: int = 4096  # deltas buffered between the network and the merge worker
    batch_max: int = 128  # deltas merged and committed together at most (bounds the lock hold)
    snapshot_every: int = 20_000  # deltas logged before tiles are snapshotted and the log truncated
    limits: Limits = field(default_factory=Limits)  # resource limits (map_server/limits.py)
    zenoh_config: str | None = None  # Zenoh config file with the server's credentials (psrmap secure init)
    insecure: bool = False  # allow listening on a non-loopback endpoint without credentials
    rrd: str | None = None  # Rerun recording path; None: no visualisation
    # Zenoh shared memory: off, because the server would map a 16 MiB pool of every publisher that
    # ever sent a payload above 3 KiB (a delta is ~5 KiB) and keep it resident; over loopback TCP a
    # delta costs a copy of 5 KiB instead
    shared_memory: bool = False
    checkpoint_s: float = 0.05  # WAL checkpoint period of the background checkpointer (short: it keeps up)
    # after the first delta of a batch, wait this long once for more when fewer than batch_max/4 are queued
    # (Kafka's linger.ms): bounded added latency, fewer and larger commits under a steady trickle
    linger_s: float = 0.002
    # sharded map (protocol.partition): this server is shard `shard` of `shards`; it subscribes only its own
    # delta key, rejects cells of other shards (`wrong_shard`) and answers queries for the cells it owns
    shards: int = 1
    shard: int | None = None
    changes: bool = True  # publish the tiles each committed batch changed (TileChanges, psr/<map>/changes/…)
    # a map bigger than memory: keep at most this many MiB of tiles in memory, the rest in the store (db).
    # None: `limits.default_tile_budget_mib()` (sized for the machine); 0: no budget (whole map in memory, bounded
    # by limits.max_tiles only). Without a db the budget caps max_tiles (nowhere to page to).
    tile_budget_mib: float | None = None
    # the mission area, map frame [m] (x0, y0, x1, y1): a delta with a cell outside is rejected (`outside_bbox`)
    bbox_m: tuple[float, float, float, float] | None = None
    max_queries_in_flight: int = 64  # queries queued or being answered; more get a `busy` reply at once
    query_share: float = 0.25  # while deltas flow, the query worker answers at most this share of the time
    # keep every accepted delta in the store (a snapshot only moves the replay cut): `psrmap remove` recomputes
    # a scout's removal from them; False (--discard-deltas): the log is deleted as snapshots cover it
    keep_deltas: bool = True

    def __post_init__(self) -> None:
        part = Partition(self.shards, self.tile)  # ProtocolError naming what is valid
        if self.shards > 1:
            if self.shard is None:
                raise ValueError(f"shards={self.shards}: give this server's shard, 0..{self.shards - 1}")
            part.check_shard(self.shard)
        elif self.shard not in (None, 0):
            raise ValueError(f"shard={self.shard} of an unsharded map (shards=1): give shards=K > 1 too")
        if not 0.0 <= self.linger_s <= 0.1:
            raise ValueError(f"linger_s={self.linger_s}: need 0 (no wait) to 0.1 s")
        if self.tile_budget_mib is not None and not self.tile_budget_mib >= 0:
            raise ValueError(f"tile_budget_mib={self.tile_budget_mib}: need >= 0 MiB (0: no budget)")
        if self.bbox_m is not None:
            x0, y0, x1, y1 = self.bbox_m
            if not (x0 <= x1 and y0 <= y1) or not all(abs(v) <= INDEX_LIMIT * self.res for v in self.bbox_m):
                raise ValueError(
                    f"bbox {self.bbox_m}: need x0 <= x1, y0 <= y1 [m], within ±{INDEX_LIMIT * self.res:.4g} m"
                )
        if not 0.0 < self.query_share <= 1.0:
            raise ValueError(f"query_share={self.query_share}: need a share of time in (0, 1]")
        if self.max_queries_in_flight < 1:
            raise ValueError(f"max_queries_in_flight={self.max_queries_in_flight}: need >= 1")

    @property
    def budget_mib(self) -> float:
        """The tile budget in effect [MiB] (0: none)."""
        return default_tile_budget_mib() if self.tile_budget_mib is None else float(self.tile_budget_mib)

    @property
    def bbox_cells(self) -> tuple[int, int, int, int] | None:
        """`bbox_m` as inclusive cell indices (ix0, iy0, ix1, iy1)."""
        if self.bbox_m is None:
            return None
        x0, y0, x1, y1 = self.bbox_m
        (ix0, iy0), (ix1, iy1) = cell_index(x0, y0, self.res), cell_index(x1, y1, self.res)
        return int(ix0), int(iy0), int(ix1), int(iy1)

    @property
    def partition(self) -> Partition:
        return Partition(self.shards, self.tile)

    @property
    def shard_id(self) -> int | None:
        """None for an unsharded map (contract v1 keys), else the shard index."""
        return self.shard if self.shards > 1 else None


def _drain(
    sub: zenoh.Subscriber[zenoh.handlers.Handler[zenoh.Sample]], batch: list[zenoh.Sample], most: int
) -> None:
    """Append what is already queued on `sub` to `batch`, up to `most` in all (never blocks)."""
    while len(batch) < most:
        nxt = sub.try_recv()
        if nxt is None:
            return
        batch.append(nxt)


class MapService:
    """Runs one map: `start()`, then `stop()` (or use as a context manager)."""

    def __init__(self, config: ServerConfig) -> None:
        self.config = config
        self.map = TiledMap(config.res, config.tile)
        self.newest_t = 0.0  # newest merged sample's scout clock [s] (the recording's sim_time)
        if config.tile_budget_mib and not config.db:
            raise MapServerConfigError(
                "a tile budget needs a database file (--db PATH): the tiles out of memory live there"
            )
        budget = int(config.budget_mib * 2**20)
        limits = config.limits
        if budget and not config.db:  # nowhere to page to: the budget bounds the map's extent
            per_tile = tile_bytes(config.tile)
            limits = replace(limits, max_tiles=max(1, min(limits.max_tiles, budget // per_tile)))
        self.merger = Merger(
            self.map,
            config.map_id,
            limits=limits,
            partition=config.partition,
            shard=config.shard_id,
            bbox=config.bbox_cells,
        )
        self._db_lock: IO[str] | None = None
        if config.db and config.db != ":memory:":
            try:
                self._db_lock = hold_lock(config.db)  # `psrmap remove` refuses while a server holds it
            except RemovalError as exc:
                raise MapServerConfigError(str(exc)) from None
        self.store = (
            MapStore(
                config.db,
                config.map_id,
                config.res,
                config.tile,
                auto_checkpoint=False,
                keep_deltas=config.keep_deltas,
            )
            if config.db
            else None
        )
        self.replayed = self.store.load(self.merger) if self.store else 0
        self.pager: TilePager | None = None
        if budget and self.store is not None and self.store.path != ":memory:":
            # (after load: the map replays whole, then sheds cold tiles)
            self.pager = TilePager(self.store, budget)
            self._set_map(self.pager.evict(self.map))
        self.lock = threading.Lock()  # guards map + book between the worker and the query thread
        self.alive: dict[str, bool] = {}
        self.ready = threading.Event()
        self.failed = threading.Event()  # the merge worker stopped on an unexpected error
        self.worker_state = "ok"
        self.worker_error: str | None = None
        self._stopping = threading.Event()
        # admission: at most max_queries_in_flight queries queued or being answered; the rest are answered
        # `busy` at once in Zenoh's callback (which never blocks: a blocked callback would hold up deltas)
        self._queries: queue.Queue[Any] = queue.Queue()
        self._query_slots = threading.BoundedSemaphore(config.max_queries_in_flight)
        # set while the merge worker waits for deltas: the query worker starts a query only then (or after
        # QUERY_YIELD_S), so queries fill the gaps between batches and never hold the GIL/lock against one
        self._merge_idle = threading.Event()
        self._last_batch = 0.0  # monotonic time the merge worker last took a batch
        self.busy_replies = 0
        self._session: Any = None
        self._entities: list[Any] = []
        self._threads: list[threading.Thread] = []
        self._viz: Any = None
        self._changes_pub: Any = None
        self._last_step = 0.0  # monotonic time of the last snapshot slice
        if config.rrd:
            from map_server.viz import MapViz  # lazy: Rerun only with --rrd

            self._viz = MapViz(config.rrd, config.map_id)

    def _set_map(self, tiled: TiledMap) -> None:
        self.map = tiled
        self.merger.map = tiled
        if self.pager is not None:
            self.merger.extra_tiles = len(self.pager.cold)

    @property
    def cells(self) -> int:
        """Cells holding data, in memory or paged out."""
        return self.map.cells + (self.pager.cold_cells if self.pager is not None else 0)

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> MapService:
        """Open the session, declare the subscriber and queryables, start the workers (once)."""
        if self._session is not None:
            return self
        c = self.config
        conf = zenoh_config(
            c.connect, c.listen, None if c.zenoh_config else c.mode, c.zenoh_config, c.insecure
        )
        if not c.shared_memory:
            conf.insert_json5("transport/shared_memory/enabled", "false")
        # Zenoh itself drops a message far over the delta limit before buffering it (a margin for framing)
        conf.insert_json5("transport/link/rx/max_message_size", str(c.limits.max_message_bytes + (1 << 20)))
        self._session = open_session(conf)  # SessionError (a ConnectionError) when it cannot
        # a delta waiting for the GIL behind a query's reply encoding waits one switch interval at most
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        s = self._session
        # first: clients believe this session's replies and notices only once its id is attested (psrmap_common.trust)
        self._entities.append(s.liveliness().declare_token(server_id_key(c.map_id, str(s.info.zid()))))
        self._sub = s.declare_subscriber(
            delta_pattern(c.map_id, c.shard_id), zenoh.handlers.FifoChannel(c.channel_capacity)
        )
        self._changes_pub = s.declare_publisher(changes_key(c.map_id, c.shard_id)) if c.changes else None
        self._entities += [
            self._sub,
            *([self._changes_pub] if self._changes_pub is not None else []),
            s.declare_queryable(map_key(c.map_id), self._admit),
            s.declare_queryable(status_key(c.map_id), self._admit),
            s.declare_queryable(partition_key(c.map_id), self._admit),
            s.liveliness().declare_subscriber(alive_pattern(c.map_id), self._on_alive, history=True),
        ]
        self._threads = [
            threading.Thread(target=self._merge_loop, name="merge-worker", daemon=True),
            threading.Thread(target=self._query_loop, name="query-worker", daemon=True),
        ]
        if self.store is not None:
            self._threads.append(
                threading.Thread(target=self._checkpoint_loop, name="checkpoint", daemon=True)
            )
        for t in self._threads:
            t.start()
        self._entities.append(s.liveliness().declare_token(alive_key(c.map_id, server_who(c.shard_id))))
        self.ready.set()
        log.info(
            "map %s (res %.3f m) up; %d cells, %d deltas replayed",
            c.map_id,
            c.res,
            self.map.cells,
            self.replayed,
        )
        return self

    def stop(self) -> None:
        """Drain, snapshot, close Zenoh entities and the session; idempotent."""
        if self._stopping.is_set():
            return
        self._stopping.set()
        if self._session is not None:
            self._session.put(delta_key(self.config.map_id, _WAKE, self.config.shard_id), b"")
            self._queries.put(None)
            for t in self._threads:
                t.join(timeout=10)
            for e in reversed(self._entities):
                try:
                    e.undeclare()
                except Exception as exc:  # already gone with a closing session
                    log.debug("undeclare: %s", exc)
            self._session.close()
            self._session = None
        if self.store is not None:
            with self.lock:
                self.store.snapshot(self.map)
            if self.pager is not None:
                self.pager.close()
            self.store.close()
        if self._db_lock is not None:
            self._db_lock.close()
            self._db_lock = None
        if self._viz is not None:
            self._viz.log_tiles(self.map, set(), self.lock, self.merger.book.version, force=True)
            self._viz.close()

    def __enter__(self) -> MapService:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ merge worker

    def _merge_loop(self) -> None:
        sub = self._sub
        c = self.config
        store = self.store
        while not self._stopping.is_set():
            if store is not None and store.snapshotting:
                first = sub.try_recv()  # snapshot slices fill the gaps between batches
                if first is None:
                    self._snapshot_step()
                    time.sleep(IDLE_STEP_PAUSE_S)  # leave the GIL to queries between slices
                    continue
            else:
                self._merge_idle.set()  # queries may run while the worker waits for deltas
                try:
                    first = sub.recv()
                except zenoh.ZError:
                    break
            self._merge_idle.clear()
            self._last_batch = time.monotonic()
            batch = [first]
            _drain(sub, batch, c.batch_max)
            if c.linger_s > 0 and len(batch) < c.batch_max // 4:
                # few queued: wait once for more, so one commit, one WAL append and one ack per scout
                # cover several deltas (each commit rewrites the same index and counter pages)
                time.sleep(c.linger_s)
                _drain(sub, batch, c.batch_max)
            samples = self._take(batch)
            if samples and not self._process_or_fail(samples):
                return
        # drain what is left so nothing is merged half-way at shutdown
        rest = []
        while (nxt := sub.try_recv()) is not None:
            key = str(nxt.key_expr)
            if not key.endswith("/" + _WAKE):
                rest.append((key, nxt.payload.to_bytes()))
        if rest:
            self._process(rest)

    def _take(self, batch: list[Any]) -> list[tuple[str, bytes]]:
        """(key, payload) of each sample, the size checked before the payload is copied out of Zenoh."""
        out, limit = [], self.config.limits.max_message_bytes
        for s in batch:
            key = str(s.key_expr)
            if key.endswith("/" + _WAKE):
                continue
            size = len(s.payload)
            if size > limit:
                with self.lock:
                    self.merger.book.rejected["oversize"] += 1
                log.warning(
                    "rejected delta on %s: oversize: %d bytes; limit max_message_bytes=%d", key, size, limit
                )
                continue
            out.append((key, s.payload.to_bytes()))
        return out

    def _process_or_fail(self, samples: list[tuple[str, bytes]]) -> bool:
        """Process a batch; on an unexpected error (a bug: the map may be half-merged) log it, count it, mark
        the worker failed in `status` and stop the worker (`failed` is set: the CLI exits non-zero, so a
        supervisor restarts the server from its store). False when the worker must stop."""
        try:
            self._process(samples)
            return True
        except Exception as exc:
            log.exception(
                "merge worker failed on a batch of %d deltas; nothing of it was acked", len(samples)
            )
            reason = f"internal_{type(exc).__name__}"
            with self.lock:
                self.merger.book.rejected[reason] += len(samples)
            self.worker_state, self.worker_error = "failed", f"{type(exc).__name__}: {exc}"
            self.failed.set()
            return False

    def _commit_until_durable(self, res: IngestResult, first_error: Exception) -> None:
        """The store refused a commit (disk full, I/O error): keep the batch (merged in memory, not acked),
        report the original error in `status`, retry with backoff until the store takes it, then go on."""
        assert self.store is not None
        self.worker_state = "waiting_for_store"
        log.error("store commit failed: %s; retrying (no acks until it is durable)", first_error)
        wait = 0.05
        while not self._stopping.wait(wait):
            try:
                with self.lock:
                    self.store.commit(res.accepted, self.merger.book, res.touched)
            except sqlite3.Error as exc:
                wait = min(2.0, wait * 2)
                log.debug("store still refuses the commit: %s", exc)
                continue
            log.info("store accepts writes again; the held batch is durable")
            self.worker_state = "ok"
            return
        raise _Stopped

    def _process(self, samples: list[tuple[str, bytes]]) -> None:
        batch = self.merger.decode(samples)  # validation needs no lock: queries go on meanwhile
        # merge + commit under the lock: a query sees a delta only once it is durable
        store_error: Exception | None = None
        with self.lock:
            keys: list[tuple[int, int]] = []
            if self.pager is not None:  # the batch's tiles in memory first (exact merge, exact tile limits)
                for c in batch.columns.values():
                    keys.extend(TilePager.tiles_of(self.map, c.ix, c.iy))
                keys = sorted(set(keys))
                self.pager.page_in(self.map, keys)
                self.merger.extra_tiles = len(self.pager.cold)
            res = self.merger.apply(samples, batch)
            if self.store is not None and (res.accepted or res.rejected or res.duplicates):
                try:
                    self.store.commit(res.accepted, self.merger.book, res.touched)
                except sqlite3.Error as exc:
                    store_error = exc
            touched = (
                self.map.take_touched() if self._viz is not None or self._changes_pub is not None else set()
            )
            version = self.merger.book.version
            if self.pager is not None and store_error is None:  # durable: the map may shed cold tiles now
                # (the batch's own tiles too: the budget holds between batches; during one, its tiles are in)
                self._set_map(self.pager.evict(self.map))
        if res.accepted:
            self.newest_t = max(self.newest_t, *(a.delta.t for a in res.accepted))
        if store_error is not None:
            try:
                self._commit_until_durable(res, store_error)
            except _Stopped:
                return  # stopping with the batch not durable: no acks, the scouts resend it
        shard = self.config.shard_id
        for ack in res.acks.values():
            # above the priority of query replies (a reply has its query's, DATA by default): an ack never queues
            # behind megabytes of region replies on the server's link (Zenoh keeps a transmission queue per priority)
            self._session.put(
                ack_key(ack.map, ack.scout, shard), encode(ack), priority=ACK_PRIORITY, express=True
            )
        if self._changes_pub is not None and touched:
            self._publish_changes(touched, version)
        store = self.store
        if store is not None:
            # only this thread changes the map, so snapshot slices read it without the lock (queries
            # go on); a slice of a few MiB at a time, never the whole map in one stall
            if not store.snapshotting and store.since_snapshot >= self.config.snapshot_every:
                store.begin_snapshot(self.map)
                self._last_step = time.monotonic()
            elif (
                store.snapshotting
                and store.since_snapshot >= 2 * self.config.snapshot_every
                and time.monotonic() - self._last_step > FORCED_STEP_S
            ):
                # slices normally fill idle gaps between batches; a server busy without gaps long
                # enough for its log to double still progresses at one slice per FORCED_STEP_S
                self._snapshot_step()
        if self._viz is not None and touched:
            self._viz.log_tiles(self.map, touched, self.lock, version, self.newest_t)

    def _publish_changes(self, touched: set[tuple[str, int, int]], version: int) -> None:
        """Tell watchers which tiles this batch changed (once it is durable: after the commit above)."""
        tiles = np.array(sorted({(tx, ty) for _, tx, ty in touched}), np.int32).reshape(-1, 2)
        c = self.config
        msg = TileChanges(c.map_id, c.shard_id, version, self.map.res, self.map.tile, tiles)
        try:
            # the sender's id travels with the notice: watchers ignore notices from ids that are not servers
            self._changes_pub.put(encode(msg), source_info=zenoh.SourceInfo(self._changes_pub.id, version))
        except zenoh.ZError as exc:  # a notification is advisory: never let it stop the merge worker
            log.warning("could not publish tile changes: %s", exc)

    def _snapshot_step(self) -> None:
        assert self.store is not None
        self._last_step = time.monotonic()
        self.store.snapshot_step(self.map)

    def _checkpoint_loop(self) -> None:
        assert self.store is not None
        while not self._stopping.wait(self.config.checkpoint_s):
            try:
                self.store.checkpoint()
            except Exception as exc:  # e.g. busy: the next period retries
                log.debug("checkpoint: %s", exc)

    # ------------------------------------------------------------------ queries

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            _, who = parse_alive_key(str(sample.key_expr))
        except ProtocolError:
            return
        if who != "server":
            self.alive[who] = sample.kind == zenoh.SampleKind.PUT

    def _admit(self, query: zenoh.Query) -> None:
        """Zenoh's query callback: queue the query for the query worker, or answer `busy` when
        max_queries_in_flight are already queued or being answered (never blocks)."""
        if self._query_slots.acquire(blocking=False):
            self._queries.put(query)
            return
        self.busy_replies += 1
        with query:
            try:
                query.reply_err(
                    f"busy: {self.config.max_queries_in_flight} queries in flight (limit "
                    "max_queries_in_flight; deltas are served first): retry later".encode()
                )
            except zenoh.ZError as exc:
                log.debug("busy reply: %s", exc)

    def _query_loop(self) -> None:
        while True:
            query = self._queries.get()
            if query is None:
                break
            self._merge_idle.wait(QUERY_YIELD_S)
            t0 = time.monotonic()
            try:
                self._answer(query)
            finally:
                self._query_slots.release()
            # while deltas flow, queries take at most query_share of the time (the router, the network and
            # this process's CPU are the scouts' first); an idle map answers queries back to back
            if time.monotonic() - self._last_batch < 1.0:
                spent = time.monotonic() - t0
                self._stopping.wait(min(0.1, spent * (1.0 / self.config.query_share - 1.0)))

    def _answer(self, query: zenoh.Query) -> None:
        with query:
            try:
                key = str(query.key_expr)
                if key == status_key(self.config.map_id):
                    query.reply(key, encode(self.status()))
                elif key == partition_key(self.config.map_id):
                    query.reply(key, msgpack.packb(self.config.partition.to_dict()))
                else:
                    rq = RegionQuery.parse(str(query.parameters))
                    query.reply(key, encode(self.region(rq)))
            except ProtocolError as exc:
                query.reply_err(f"{exc.reason}: {exc.detail}".encode())
            except Exception as exc:  # a bad query must never kill the server
                log.exception("query failed")
                query.reply_err(f"internal: {exc}".encode())

    def _reply_arrays(self, rq: RegionQuery) -> int:
        """How many (h, w) float64 arrays a reply to `rq` holds (an upper bound)."""
        total = 0
        for name in rq.layers if rq.layers is not None else tuple(self.map.grids):
            grid = self.map.grids.get(name)
            if grid is None:
                continue
            stats = grid.layer.stats
            total += sum(len(stats) if s == "all" else 1 for s in rq.stats)
        return total

    def health(self) -> dict[str, Any]:
        """The merge worker's state (`ok`, `waiting_for_store`, `failed`) and error, and the store's health."""
        out: dict[str, Any] = {"worker": self.worker_state, "worker_error": self.worker_error}
        if self.store is not None:
            out.update(self.store.health())
        else:
            out["store"] = "none"
        return out

    def status(self) -> Status:
        health = self.health()
        with self.lock:
            book = self.merger.book
            scouts = {
                s: ScoutStatus(epoch, hw, self.alive.get(s, False))
                for s, (epoch, hw) in book.latest().items()
            }
            for s, up in self.alive.items():
                scouts.setdefault(s, ScoutStatus(0, -1, up))
            return Status(
                self.config.map_id,
                self.map.res,
                book.version,
                self.cells,
                book.merged,
                book.duplicates,
                dict(book.rejected),
                scouts,
                health,
                self.newest_t,
                self.config.shard_id,
                self.config.shards,
                self._bounds(),
            )

    def _bounds(self) -> tuple[int, int, int, int] | None:
        """The inclusive cell box of the cells holding data: the hot map's cells exactly, paged-out tiles whole
        (their occupancy is in the store only). Called under the lock."""
        boxes = [b] if (b := self.map.bounds()) is not None else []
        if self.pager is not None and self.pager.cold:
            t = self.map.tile
            keys = np.asarray(list(self.pager.cold), dtype=np.int64)
            lo, hi = keys.min(axis=0) * t, keys.max(axis=0) * t + t - 1
            boxes.append((int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1])))
        if not boxes:
            return None
        a = np.asarray(boxes, dtype=np.int64)
        return int(a[:, 0].min()), int(a[:, 1].min()), int(a[:, 2].max()), int(a[:, 3].max())

    def region(self, rq: RegionQuery) -> MapRegion:
        res, lim = self.map.res, self.config.limits
        reach = INDEX_LIMIT * res  # the contract's index range, in metres
        for name, v in (("x0", rq.x0), ("y0", rq.y0), ("x1", rq.x1), ("y1", rq.y1)):
            if not -reach <= v <= reach:
                raise ProtocolError(
                    "bad_value",
                    f"{name}={v:g} m is outside the map's index range (±2^30 cells = ±{reach:.4g} m)",
                )
        ix0, iy0 = (int(v) for v in cell_index(rq.x0, rq.y0, res))
        ix1, iy1 = (int(v) for v in cell_index(rq.x1, rq.y1, res))
        cells = (ix1 - ix0 + 1) * (iy1 - iy0 + 1)
        if cells > lim.max_query_cells:
            raise ProtocolError(
                "limit_query_cells", f"box covers {cells} cells; limit max_query_cells={lim.max_query_cells}"
            )
        arrays = self._reply_arrays(rq)
        if cells * arrays * 8 > lim.max_reply_bytes:
            raise ProtocolError(
                "limit_reply_bytes",
                f"reply would hold {cells} cells × {arrays} arrays × 8 B = {cells * arrays * 8} bytes; limit "
                f"max_reply_bytes={lim.max_reply_bytes} (ask for fewer layers/stats or a smaller box)",
            )
        with self.lock:
            if self.pager is not None:
                layers = self.pager.region(self.map, ix0, iy0, ix1, iy1, rq.layers, rq.stats)
            else:
                layers = self.map.region(ix0, iy0, ix1, iy1, rq.layers, rq.stats)
            version = self.merger.book.version
        return MapRegion(self.config.map_id, res, ix0, iy0, ix1 - ix0 + 1, iy1 - iy0 + 1, version, layers)
