"""The root exceptions of the `psrmap` composition root (mission, experiments), and the one table that maps
every package's root exception to a one-line message and an exit code at the command line."""

from __future__ import annotations

import sys

__all__ = ["EXIT_CODES", "MissionRunError", "PsrmapError", "exit_code_for"]


class PsrmapError(Exception):
    """Root of the errors raised by the `psrmap` package itself."""


class MissionRunError(PsrmapError, RuntimeError):
    """A mission that started but could not finish: a component died, the servers never answered, timeout."""


# (module, exception class, exit code), most specific first. 2: the input was wrong (a usage error: fix the
# command, file or message); 1: the run failed (a component, the network or the disk). Looked up in
# sys.modules only: an exception of a package that was never imported cannot have been raised, and the
# command stays quick to start.
EXIT_CODES: tuple[tuple[str, str, int], ...] = (
    ("psrmap_common.errors", "UsageError", 2),
    ("psrmap_common.errors", "InsecureListen", 2),
    ("psrmap_common.errors", "ViewerUnavailable", 2),
    ("psrmap_common.errors", "SessionError", 1),
    ("psrmap_common.errors", "QueryError", 1),
    ("psrmap_common.errors", "CommonError", 1),
    ("protocol.errors", "ProtocolError", 2),
    ("psrmap_mapcore.errors", "MapFileError", 2),
    ("psrmap_mapcore.errors", "MapCoreError", 1),
    ("scout_agent.errors", "ScoutConfigError", 2),
    ("scout_agent.errors", "ScoutError", 1),
    ("map_server.errors", "MapServerConfigError", 2),
    ("map_server.errors", "MapServerError", 1),
    ("consumer_planner.errors", "PlannerError", 1),
    ("psrmap_interop.errors", "InteropError", 2),
    ("psrmap.mission.config", "MissionError", 2),
    ("psrmap.experiments.config", "ExperimentError", 2),
    ("psrmap.errors", "MissionRunError", 1),
    ("psrmap.errors", "PsrmapError", 1),
)


def exit_code_for(exc: BaseException) -> int | None:
    """The exit code of a known root exception (`EXIT_CODES`), None for anything else (a programming error,
    which keeps its traceback)."""
    for module, name, code in EXIT_CODES:
        cls = getattr(sys.modules.get(module), name, None)
        if isinstance(cls, type) and isinstance(exc, cls):
            return code
    return None
