"""The one root exception of `protocol`: a message or query that breaks wire contract v1."""

from __future__ import annotations

__all__ = ["REASONS", "ProtocolError"]

# Every reason a message can be rejected for; the server counts rejections by these keys in `status`.
DEFAULT_MAX_BYTES = 8 * 1024 * 1024  # a message larger than this is rejected (`oversize`) before decoding
MAX_CLIENT_CELLS = 1 << 24  # cells a client allocates for one (stitched) map reply at most: 128 MiB an array

REASONS: tuple[str, ...] = (
    "decode",  # not msgpack, or not a map with string keys
    "oversize",  # payload longer than the configured maximum
    "bad_version",  # `v` is not a supported schema version
    "bad_type",  # `type` unknown, or not the type expected on this key
    "missing_field",  # a required field (or a layer's statistic) is absent
    "wrong_type",  # a field has the wrong Python/msgpack type
    "bad_id",  # a map / scout id outside [A-Za-z0-9_-]+
    "bad_value",  # a scalar out of its domain (negative seq, res <= 0, non-finite t, ...)
    "key_mismatch",  # `map` / `scout` disagree with the key expression the message arrived on
    "wrong_res",  # `res` differs from the map's resolution
    "unknown_layer",  # a layer name not in protocol.layers.LAYERS
    "unknown_stat",  # a statistic the layer does not define
    "bad_length",  # a byte array whose length is not a multiple of its dtype size
    "length_mismatch",  # arrays of one layer (or of a region) have different lengths
    "nonfinite",  # NaN or inf in a statistic
    "negative_count",  # a count-like statistic below zero
    "stat_range",  # a statistic beyond ±1e30 (protocol.consistency.MAX_STAT: stored sums stay finite)
    "inconsistent",  # statistics no set of samples has (variance < 0, min > max, impossible plane moments)
    "index_range",  # a cell index beyond +-2**30
    "duplicate_cell",  # a cell appears twice in one layer of one delta
    "seq_conflict",  # a (scout, epoch, seq) already merged with other content
    "duplicate_name",  # a query names a layer or stat twice
    "limit_cells",  # a delta with more cells than the server's max_cells_per_delta
    "limit_new_tiles",  # a delta that would create more tiles than max_new_tiles_per_delta
    "limit_tiles",  # a delta that would grow the map beyond max_tiles (its extent budget)
    "limit_query_cells",  # a query box of more cells than max_query_cells
    "limit_reply_bytes",  # a reply that would exceed max_reply_bytes
    "wrong_shard",  # a delta with a cell another shard of a sharded map owns (protocol.partition)
    "limit_scout_tiles",  # a delta that would make its scout the creator of more than max_tiles_per_scout tiles
    "limit_scout_tile_rate",  # a scout creating new tiles faster than its rate (max_new_tiles_per_scout_minute)
    "outside_bbox",  # a delta with a cell outside the server's mission bounding box (--bbox)
    "busy",  # the server's query budget is full (queries in flight); retry later — deltas are never delayed
)


class ProtocolError(ValueError):
    """A message, key or query violates the wire contract.

    `reason` is a short snake_case key from `REASONS` (counted in the server's status);
    the message says which field was wrong and what would have been valid.
    """

    def __init__(self, reason: str, message: str) -> None:
        if reason not in REASONS:
            raise ValueError(f"unknown ProtocolError reason {reason!r}; reasons: {', '.join(REASONS)}")
        super().__init__(f"{reason}: {message}")
        self.reason = reason
        self.detail = message
