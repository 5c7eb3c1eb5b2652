"""The planner's only Zenoh module: region queries of the `map` queryable, fanned out to every shard, and
region change notifications (`RegionWatch`) and when to re-query a box because of them (`RegionFollower`) —
the last two and the query itself from `psrmap_common.region`, which the scouts use too.

Raw stats (`all`) are asked for so the planner recomputes values and the elevation plane-fit slope itself.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace

import zenoh

from consumer_planner.errors import PlannerError
from protocol.keys import map_key
from psrmap_common.errors import QueryError
from psrmap_common.query import get_statuses, map_extent
from psrmap_common.region import Box, NoAnswer, RegionChange, RegionFollower, RegionWatch, fetch_region
from psrmap_common.session import SessionError, open_session, zenoh_config
from psrmap_common.trust import Trust, load_trust
from psrmap_mapcore import LayerGrid

__all__ = [
    "ClientConfig",
    "MapClient",
    "RegionChange",
    "RegionFollower",
    "RegionWatch",
    "query_region",
]

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
    trusted_servers: tuple[str, ...] = ()  # Zenoh ids of map servers to believe outright
    trust: Trust | None = None  # whom to believe; None: the servers.json beside zenoh_config, if any

    def believed(self) -> Trust:
        """The trust the client applies (psrmap_common.trust): `trust`, else what the files beside the Zenoh config ask
        for, and the `trusted_servers` ids; PlannerError for an unreadable servers.json."""
        try:
            base = self.trust if self.trust is not None else load_trust(None, self.zenoh_config)
        except ValueError as exc:
            raise PlannerError(str(exc)) from None
        return replace(base, zids=base.zids + self.trusted_servers) if self.trusted_servers else base


def query_region(
    session: zenoh.Session,
    map_id: str,
    box: tuple[float, float, float, float],
    config: ClientConfig = ClientConfig(),
    layers: Sequence[str] | None = None,
    stats: Sequence[str] = ("all",),
) -> LayerGrid:
    """The map box (x0, y0, x1, y1) [m, inclusive] from every shard that answers, stitched
    (`psrmap_common.region.fetch_region`).

    Raises PlannerError when no server answers within `timeout_s` or every answer is an error."""
    try:
        return fetch_region(session, map_id, box, config.timeout_s, trusted=config.believed(), layers=layers,
                            stats=stats, x0=config.x0, y0=config.y0, max_bytes=config.max_bytes)  # fmt: skip
    except NoAnswer:
        raise PlannerError(
            f"no map server answered {map_key(map_id)!r} within {config.timeout_s:g} s via "
            f"{', '.join(config.connect) or '(no endpoint)'}; is `psrmap server --map {map_id}` running "
            f"and reachable?"
        ) from None
    except QueryError as exc:
        raise PlannerError(str(exc)) from None


class MapClient:
    """A Zenoh session for map queries: `with MapClient(cfg) as c: grid = c.region(map_id, box)`."""

    def __init__(self, config: ClientConfig = ClientConfig()) -> None:
        self.config = config
        self._session: zenoh.Session | None = None

    def __enter__(self) -> MapClient:
        try:
            c = self.config
            self._session = open_session(
                zenoh_config(c.connect, (), None if c.zenoh_config else c.mode, c.zenoh_config)
            )
        except (SessionError, ValueError) as exc:  # SessionError: nothing listens, or credentials needed
            raise PlannerError(str(exc)) from None
        return self

    def __exit__(self, *exc: object) -> None:
        if self._session is not None:
            self._session.close()
            self._session = None

    @property
    def session(self) -> zenoh.Session | None:
        """The open session (inside the `with` block), e.g. for a `RegionFollower` on the same connection."""
        return self._session

    def region(self, map_id: str, box: Box | None = None) -> LayerGrid:
        """The map box (x0, y0, x1, y1) [m, inclusive]; None: the whole map (`extent`)."""
        if self._session is None:
            raise RuntimeError("MapClient used outside its `with` block")
        return query_region(self._session, map_id, self.extent(map_id) if box is None else box, self.config)

    def extent(self, map_id: str) -> Box:
        """The box [m] holding every cell of the map with data, from every (trusted) server's status."""
        if self._session is None:
            raise RuntimeError("MapClient used outside its `with` block")
        statuses = get_statuses(self._session, map_id, self.config.timeout_s, self.config.believed())
        try:
            return map_extent(statuses, map_id)
        except QueryError as exc:
            raise PlannerError(str(exc)) from None

    def newest_sample_t(self, map_id: str) -> float | None:
        """The newest merged sample's time [s] over every (trusted) server's `status` (mission time:
        where the recording logs a plan made now), None when no server answers."""
        if self._session is None:
            raise RuntimeError("MapClient used outside its `with` block")
        parts = get_statuses(self._session, map_id, self.config.timeout_s, self.config.believed())
        return max((st.t for st in parts), default=None)
