"""psrmap's rmw_zenoh wire details decoded the way rmw_zenoh and zenoh-cpp read them, by code written here from
their sources (not psrmap's encoder): the sample attachment (zenoh-cpp's `Deserializer` for rmw_zenoh's
`AttachmentData`), the QoS field of liveliness tokens (rmw_zenoh's `keyexpr_to_qos` with its default depth 42),
and the sporadic heartbeat rmw_zenoh's reliable transient-local publishers declare (zenoh-ext's advanced
publisher state messages)."""

from __future__ import annotations

import struct
import time

import pytest
import zenoh

from psrmap_common.session import zenoh_config
from psrmap_interop.rmw_zenoh import Qos, RosNode, attachment, qos_key
from psrmap_interop.ros2_messages import PATH, path_msg

GID = bytes(range(0xA0, 0xB0))


def leb128(buf: bytes, pos: int) -> tuple[int, int]:
    """An unsigned LEB128 varint at `pos` (zenoh's sequence length): (value, position after it)."""
    value = shift = 0
    while True:
        if pos >= len(buf):
            raise ValueError("truncated varint")
        byte = buf[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, pos


def read_rmw_zenoh_attachment(buf: bytes) -> tuple[int, int, bytes]:
    """rmw_zenoh's `AttachmentData(const zenoh::Bytes &)`: int64 sequence number, int64 source timestamp (both
    little endian, fixed width), then `std::array<uint8_t, 16>`, which zenoh-cpp reads as a sequence: its
    length, then that many bytes, throwing "Incorrect sequence size" when the length is not 16."""
    if len(buf) < 16:
        raise ValueError("attachment shorter than its two int64")
    seq, stamp = struct.unpack_from("<qq", buf, 0)
    n, pos = leb128(buf, 16)
    if n != 16:
        raise ValueError(f"Incorrect sequence size {n}")
    if len(buf) < pos + n:
        raise ValueError("truncated GID")
    return seq, stamp, buf[pos : pos + n]


def test_the_attachment_is_what_zenoh_cpp_reads_for_rmw_zenoh() -> None:
    att = attachment(7, 1_700_000_000_123_456_789, GID)
    assert len(att) == 33 and att[16] == 0x10
    assert read_rmw_zenoh_attachment(att) == (7, 1_700_000_000_123_456_789, GID)
    # the form psrmap used to send (GID without its length) is what zenoh-cpp refuses
    for gid in (
        GID,
        bytes(range(16)),
    ):  # its first byte taken for a length: a varint that runs off, or 0 != 16
        with pytest.raises(ValueError, match="Incorrect sequence size|truncated"):
            read_rmw_zenoh_attachment(struct.pack("<qq", 7, 1) + gid)
    with pytest.raises(ValueError, match="16 bytes"):
        attachment(1, 1, GID[:15])


def parse_qos_field(field: str) -> dict[str, int]:
    """rmw_zenoh's `keyexpr_to_qos` for the fields psrmap sets: `rel:dur:hist,depth:...`, an empty field meaning
    rmw_zenoh's default (`qos.cpp`: RELIABLE 1, VOLATILE 2, KEEP_LAST 1, depth 42)."""
    parts = field.split(":")
    assert len(parts) == 6, field
    hist, depth = parts[2].split(",")
    assert parts[3:] == [",", ",", ",,"]  # deadline, lifespan, liveliness: defaults (infinite, automatic)
    return {"reliability": int(parts[0] or 1), "durability": int(parts[1] or 2), "history": int(hist or 1),
            "depth": int(depth or 42)}  # fmt: skip


@pytest.mark.parametrize("depth", [1, 10, 42, 100])
def test_the_token_qos_field_round_trips_through_rmw_zenohs_defaults(depth: int) -> None:
    q = Qos(depth=depth)
    field = qos_key(q)
    assert parse_qos_field(field) == {"reliability": 1, "durability": 1, "history": 1, "depth": depth}
    assert (field.split(":")[2] == ",") == (depth == 42)  # the default depth is left empty, as rmw_zenoh does
    assert parse_qos_field(qos_key(Qos(reliability=2, durability=2)))["reliability"] == 2


def test_a_reliable_transient_local_publisher_sends_sporadic_heartbeats(router: str) -> None:
    """zenoh-ext's advanced publisher with sporadic-heartbeat miss detection puts, once per period and only when
    it published since, the last sequence number (uint32, zenoh-serialised: 4 bytes little endian) on
    `<topic key>/@adv/pub/<zid>/<eid>/...`; rmw_zenoh's subscribers use it to fetch a missed sample."""
    beats: list[tuple[str, bytes]] = []
    conf = lambda: zenoh_config([router], (), "client")  # noqa: E731
    with zenoh.open(conf()) as pub_s, zenoh.open(conf()) as sub_s:
        zid = str(pub_s.info.zid())
        node = RosNode(pub_s, "hb_node")
        pub = node.publisher("/hb/path", PATH, Qos(depth=3))
        sub = sub_s.declare_subscriber(
            f"{pub.key}/@adv/pub/**", lambda s: beats.append((str(s.key_expr), s.payload.to_bytes()))
        )
        try:
            time.sleep(0.5)
            pub.publish(path_msg([(0.0, 0.0), (1.0, 0.0)], "map", 1))
            pub.publish(path_msg([(0.0, 0.0), (2.0, 0.0)], "map", 2))
            end = time.monotonic() + 3.0
            while not beats and time.monotonic() < end:
                time.sleep(0.05)
            time.sleep(1.2)  # two more periods with nothing published: sporadic, so no further beat
        finally:
            sub.undeclare()
            node.close()
    assert beats, "no heartbeat"
    assert all(key.startswith(f"{pub.key}/@adv/pub/{zid}/") for key, _ in beats), beats
    # One beat per period in which something was published: one, or two when a period's end fell between
    # the two publishes (a loaded machine); the sequence numbers never go back and the last is the last sent.
    seqs = [struct.unpack("<I", payload)[0] for _, payload in beats]
    assert len(beats) <= 2 and seqs == sorted(set(seqs)) and seqs[-1] == 1, beats
