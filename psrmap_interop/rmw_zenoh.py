"""Publish ROS 2 topics the way ROS 2's Zenoh middleware (ros2/rmw_zenoh) does, from a plain Zenoh session.

What a ROS 2 node on rmw_zenoh (RViz, `ros2 topic echo`) needs to see a topic:
- samples on `<domain>/<topic without leading slash>/<DDS type name>/<RIHS01 type hash>`
  (`topic_key`), payload CDR little endian with its encapsulation header (`psrmap_interop.ros2_messages.serialize`);
- an attachment on every sample, in zenoh-ext serialisation (`attachment`): sequence number (int64), source
  timestamp [ns] (int64), the publisher's 16-byte GID as a *sequence* (rmw_zenoh serialises a
  `std::array<uint8_t, 16>`, which zenoh-cpp writes as a LEB128 length, 0x10, then the bytes, and reads back
  refusing any other length): 33 bytes;
- graph discovery: liveliness tokens `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP>/<enclave>/<namespace>/
  <node>[/<topic>/<type>/<hash>/<qos>]`, names with '/' mangled to '%' (`node_token`, `publisher_token`);
- transient-local topics (a late RViz gets the last map) are served from a publication cache: a zenoh-ext
  advanced publisher with a cache of `depth` samples and publisher detection, and, when also reliable, sample
  miss detection with a sporadic heartbeat every 500 ms (subscribers notice a lost sample and fetch it from the
  cache), as rmw_zenoh declares them (`rmw_publisher_data.cpp`).
The GID is the XXH3-128 of the publisher's liveliness key expression (low 64 bits first), as rmw_zenoh's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import xxhash
import zenoh
import zenoh.ext as zext

from psrmap_interop.errors import InteropError
from psrmap_interop.ros2_messages import dds_type_name, serialize, type_hash

__all__ = [
    "Qos",
    "RosNode",
    "RosPublisher",
    "attachment",
    "mangle",
    "publisher_token",
    "qos_key",
    "topic_key",
]

ADMIN_SPACE = "@ros2_lv"

# rmw's enum values and rmw_zenoh's default profile (`qos.cpp`: RELIABLE, VOLATILE, KEEP_LAST with depth 42):
# rmw_zenoh writes a QoS field in a liveliness token only where it differs from that default
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST = 1
DEFAULT_DEPTH = 42
_DEFAULT = {"reliability": RELIABLE, "durability": VOLATILE, "history": KEEP_LAST, "depth": DEFAULT_DEPTH}
# rmw_zenoh's heartbeat period for sample miss detection on RELIABLE + TRANSIENT_LOCAL publishers
MISS_DETECTION_HEARTBEAT_MS = 500
GID_BYTES = 16


@dataclass(frozen=True)
class Qos:
    reliability: int = RELIABLE
    durability: int = TRANSIENT_LOCAL
    history: int = KEEP_LAST
    depth: int = 1


def mangle(name: str) -> str:
    """A ROS name inside a liveliness key: '/' -> '%' (an empty namespace '/' becomes '%')."""
    return name.replace("/", "%")


def topic_key(domain: int, topic: str, typename: str) -> str:
    return f"{domain}/{topic.strip('/')}/{dds_type_name(typename)}/{type_hash(typename)}"


def qos_key(q: Qos) -> str:
    """`reliability:durability:history,depth:deadline s,ns:lifespan s,ns:liveliness,s,ns` (defaults empty)."""

    def f(name: str, v: int) -> str:
        return "" if v == _DEFAULT[name] else str(v)

    return (f"{f('reliability', q.reliability)}:{f('durability', q.durability)}:"
            f"{f('history', q.history)},{f('depth', q.depth)}:,:,:,,")  # fmt: skip


def node_token(domain: int, zid: str, nid: int, ns: str, node: str, enclave: str = "/") -> str:
    return f"{ADMIN_SPACE}/{domain}/{zid}/{nid}/{nid}/NN/{mangle(enclave)}/{mangle(ns)}/{mangle(node)}"


def publisher_token(domain: int, zid: str, nid: int, eid: int, ns: str, node: str, topic: str, typename: str,
                    qos: Qos, enclave: str = "/") -> str:  # fmt: skip
    return (f"{ADMIN_SPACE}/{domain}/{zid}/{nid}/{eid}/MP/{mangle(enclave)}/{mangle(ns)}/{mangle(node)}/"
            f"{mangle(topic)}/{dds_type_name(typename)}/{type_hash(typename)}/{qos_key(qos)}")  # fmt: skip


def gid(token: str) -> bytes:
    """16-byte GID of an entity: XXH3-128 of its liveliness key, low 64 bits then high 64, little endian."""
    h = xxhash.xxh3_128_intdigest(token.encode())
    return (h & (2**64 - 1)).to_bytes(8, "little") + (h >> 64).to_bytes(8, "little")


def attachment(seq: int, stamp_ns: int, source_gid: bytes) -> bytes:
    """The per-sample attachment rmw_zenoh subscribers read: int64 seq, int64 timestamp [ns], then the GID as a
    sequence of 16 uint8 (a list serialises with its length first, as zenoh-cpp's std::array does)."""
    if len(source_gid) != GID_BYTES:
        raise InteropError(f"a GID is {GID_BYTES} bytes, got {len(source_gid)}")
    return zext.z_serialize(
        (zext.Int64(seq), zext.Int64(stamp_ns), [zext.UInt8(b) for b in source_gid])
    ).to_bytes()


class RosNode:
    """A ROS 2 node's presence on the graph (its liveliness token) over an open Zenoh session."""

    def __init__(self, session: zenoh.Session, name: str, namespace: str = "/", domain: int = 0) -> None:
        self.session, self.name, self.namespace, self.domain = session, name, namespace, domain
        self.zid = str(session.info.zid())
        self.nid = 0
        self._next_id = 1
        self._tokens = [
            session.liveliness().declare_token(node_token(domain, self.zid, self.nid, namespace, name))
        ]
        self.publishers: list[RosPublisher] = []

    def publisher(self, topic: str, typename: str, qos: Qos = Qos()) -> RosPublisher:
        pub = RosPublisher(self, self._next_id, topic, typename, qos)
        self._next_id += 1
        self.publishers.append(pub)
        return pub

    def close(self) -> None:
        for p in self.publishers:
            p.close()
        for t in self._tokens:
            t.undeclare()
        self._tokens.clear()


def _reliability(q: Qos) -> zenoh.Reliability:
    return zenoh.Reliability.RELIABLE if q.reliability == RELIABLE else zenoh.Reliability.BEST_EFFORT


class RosPublisher:
    """One topic: samples on its rmw_zenoh key with the attachment; a liveliness token; for transient-local
    QoS an advanced publisher whose cache serves late joiners."""

    def __init__(self, node: RosNode, eid: int, topic: str, typename: str, qos: Qos) -> None:
        if not topic.startswith("/"):
            topic = "/" + topic
        self.topic, self.typename, self.qos = topic, typename, qos
        self.key = topic_key(node.domain, topic, typename)
        self.token_key = publisher_token(node.domain, node.zid, node.nid, eid, node.namespace, node.name, topic,
                                         typename, qos)  # fmt: skip
        self.gid = gid(self.token_key)
        self.seq = 0
        s = node.session
        self._pub: Any
        if qos.durability == TRANSIENT_LOCAL:
            miss = (zext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=MISS_DETECTION_HEARTBEAT_MS / 1000)
                    if qos.reliability == RELIABLE else None)  # fmt: skip
            self._pub = zext.declare_advanced_publisher(s, self.key, cache=zext.CacheConfig(max_samples=qos.depth),
                                                        publisher_detection=True, sample_miss_detection=miss,
                                                        reliability=_reliability(qos))  # fmt: skip
        else:
            self._pub = s.declare_publisher(self.key, reliability=_reliability(qos))
        self._token = s.liveliness().declare_token(self.token_key)

    def publish(self, msg, stamp_ns: int | None = None) -> int:
        """Serialise and put `msg`; returns its sequence number."""
        self.seq += 1
        stamp = time.time_ns() if stamp_ns is None else stamp_ns
        self._pub.put(serialize(msg, self.typename), attachment=attachment(self.seq, stamp, self.gid))
        return self.seq

    def close(self) -> None:
        self._token.undeclare()
        self._pub.undeclare()
