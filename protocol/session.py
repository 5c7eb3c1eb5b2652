"""Every process builds its Zenoh configuration here: explicit endpoints, multicast scouting off."""

from __future__ import annotations

import json
from collections.abc import Sequence

__all__ = ["MODES", "zenoh_config"]

MODES = ("peer", "client", "router")


def zenoh_config(connect: Sequence[str] = (), listen: Sequence[str] = (), mode: str = "peer"):
    """A `zenoh.Config` for `mode` with the given endpoints (e.g. `tcp/127.0.0.1:7447`)."""
    import zenoh

    if mode not in MODES:
        raise ValueError(f"mode {mode!r}; modes: {', '.join(MODES)}")
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return conf
