"""Exactly-once merge bookkeeping: which (scout, epoch, seq) are merged, validation against the map.

`Merger.ingest` takes a batch of raw `(key, payload)` samples, rejects bad ones whole (counted by
reason), drops duplicates, merges the rest into the `TiledMap` in one vectorised pass and says which
acks to send. Nothing here knows about Zenoh or SQLite.

A duplicate is a `(scout, epoch, seq)` already merged *with the same content* (a 64-bit xxh3 digest of its
payload is kept per merged seq); the same seq with other content (e.g. a scout restarted with its old epoch)
is rejected as `seq_conflict` and named in the ack, never silently dropped as a duplicate.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import xxhash

from map_server.decode import DeltaBatch, DeltaDecoder
from map_server.limits import Limits
from protocol.codec import DEFAULT_MAX_BYTES, decode
from protocol.errors import ProtocolError
from protocol.layers import pack_pair, unpack_pair
from protocol.messages import Ack, CellDelta
from protocol.partition import Partition
from psrmap_mapcore import TiledMap

__all__ = ["Accepted", "IngestResult", "MergeBook", "Merger", "SeqState", "payload_digest"]

log = logging.getLogger(__name__)


def payload_digest(payload: bytes) -> int:
    """64-bit digest of a delta's payload (xxh3), never 0 (0 = unknown)."""
    return xxhash.xxh3_64_intdigest(payload) or 1


_DENSE_AHEAD = 1 << 16  # digests of seqs up to this far above hw live in the dense array


@dataclass
class SeqState:
    """Merged seqs of one (scout, epoch): all of 0..hw, plus the out-of-order ones in `above`; the payload
    digest of each merged seq (a dense uint64 array by seq, a dict for seqs far ahead of hw)."""

    hw: int = -1
    above: set[int] = field(default_factory=set)
    dense: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint64))
    sparse: dict[int, int] = field(default_factory=dict)

    def digest(self, seq: int) -> int:
        """The digest merged under `seq` (0: not known)."""
        if seq < self.dense.size:
            return int(self.dense[seq])
        return self.sparse.get(seq, 0)

    def set_digest(self, seq: int, digest: int) -> None:
        if seq < self.dense.size:
            self.dense[seq] = digest
        elif seq <= self.hw + _DENSE_AHEAD:
            grown = np.zeros(max(2 * self.dense.size, seq + 1, 64), np.uint64)
            grown[: self.dense.size] = self.dense
            grown[seq] = digest
            self.dense = grown
            for k in [k for k in self.sparse if k < grown.size]:
                grown[k] = self.sparse.pop(k)
        else:
            self.sparse[seq] = digest

    def seen(self, seq: int) -> bool:
        return seq <= self.hw or seq in self.above

    def mark(self, seq: int) -> None:
        self.above.add(seq)
        while self.hw + 1 in self.above:
            self.hw += 1
            self.above.discard(self.hw)


@dataclass
class MergeBook:
    """Counters and seq states of a map; everything `status` reports and the store persists."""

    seqs: dict[tuple[str, int], SeqState] = field(default_factory=dict)
    version: int = 0  # grows with every merged delta
    merged: int = 0
    duplicates: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    scout_tiles: Counter[str] = field(default_factory=Counter)  # tiles each scout created (its quota's use)

    def latest(self) -> dict[str, tuple[int, int]]:
        """scout -> (newest epoch, its hw)."""
        out: dict[str, tuple[int, int]] = {}
        for (scout, epoch), st in self.seqs.items():
            if scout not in out or epoch > out[scout][0]:
                out[scout] = (epoch, st.hw)
        return out


class Accepted(NamedTuple):
    """A merged delta: its header, its payload (the store logs it) and its digest."""

    delta: CellDelta
    payload: bytes
    digest: int = 0  # `payload_digest(payload)`


@dataclass
class IngestResult:
    accepted: list[Accepted] = field(default_factory=list)
    duplicates: int = 0
    rejected: list[tuple[str, str]] = field(default_factory=list)  # (reason, message)
    acks: dict[tuple[str, int], Ack] = field(default_factory=dict)
    touched: set[tuple[str, int]] = field(default_factory=set)  # seq states changed
    conflicts: dict[tuple[str, int], list[int]] = field(
        default_factory=dict
    )  # seqs merged with other content


