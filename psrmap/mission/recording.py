"""The mission's Rerun recordings: every component's `.rrd` merged and optimized into `mission.rrd`."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

__all__ = ["merge_recordings", "rerun_exe"]


def rerun_exe() -> list[str]:
    """The `rerun` command line tool: the script on PATH, else the module of the installed rerun-sdk."""
    exe = shutil.which("rerun")
    return [exe] if exe else [sys.executable, "-m", "rerun"]


def merge_recordings(run_dir: Path) -> Path | None:
    """Merge every process's .rrd of the run into `mission.rrd` (the recordings share one recording id) and
    compact its chunks (`rerun rrd optimize`: the processes send small chunks as they go; the viewer loads
    and scrubs the compacted file much faster)."""
    parts = sorted((run_dir / "recordings").glob("*.rrd"))
    if not parts:
        return None
    dst = run_dir / "mission.rrd"
    res = subprocess.run(
        [*rerun_exe(), "rrd", "optimize", *map(str, parts), "-o", str(dst)],
        capture_output=True,
        text=True,
        check=False,
    )
    if res.returncode != 0:
        print(
            f"warning: rerun rrd optimize failed ({res.stderr.strip()[:300]}); the per-process recordings stay",
            file=sys.stderr,
        )
        return None
    return dst
