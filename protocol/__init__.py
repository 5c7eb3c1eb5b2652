"""protocol: the msgpack wire contract v1 shared by scouts, map servers and planners."""

from __future__ import annotations

from protocol.codec import DEFAULT_MAX_BYTES, INDEX_LIMIT, decode, encode
from protocol.errors import REASONS, ProtocolError
from protocol.keys import (
    ack_key,
    alive_key,
    alive_pattern,
    delta_key,
    delta_pattern,
    map_key,
    parse_delta_key,
    status_key,
    validate_id,
)
from protocol.layers import (
    LAYERS,
    Layer,
    cell_center,
    cell_index,
    elevation_slope_deg,
    layer_derived,
    layer_value,
    merge_op,
    plane_fit,
)
from protocol.messages import VERSION, Ack, CellDelta, MapRegion, RegionQuery, ScoutStatus, Status
from protocol.publisher import DeltaPublisher, InMemoryTransport, Transport, UnackedBufferFull
from protocol.session import zenoh_config

__all__ = [
    "DEFAULT_MAX_BYTES",
    "INDEX_LIMIT",
    "LAYERS",
    "REASONS",
    "VERSION",
    "Ack",
    "CellDelta",
    "DeltaPublisher",
    "InMemoryTransport",
    "Layer",
    "MapRegion",
    "ProtocolError",
    "RegionQuery",
    "ScoutStatus",
    "Status",
    "Transport",
    "UnackedBufferFull",
    "ack_key",
    "alive_key",
    "alive_pattern",
    "cell_center",
    "cell_index",
    "decode",
    "delta_key",
    "delta_pattern",
    "elevation_slope_deg",
    "encode",
    "layer_derived",
    "layer_value",
    "map_key",
    "merge_op",
    "plane_fit",
    "parse_delta_key",
    "status_key",
    "validate_id",
    "zenoh_config",
]
