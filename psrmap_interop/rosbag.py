"""A rosbag2 recording (MCAP storage) of the map, the cost grid and paths, written with `rosbags` (no ROS install):
`ros2 bag play`, Foxglove and PlotJuggler read it.

Each topic carries what rosbag2 itself records, so `ros2 bag play` republishes it as psrmap's bridge publishes it
(transient local: a late RViz still gets the map):
- `offered_qos_profiles`: the publisher's profile (reliability, durability, history, depth; rmw's infinite
  deadline, lifespan and lease; automatic liveliness), in rosbag2's version-9 YAML, both in `metadata.yaml` and in
  each MCAP channel's metadata;
- `topic_type_hash`: the message type's RIHS01 hash, in the MCAP channel's metadata (rosbag2_storage_mcap's key;
  `metadata.yaml` has it as `type_description_hash`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any

from psrmap_interop.rmw_zenoh import Qos
from psrmap_interop.ros2_messages import serialize, typestore

__all__ = ["BagMessage", "write_mcap_bag"]

# rmw's RMW_DURATION_INFINITE as rosbag2 writes it (what a recording of an rmw_zenoh publisher holds)
_INFINITE = (9_223_372_036, 854_775_807)


@dataclass(frozen=True)
class BagMessage:
    topic: str
    typename: str
    msg: Any
    stamp_ns: int
    qos: Qos = Qos()  # as the bridge publishes: reliable, transient local, keep last 1
    extra: dict = field(default_factory=dict, compare=False)


def rosbag_qos(q: Qos):  # -> rosbags.interfaces.Qos
    """psrmap's QoS as the profile rosbag2 records for the publisher (rmw's enum values are rosbags')."""
    from rosbags.interfaces import Qos as BagQos  # lazy: rosbags only when a bag is written
    from rosbags.interfaces import QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    inf = QosTime(*_INFINITE)
    return BagQos(history=QosHistory(q.history), depth=q.depth, reliability=QosReliability(q.reliability),
                  durability=QosDurability(q.durability), deadline=inf, lifespan=inf,
                  liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=inf,
                  avoid_ros_namespace_conventions=False)  # fmt: skip


def _writer(path: Path):
    """rosbags' rosbag2 Writer whose MCAP channels also carry `topic_type_hash`, as rosbag2_storage_mcap writes
    them (rosbags' own MCAP storage writes only `offered_qos_profiles`)."""
    from rosbags.rosbag2 import StoragePlugin, Writer  # lazy: rosbags only when a bag is written
    from rosbags.rosbag2.storage_mcap import Channel, McapWriter, write_channel, write_string

    class _McapStorage(McapWriter):
        def add_connection(self, connection, offered_qos_profiles: str) -> None:
            meta = BytesIO()
            for key, value in (
                ("offered_qos_profiles", offered_qos_profiles),
                ("topic_type_hash", connection.digest),
            ):
                write_string(meta, key)
                write_string(meta, value)
            self.channels.append(Channel(connection.id, connection.msgtype, connection.topic,
                                         connection.ext.serialization_format, meta.getvalue()))  # fmt: skip
            self.channel_stats[connection.id] = 0
            write_channel(self.chunk.bio, self.channels[-1], self.schemas)

    class _Writer(Writer):
        STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: _McapStorage}

    return _Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)


def write_mcap_bag(path: str | Path, messages: Sequence[BagMessage]) -> Path:
    """Write `messages` (in time order per topic) into a new rosbag2 folder `path` with MCAP storage. Every
    message of a topic must share its type and QoS."""
    out = Path(path)
    if out.exists():
        raise FileExistsError(f"{out} exists; a rosbag2 is a new folder: give a path that does not exist")
    store = typestore()
    with _writer(out) as writer:
        conns: dict[str, Any] = {}
        kinds: dict[str, tuple[str, Qos]] = {}
        for m in sorted(messages, key=lambda m: m.stamp_ns):
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, m.typename, typestore=store,
                                                       offered_qos_profiles=[rosbag_qos(m.qos)])  # fmt: skip
                kinds[m.topic] = (m.typename, m.qos)
            elif kinds[m.topic] != (m.typename, m.qos):
                raise ValueError(f"topic {m.topic}: {(m.typename, m.qos)} after {kinds[m.topic]}; one type and "
                                 "QoS per topic")  # fmt: skip
            writer.write(conns[m.topic], int(m.stamp_ns), serialize(m.msg, m.typename))
    return out
