"""protocol: the msgpack wire contract v1 shared by scouts, map servers and planners, and nothing else.

Keys (`keys`), messages (`messages`), their codec (`codec`), the layers and their merge rule (`layers`),
errors and rejection reasons (`errors`), and builders of valid and broken messages for tests
(`testing`). It imports no Zenoh, no Rerun and no service: the services import it, never each other.
"""

from __future__ import annotations

import importlib
from typing import Any

# name -> the module defining it; imported on first use (PEP 562), so `import protocol.keys` (or the CLI's
# start-up) does not pay for numpy and msgpack
_EXPORTS: dict[str, str] = {
    "DEFAULT_MAX_BYTES": "protocol.errors",
    "INDEX_LIMIT": "protocol.codec",
    "decode": "protocol.codec",
    "encode": "protocol.codec",
    "REASONS": "protocol.errors",
    "ProtocolError": "protocol.errors",
    "ack_key": "protocol.keys",
    "alive_key": "protocol.keys",
    "alive_pattern": "protocol.keys",
    "delta_key": "protocol.keys",
    "delta_pattern": "protocol.keys",
    "map_key": "protocol.keys",
    "parse_delta_key": "protocol.keys",
    "status_key": "protocol.keys",
    "validate_id": "protocol.keys",
    "LAYERS": "protocol.layers",
    "Layer": "protocol.layers",
    "cell_center": "protocol.layers",
    "cell_index": "protocol.layers",
    "elevation_slope_deg": "protocol.layers",
    "layer_derived": "protocol.layers",
    "layer_value": "protocol.layers",
    "merge_op": "protocol.layers",
    "plane_fit": "protocol.layers",
    "VERSION": "protocol.messages",
    "Ack": "protocol.messages",
    "CellDelta": "protocol.messages",
    "MapRegion": "protocol.messages",
    "RegionQuery": "protocol.messages",
    "ScoutStatus": "protocol.messages",
    "Status": "protocol.messages",
}


__all__ = [
    "DEFAULT_MAX_BYTES",
    "INDEX_LIMIT",
    "LAYERS",
    "REASONS",
    "VERSION",
    "Ack",
    "CellDelta",
    "Layer",
    "MapRegion",
    "ProtocolError",
    "RegionQuery",
    "ScoutStatus",
    "Status",
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
]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'protocol' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
