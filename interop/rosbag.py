"""A rosbag2 recording (MCAP storage) of the map, the cost grid and paths, written with `rosbags` (no ROS install):
`ros2 bag play`, Foxglove and PlotJuggler read it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from interop.ros2_messages import serialize, typestore

__all__ = ["BagMessage", "write_mcap_bag"]


@dataclass(frozen=True)
class BagMessage:
    topic: str
    typename: str
    msg: Any
    stamp_ns: int
    extra: dict = field(default_factory=dict, compare=False)


def write_mcap_bag(path: str | Path, messages: Sequence[BagMessage]) -> Path:
    """Write `messages` (in time order per topic) into a new rosbag2 folder `path` with MCAP storage."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    out = Path(path)
    if out.exists():
        raise FileExistsError(f"{out} exists; a rosbag2 is a new folder: give a path that does not exist")
    store = typestore()
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns: dict[str, Any] = {}
        for m in sorted(messages, key=lambda m: m.stamp_ns):
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, m.typename, typestore=store)
            writer.write(conns[m.topic], int(m.stamp_ns), serialize(m.msg, m.typename))
    return out
