"""The shared modules' exceptions: one root, `CommonError`."""

from __future__ import annotations

__all__ = ["CommonError", "InsecureListen", "QueryError", "SessionError", "UsageError", "ViewerUnavailable"]


class CommonError(Exception):
    """Root of every error `psrmap_common` raises on purpose."""


class InsecureListen(CommonError, ValueError):
    """Listening on a non-loopback endpoint without credentials, and `--insecure` was not given."""


class SessionError(CommonError, ConnectionError):
    """A Zenoh session that cannot be opened (no router where the endpoints point, a refused config)."""


class QueryError(CommonError):
    """No server answered a query in time, or every answer was an error; the message says which."""


class ViewerUnavailable(CommonError, ValueError):
    """`--viewer` where no viewer can open (no display, no `rerun` binary) or `--connect-viewer` to a URL where
    nothing listens: found before any work starts, one line saying what to do instead."""


class UsageError(CommonError):
    """A command line whose arguments do not go together (or name a bad file): raised by a command, shown by the
    `psrmap` entry point with that command's usage and exit code 2, like argparse's own errors; `usage=False`:
    one line without the usage (nothing is wrong with the command, only the place, e.g. no display)."""

    def __init__(self, message: str, usage: bool = True) -> None:
        super().__init__(message)
        self.usage = usage