class Merger:
    """Validates deltas against the map (id, res, layers, limits) and merges each exactly once."""

    def __init__(
        self,
        tiled: TiledMap,
        map_id: str,
        book: MergeBook | None = None,
        *,
        max_bytes: int = DEFAULT_MAX_BYTES,
        limits: Limits | None = None,
        partition: Partition | None = None,
        shard: int | None = None,
        bbox: tuple[int, int, int, int] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """partition, shard: this merger holds shard `shard` of a sharded map and rejects deltas with cells
        of other shards (`wrong_shard`); None: an unsharded map. bbox: (ix0, iy0, ix1, iy1), the cells a
        delta may touch (inclusive; `outside_bbox` otherwise); None: anywhere. clock [s]: the scouts' tile
        rate buckets refill by it."""
        self.map = tiled
        self.map_id = map_id
        self.extra_tiles = 0  # tiles of the map not in `tiled` (paged out to the store: map_server.paging)
        self.partition = partition if partition is not None and partition.shards > 1 else None
        self.shard = shard if self.partition is not None else None
        if self.partition is not None:
            self.partition.check_shard(shard)  # type: ignore[arg-type]
        self.book = book or MergeBook()
        self.bbox = bbox
        self.clock = clock
        self._buckets: dict[str, tuple[float, float]] = {}  # scout -> (tiles it may still create, at time)
        self.limits = limits or Limits(max_message_bytes=max_bytes)
        self.max_bytes = self.limits.max_message_bytes
        self._decoder = DeltaDecoder(res=tiled.res, max_bytes=self.max_bytes)
        self._replay_decoder = DeltaDecoder(res=tiled.res, max_bytes=2**62)  # the log holds accepted deltas

    def validate(self, key: str, payload: bytes) -> CellDelta:
        """Decode one sample as a delta for this map, or raise ProtocolError."""
        delta = decode(
            payload, expected_type="cell_delta", key=key, res=self.map.res, max_bytes=self.max_bytes
        )
        assert isinstance(delta, CellDelta)
        self._check_map(delta)
        return delta

    def ingest(self, samples: Iterable[tuple[str, bytes]]) -> IngestResult:
        """Validate, deduplicate and merge a batch; returns what happened (acks for every scout touched)."""
        samples = list(samples)
        return self.apply(samples, self.decode(samples))

    def decode(self, samples: list[tuple[str, bytes]]) -> DeltaBatch:
        """The stateless half of `ingest` (decode + validate): needs no lock on the map."""
        return self._decoder.decode(samples)

    def apply(self, samples: list[tuple[str, bytes]], batch: DeltaBatch) -> IngestResult:
        """The half of `ingest` that reads and changes state: dedupe, book-keep, merge `decode(samples)`."""
        res = IngestResult()
        book = self.book
        seqs = book.seqs
        map_id = self.map_id
        unknown = {name for name in batch.columns if name not in self.map.grids}
        no_layer = self._without_layer(batch, unknown) if unknown else {}
        if self.partition is not None:
            no_layer.update(self._foreign(batch, no_layer))
        if self.bbox is not None:
            no_layer.update(self._outside(batch, no_layer))
        no_layer.update(self._over_limits(batch, no_layer))
        take = [False] * len(samples)
        acked: dict[tuple[str, int], CellDelta] = {}
        accepted = res.accepted
        touched = res.touched
        # scout -> (epoch, (scout, epoch), its SeqState): one dict lookup per delta, no key tuple
        memo: dict[str, tuple[int, tuple[str, int], SeqState]] = {}
        xxh3 = xxhash.xxh3_64_intdigest  # payload_digest, inlined: this loop runs once per delta
        for i, delta in enumerate(batch.results):
            if type(delta) is CellDelta and (delta.map != map_id or i in no_layer):
                delta = (
                    ProtocolError(
                        "key_mismatch", f"delta for map {delta.map!r}; this server holds {map_id!r}"
                    )
                    if delta.map != map_id
                    else no_layer[i]
                )
            if type(delta) is not CellDelta:
                assert isinstance(delta, ProtocolError)
                book.rejected[delta.reason] += 1
                res.rejected.append((delta.reason, str(delta)))
                log.warning("rejected delta on %s: %s", samples[i][0], delta)
                continue
            got = memo.get(delta.scout)
            if got is not None and got[0] == delta.epoch:
                sk, st = got[1], got[2]
            else:
                sk = (delta.scout, delta.epoch)
                st = seqs.get(sk)  # type: ignore[assignment]
                if st is None:
                    st = seqs[sk] = SeqState()
                memo[delta.scout] = (delta.epoch, sk, st)
            seq = delta.seq
            payload = samples[i][1]
            dig = xxh3(payload) or 1
            if seq <= st.hw or seq in st.above:
                known = st.digest(seq)
                if known and known != dig:
                    book.rejected["seq_conflict"] += 1
                    msg = (
                        f"seq_conflict: {delta.scout} epoch {delta.epoch} seq {seq} was merged with other "
                        "content; a restarted scout must use a new epoch"
                    )
                    res.rejected.append(("seq_conflict", msg))
                    res.conflicts.setdefault(sk, []).append(seq)
                    touched.add(sk)  # the counters change: persist them with the batch
                    log.warning("rejected delta on %s: %s", samples[i][0], msg)
                else:
                    book.duplicates += 1
                    res.duplicates += 1
            else:
                if seq == st.hw + 1 and not st.above:
                    st.hw = seq
                else:
                    st.mark(seq)
                if seq < st.dense.size:  # set_digest's common case, inlined
                    st.dense[seq] = dig
                else:
                    st.set_digest(seq, dig)
                take[i] = True
                accepted.append(Accepted(delta, payload, dig))
                touched.add(sk)
            acked[sk] = delta
        for sk, delta in acked.items():
            hw = seqs[sk].hw
            conflicts = tuple(res.conflicts.get(sk, ()))
            if hw >= 0 or conflicts:
                res.acks[sk] = Ack(map_id, delta.scout, delta.epoch, hw, conflicts)
        if accepted:
            self._merge_columns(batch, np.array(take, dtype=bool))
            book.merged += len(accepted)
            book.version += len(accepted)
        return res

    def _over_limits(self, batch: DeltaBatch, already: dict[int, ProtocolError]) -> dict[int, ProtocolError]:
        """Deltas of the batch over a resource limit: too many cells, too many new tiles, or tiles beyond the
        map's tile budget (counted in arrival order, so the budget is never exceeded)."""
        lim, n = self.limits, len(batch.results)
        out: dict[int, ProtocolError] = {}
        if not batch.columns:
            return out
        cells = np.zeros(n, np.int64)
        sh = self.map.shift
        segs, tks = [], []
        seen: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        for c in batch.columns.values():
            cells += np.bincount(c.seg, minlength=n)[:n]
            # the layers of a batch usually list the same cells of the same deltas: their tiles once
            if any(s.shape == c.seg.shape and (s == c.seg).all() and (x == c.ix).all() and (y == c.iy).all()
                   for s, x, y in seen):  # fmt: skip
                continue
            seen.append((c.seg, c.ix, c.iy))
            segs.append(c.seg)
            tks.append(pack_pair(c.ix.astype(np.int64) >> sh, c.iy.astype(np.int64) >> sh))
        for i in np.flatnonzero(cells > lim.max_cells_per_delta).tolist():
            out[i] = ProtocolError(
                "limit_cells",
                f"delta has {cells[i]} cells; limit max_cells_per_delta={lim.max_cells_per_delta}",
            )
        tk = np.concatenate(tks)
        known = self.map.gslots
        fresh_keys = {int(k) for k in np.unique(tk).tolist() if unpack_pair(int(k)) not in known}
        if not fresh_keys:  # the common case: every cell lands in a tile the map has
            return out
        fresh = np.isin(tk, np.fromiter(fresh_keys, np.int64, len(fresh_keys)))
        seg_tile = np.unique(
            np.stack([np.concatenate(segs)[fresh], tk[fresh]]), axis=1
        )  # (2, K) (delta, new tile)
        created: set[int] = set()
        now = self.clock()
        for i in np.unique(seg_tile[0]).tolist():
            d = batch.results[i]
            if i in out or i in already or type(d) is not CellDelta:
                continue
            mine = {int(k) for k in seg_tile[1][seg_tile[0] == i].tolist()}
            new = mine - created
            err = self._tile_quota(d.scout, len(new), len(known) + self.extra_tiles + len(created), now)
            if err is not None:
                out[i] = err
            elif new:
                created |= new
                self._charge(d.scout, len(new), now)
        return out

    def _tile_quota(self, scout: str, new: int, tiles: int, now: float) -> ProtocolError | None:
        """Why a delta of `scout` that creates `new` tiles in a map of `tiles` may not, or None."""
        lim = self.limits
        if new > lim.max_new_tiles_per_delta:
            return ProtocolError(
                "limit_new_tiles",
                f"delta would create {new} tiles; limit max_new_tiles_per_delta={lim.max_new_tiles_per_delta}",
            )
        if tiles + new > lim.max_tiles:
            return ProtocolError(
                "limit_tiles",
                f"delta would grow the map to {tiles + new} tiles; limit max_tiles={lim.max_tiles} (the map's "
                "extent budget)",
            )
        had = self.book.scout_tiles[scout]
        if had + new > lim.max_tiles_per_scout:
            return ProtocolError(
                "limit_scout_tiles",
                f"scout {scout} created {had} tiles; {new} more would pass its quota "
                f"max_tiles_per_scout={lim.max_tiles_per_scout} (other scouts' quotas are untouched)",
            )
        left = self._tokens(scout, now)
        if new > left:
            return ProtocolError(
                "limit_scout_tile_rate",
                f"scout {scout} may create {int(left)} more tiles now; {new} asked: limit "
                f"max_new_tiles_per_scout_minute={lim.max_new_tiles_per_scout_minute} (resend later)",
            )
        return None

    def _tokens(self, scout: str, now: float) -> float:
        """Tiles `scout` may create at `now`: its bucket refilled at the per-minute rate, at most a minute's."""
        rate = self.limits.max_new_tiles_per_scout_minute
        left, at = self._buckets.get(scout, (float(rate), now))
        return min(float(rate), left + max(0.0, now - at) * rate / 60.0)

    def _charge(self, scout: str, new: int, now: float) -> None:
        self._buckets[scout] = (self._tokens(scout, now) - new, now)
        self.book.scout_tiles[scout] += new

    def _outside(self, batch: DeltaBatch, already: dict[int, ProtocolError]) -> dict[int, ProtocolError]:
        """Deltas with a cell outside the mission bounding box -> `outside_bbox`."""
        assert self.bbox is not None
        x0, y0, x1, y1 = self.bbox
        out: dict[int, ProtocolError] = {}
        for c in batch.columns.values():
            bad = (c.ix < x0) | (c.ix > x1) | (c.iy < y0) | (c.iy > y1)
            if not bad.any():
                continue
            for i in np.unique(c.seg[bad]).tolist():
                if i not in out and i not in already:
                    k = int(np.flatnonzero((c.seg == i) & bad)[0])
                    out[int(i)] = ProtocolError(
                        "outside_bbox",
                        f"cell ({int(c.ix[k])}, {int(c.iy[k])}) of layer {c.layer.name} is outside the mission "
                        f"bounding box, cells x {x0}..{x1}, y {y0}..{y1} (psrmap server --bbox)",
                    )
        return out

    def _foreign(self, batch: DeltaBatch, already: dict[int, ProtocolError]) -> dict[int, ProtocolError]:
        """Deltas with a cell another shard owns -> `wrong_shard` (nothing of them is merged)."""
        part, me = self.partition, self.shard
        assert part is not None
        out: dict[int, ProtocolError] = {}
        for c in batch.columns.values():
            sh = part.shard_of(c.ix, c.iy)
            bad = sh != me
            if not bad.any():
                continue
            for i in np.unique(c.seg[bad]).tolist():
                if i in out or i in already:
                    continue
                others = sorted(set(np.unique(sh[(c.seg == i) & bad]).tolist()))
                out[int(i)] = ProtocolError(
                    "wrong_shard",
                    f"delta has cells of shard(s) {others}; this server is shard {me} of {part.shards} "
                    f"(partition {part.scheme}, tile {part.tile}): send each shard only its cells "
                    "(protocol.partition.Partition.split)",
                )
        return out

    def _without_layer(self, batch: DeltaBatch, unknown: set[str]) -> dict[int, ProtocolError]:
        """Deltas carrying a layer this map lacks -> their `unknown_layer` error (first such layer)."""
        out: dict[int, ProtocolError] = {}
        for name in sorted(unknown):
            err = ProtocolError(
                "unknown_layer", f"map has no layer {name!r}; layers: {', '.join(self.map.grids)}"
            )
            for i in np.unique(batch.columns[name].seg).tolist():
                out.setdefault(int(i), err)
            del batch.columns[name]
        return out

    def _check_map(self, delta: CellDelta) -> None:
        if delta.map != self.map_id:
            raise ProtocolError(
                "key_mismatch", f"delta for map {delta.map!r}; this server holds {self.map_id!r}"
            )
        for name in delta.layers:
            if name not in self.map.grids:
                raise ProtocolError(
                    "unknown_layer", f"map has no layer {name!r}; layers: {', '.join(self.map.grids)}"
                )

    def _merge_columns(self, batch: DeltaBatch, take: np.ndarray) -> None:
        everything = bool(take.all())
        for name, c in batch.columns.items():
            if name not in self.map.grids:  # (replay) a layer this map lacks: never accepted
                continue
            if everything:
                self.map.merge_columns(name, c.ix, c.iy, c.vals)
            else:
                keep = take[c.seg]
                if keep.any():
                    self.map.merge_columns(name, c.ix[keep], c.iy[keep], c.vals[:, keep])

    def replay(
        self,
        payloads: Iterable[bytes | tuple[int, bytes]],
        upto: dict[tuple[str, int, int], int] | None = None,
    ) -> int:
        """Merge already-accepted payloads (from the store's log) without touching bookkeeping.

        Items are payloads or `(log id, payload)`; with ids, a delta's cells skip the tiles whose
        `upto[(layer, tx, ty)]` >= its id (those tiles were stored with it already merged).
        """
        n = 0
        chunk: list[tuple[str | None, bytes]] = []
        ids: list[int] = []
        for p in payloads:
            if isinstance(p, tuple):
                ids.append(p[0])
                p = p[1]
            chunk.append((None, p))
            if len(chunk) == 512:
                n += self._replay_chunk(chunk, ids, upto)
                chunk, ids = [], []
        if chunk:
            n += self._replay_chunk(chunk, ids, upto)
        return n

    def _replay_chunk(
        self,
        chunk: list[tuple[str | None, bytes]],
        ids: list[int],
        upto: dict[tuple[str, int, int], int] | None,
    ) -> int:
        batch = self._replay_decoder.decode(chunk)
        take = np.array([isinstance(r, CellDelta) for r in batch.results])
        if upto and ids:
            sh = self.map.shift
            id_of = np.array(ids, dtype=np.int64)
            for name, c in list(batch.columns.items()):
                if not c.seg.size:
                    continue
                tkey = pack_pair(c.ix.astype(np.int64) >> sh, c.iy.astype(np.int64) >> sh)
                uniq, inv = np.unique(tkey, return_inverse=True)
                lim = np.array(
                    [upto.get((name, *unpack_pair(k)), 0) for k in uniq.tolist()],
                    dtype=np.int64,
                )
                keep = id_of[c.seg] > lim[inv.reshape(-1)]
                if not keep.all():
                    batch.columns[name] = c.subset(keep)
        self._merge_columns(batch, take)
        return int(take.sum())
