"""The map server as a component: `run(ServerConfig) -> ServerSummary`.

Starts a `service.MapService` (recovering the map from its SQLite store), serves until `stop` is set
(by default: on SIGINT / SIGTERM) or the merge worker fails, stops cleanly and returns what it did.
`psrmap server` parses its options into a `ServerConfig` and calls this; the mission starts it in a
spawned process and terminates it with SIGTERM, receiving the `ServerSummary` back.
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType

from map_server.errors import MapServerConfigError, MapServerError
from map_server.service import MapService, ServerConfig

__all__ = ["ServerConfig", "ServerSummary", "run", "stop_on_signals"]

log = logging.getLogger("map_server")

EX_SOFTWARE = 70  # the exit code of a server whose merge worker failed (a supervisor restarts it)


@dataclass(frozen=True)
class ServerSummary:
    map_id: str
    replayed: int  # deltas recovered from the store at start
    merged: int  # deltas merged in total (the map's version counter)
    duplicates: int
    rejected: dict[str, int]
    cells: int
    failure: str | None  # what stopped the merge worker, if it failed
    exit_code: int  # 0, or EX_SOFTWARE when the merge worker failed


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT / SIGTERM (call from the main thread)."""
    stop = threading.Event()

    def handler(signum: int, _frame: FrameType | None) -> None:
        log.info("signal %d: shutting down", signum)
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def run(
    config: ServerConfig,
    stop: threading.Event | None = None,
    on_up: Callable[[MapService], None] | None = None,
) -> ServerSummary:
    """Serve the map until `stop` is set (default: SIGINT / SIGTERM) or the merge worker fails.
    `on_up` is called once the service answers. Raises MapServerConfigError for a configuration or store
    that cannot serve (the message names what would)."""
    if not config.connect and not config.listen:
        raise MapServerConfigError(
            "give connect endpoints (a router) and/or listen endpoints, e.g. tcp/127.0.0.1:7447"
        )
    if not config.res > 0:
        raise MapServerConfigError(f"res {config.res}: need a cell size > 0 [m]")
    stop = stop if stop is not None else stop_on_signals()
    try:
        service = MapService(config)
        service.start()
    except MapServerError:
        raise
    except (ValueError, ConnectionError) as exc:
        raise MapServerConfigError(str(exc)) from None
    with service:
        if on_up is not None:
            on_up(service)
        while not stop.wait(0.2):
            if service.failed.is_set():
                log.error("merge worker failed (%s); exiting non-zero so a supervisor restarts the server "
                          "from its store", service.worker_error)  # fmt: skip
                break
    book = service.merger.book
    failed = service.failed.is_set()
    if not failed:
        log.info("stopped cleanly")
    return ServerSummary(
        map_id=config.map_id,
        replayed=service.replayed,
        merged=book.merged,
        duplicates=book.duplicates,
        rejected=dict(book.rejected),
        cells=service.cells,
        failure=service.worker_error if failed else None,
        exit_code=EX_SOFTWARE if failed else 0,
    )
