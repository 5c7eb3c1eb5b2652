"""Screenshots of a mission recording in the default blueprint, taken headlessly.

    python docs/figures/rerun_screenshots.py runs/<timestamp>/mission.rrd [--out docs/figures]

Starts the Rerun viewer without a window (`--headless`, software rendering: on a machine without a GPU it
needs Mesa's lavapipe, Debian package `mesa-vulkan-drivers`), opens the recording, and saves the whole
viewer at mid-mission and at the end of the `sim_time` timeline as `rerun_mid.png` and `rerun_end.png`.
"""

from __future__ import annotations

import argparse
import socket
import time
from pathlib import Path


def _end_of_sim_time(rrd: Path) -> float:
    from rerun.chunk import RrdReader

    end = 0
    for chunk in RrdReader(rrd).stream():
        if not chunk.is_static and "sim_time" in chunk.timeline_names:
            rb = chunk.to_record_batch()
            end = max(end, *rb.column(rb.schema.names.index("sim_time")).cast("int64").to_pylist())
    return end / 1e9


def main() -> None:
    ap = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    ap.add_argument("rrd", type=Path)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent)
    ap.add_argument("--settle", type=float, default=6.0, help="seconds the viewer gets to load and draw")
    args = ap.parse_args()
    import rerun.experimental as rre

    end = _end_of_sim_time(args.rrd)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    viewer = rre.ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True)
    try:
        viewer.open(str(args.rrd.resolve()))
        time.sleep(args.settle)
        for name, t in (("rerun_mid.png", end / 2), ("rerun_end.png", end)):
            viewer.set_time("sim_time", duration=t, play_state="paused")
            time.sleep(args.settle / 2)
            out = (args.out / name).resolve()
            viewer.save_screenshot(str(out))
            print(f"{out} at sim_time {t:.1f} s")
    finally:
        viewer.quit()


if __name__ == "__main__":
    main()
