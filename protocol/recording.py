"""The Rerun recording every process of one mission shares: application id and recording id.

Processes started for one mission (server, scouts, planner) each write their own .rrd, with the same
application id and the recording id taken from the `PSRMAP_RECORDING_ID` environment variable, so the files
open (or merge, `rerun rrd merge`) as one recording. This module only names the convention; it does not
import rerun (only the `viz` modules do).
"""

from __future__ import annotations

import os

__all__ = ["APP_ID", "RECORDING_ID_ENV", "recording_id"]

APP_ID = "psrmap"
RECORDING_ID_ENV = "PSRMAP_RECORDING_ID"


def recording_id(default: str | None = None) -> str | None:
    """The mission's recording id from the environment, else `default` (None: Rerun picks a fresh one)."""
    return os.environ.get(RECORDING_ID_ENV) or default
