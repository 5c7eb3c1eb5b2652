"""The planner's only Zenoh module: region queries of the `map` queryable, fanned out to every shard.

`get(psr/<map>/map?x0=..;y0=..;x1=..;y1=..;stats=all)` goes out through `common.query` with
`fan_out=True` (target ALL, no consolidation), so every map-server shard that owns part of the box
answers; the replies are decoded with `protocol.codec.decode` (validated) and stitched into one
`LayerGrid` (`mapcore.stitch`). Raw stats
(`all`) are asked for so the planner recomputes values and the elevation plane-fit slope itself.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import zenoh

from common.query import get_replies
from common.session import zenoh_config
from consumer_planner.errors import PlannerError
from mapcore import LayerGrid, MapCoreError, stitch
from protocol.codec import decode
from protocol.errors import ProtocolError
from protocol.keys import map_key, status_key
from protocol.messages import MapRegion, RegionQuery, Status

__all__ = ["ClientConfig", "MapClient", "query_region", "trusted_servers"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClientConfig:
    connect: tuple[str, ...] = ("tcp/127.0.0.1:7447",)  # router or server endpoints
    mode: str = "client"
    timeout_s: float = 5.0  # how long to wait for the shards' replies
    max_bytes: int = 256 * 1024 * 1024  # largest map_region reply accepted
    x0: float = 0.0  # map origin [m]
    y0: float = 0.0
    zenoh_config: str | None = None  # Zenoh config file with the planner's credentials
    trusted_servers: tuple[str, ...] = ()  # Zenoh ids of the map servers to believe (empty: any)


def trusted_servers(path: str | None, required: bool = False) -> tuple[str, ...]:
    """Server Zenoh ids from a `servers.json` written by `psrmap secure init` ({name: zid}); () without one."""
    import json
    from pathlib import Path

    if path is None or not Path(path).is_file():
        if required:
            raise ValueError(f"--trust-servers {path}: no such file (psrmap secure init writes servers.json)")
        return ()
    try:
        ids = json.loads(Path(path).read_text())
        return tuple(str(v) for v in ids.values())
    except (ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: not a servers.json ({{name: zenoh id}}): {exc}") from None


def query_region(
    session: zenoh.Session,
    map_id: str,
    box: tuple[float, float, float, float],
    config: ClientConfig = ClientConfig(),
    layers: Sequence[str] | None = None,
    stats: Sequence[str] = ("all",),
) -> LayerGrid:
    """The map box (x0, y0, x1, y1) [m, inclusive] from every shard that answers, stitched.

    Raises PlannerError when no server answers within `timeout_s` or every answer is an error."""
    q = RegionQuery(*box, layers=tuple(layers) if layers is not None else None, stats=tuple(stats))
    key = map_key(map_id)
    regions: list[MapRegion] = []
    replies = get_replies(
        session, f"{key}?{q.to_parameters()}", config.timeout_s, fan_out=True, trusted=config.trusted_servers
    )
    errors = replies.errors
    for payload in replies.ok:
        try:
            msg = decode(payload, expected_type="map_region", max_bytes=config.max_bytes)
        except ProtocolError as exc:
            errors.append(f"undecodable reply: {exc}")
            continue
        assert isinstance(msg, MapRegion)
        regions.append(msg)
    if not regions:
        if errors:
            raise PlannerError(f"map servers refused {key!r}: {'; '.join(errors)}")
        raise PlannerError(
            f"no map server answered {key!r} within {config.timeout_s:g} s via "
            f"{', '.join(config.connect) or '(no endpoint)'}; is `psrmap server --map {map_id}` running "
            f"and reachable?"
        )
    try:
        return stitch(regions, config.x0, config.y0)
    except MapCoreError as exc:  # replies that cannot be one map (other map ids or cell sizes)
        raise PlannerError(str(exc)) from None


class MapClient:
    """A Zenoh session for map queries: `with MapClient(cfg) as c: grid = c.region(map_id, box)`."""

    def __init__(self, config: ClientConfig = ClientConfig()) -> None:
        self.config = config
        self._session: zenoh.Session | None = None

    def __enter__(self) -> MapClient:
        try:
            c = self.config
            self._session = zenoh.open(
                zenoh_config(c.connect, (), None if c.zenoh_config else c.mode, c.zenoh_config)
            )
        except (zenoh.ZError, ValueError) as exc:
            raise PlannerError(
                f"cannot open a Zenoh session to {', '.join(self.config.connect)}: {exc}"
            ) from None
        return self

    def __exit__(self, *exc: object) -> None:
        if self._session is not None:
            self._session.close()
            self._session = None

    def region(self, map_id: str, box: tuple[float, float, float, float]) -> LayerGrid:
        if self._session is None:
            raise RuntimeError("MapClient used outside its `with` block")
        return query_region(self._session, map_id, box, self.config)

    def newest_sample_t(self, map_id: str) -> float | None:
        """The newest merged sample's time [s] over every (trusted) server's `status` (mission time:
        where the recording logs a plan made now), None when no server answers."""
        if self._session is None:
            raise RuntimeError("MapClient used outside its `with` block")
        best: float | None = None
        replies = get_replies(
            self._session, status_key(map_id), self.config.timeout_s, fan_out=True,
            trusted=self.config.trusted_servers,
        )  # fmt: skip
        for payload in replies.ok:
            try:
                st = decode(payload, expected_type="status")
            except ProtocolError as exc:
                log.warning("undecodable status reply: %s", exc)
                continue
            assert isinstance(st, Status)
            best = st.t if best is None else max(best, st.t)
        return best
