"""Zenoh key expressions of wire contract v1, built and parsed in one place."""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable

from protocol.errors import ProtocolError

__all__ = [
    "ID_PATTERN",
    "ack_key",
    "ack_pattern",
    "alive_key",
    "alive_pattern",
    "changes_key",
    "changes_pattern",
    "partition_key",
    "server_id_key",
    "server_id_pattern",
    "server_who",
    "delta_key",
    "delta_pattern",
    "map_key",
    "parse_alive_key",
    "parse_delta_key",
    "status_key",
    "validate_id",
]

PREFIX = "psr"
ID_PATTERN = re.compile(r"[A-Za-z0-9_-]+")
SERVER = "server"  # the `who` of the server's liveliness token


def validate_id(s: object, what: str = "id") -> str:
    """Return `s` if it is a valid map / scout id (`[A-Za-z0-9_-]+`), else raise ProtocolError('bad_id')."""
    if not isinstance(s, str):
        raise ProtocolError(
            "wrong_type", f"{what} must be a str matching [A-Za-z0-9_-]+, got {type(s).__name__}"
        )
    if not ID_PATTERN.fullmatch(s):
        raise ProtocolError("bad_id", f"{what} {s!r} must match [A-Za-z0-9_-]+ (letters, digits, '_', '-')")
    return s


def id_arg(what: str) -> Callable[[str], str]:
    """An argparse `type=` for a map or scout id: a bad one is a usage error naming the valid pattern."""

    def parse(s: str) -> str:
        try:
            return validate_id(s, what)
        except ProtocolError as exc:
            raise argparse.ArgumentTypeError(exc.detail) from None

    parse.__name__ = f"{what} id"
    return parse


def _scope(map_id: str, shard: int | None) -> str:
    """`psr/<map>` for an unsharded map (shard None), `psr/<map>/shard/<i>` for shard i of a sharded one."""
    base = f"{PREFIX}/{validate_id(map_id, 'map')}"
    if shard is None:
        return base
    if isinstance(shard, bool) or not isinstance(shard, int) or shard < 0:
        raise ProtocolError("bad_value", f"shard {shard!r}: valid is an integer ≥ 0")
    return f"{base}/shard/{shard}"


def delta_key(map_id: str, scout_id: str, shard: int | None = None) -> str:
    return f"{_scope(map_id, shard)}/delta/{validate_id(scout_id, 'scout')}"


def delta_pattern(map_id: str, shard: int | None = None) -> str:
    return f"{_scope(map_id, shard)}/delta/*"


def ack_key(map_id: str, scout_id: str, shard: int | None = None) -> str:
    return f"{_scope(map_id, shard)}/ack/{validate_id(scout_id, 'scout')}"


def ack_pattern(map_id: str, shard: int | None = None) -> str:
    return f"{_scope(map_id, shard)}/ack/*"


def server_who(shard: int | None = None) -> str:
    """The `who` of a server's liveliness token: `server`, or `server-<i>` for shard i."""
    return SERVER if shard is None else f"{SERVER}-{int(shard)}"


def partition_key(map_id: str) -> str:
    """Queryable every server of the map answers with its `protocol.partition.Partition`."""
    return f"{PREFIX}/{validate_id(map_id, 'map')}/partition"


def changes_key(map_id: str, shard: int | None = None) -> str:
    """Where a server publishes the tiles each committed batch changed (`protocol.messages.TileChanges`)."""
    return f"{PREFIX}/{validate_id(map_id, 'map')}/changes/{server_who(shard)}"


def changes_pattern(map_id: str) -> str:
    return f"{PREFIX}/{validate_id(map_id, 'map')}/changes/*"


def server_id_key(map_id: str, zid: str) -> str:
    """The liveliness token a map server holds to say "Zenoh id `zid` is a server of this map": the router's ACL
    lets only server credentials declare it, so clients believe replies from the ids these tokens name."""
    if not re.fullmatch(r"[0-9a-f]{1,32}", str(zid)):
        raise ProtocolError("bad_id", f"zenoh id {zid!r}: valid is 1-32 lowercase hex digits")
    return f"{PREFIX}/{validate_id(map_id, 'map')}/serverid/{zid}"


def server_id_pattern(map_id: str) -> str:
    return f"{PREFIX}/{validate_id(map_id, 'map')}/serverid/*"


def map_key(map_id: str) -> str:
    return f"{PREFIX}/{validate_id(map_id, 'map')}/map"


def status_key(map_id: str) -> str:
    return f"{PREFIX}/{validate_id(map_id, 'map')}/status"


def alive_key(map_id: str, who: str) -> str:
    """Liveliness token key of a scout, or of the server with `who="server"`."""
    return f"{PREFIX}/{validate_id(map_id, 'map')}/alive/{validate_id(who, 'who')}"


def alive_pattern(map_id: str) -> str:
    return f"{PREFIX}/{validate_id(map_id, 'map')}/alive/*"


def _parse(key: str, kind: str) -> tuple[str, str]:
    parts = str(key).split("/")
    if len(parts) == 6 and parts[2] == "shard" and parts[3].isdigit():  # psr/<map>/shard/<i>/<kind>/<id>
        parts = [parts[0], parts[1], parts[4], parts[5]]
    if len(parts) != 4 or parts[0] != PREFIX or parts[2] != kind:
        raise ProtocolError(
            "key_mismatch", f"key {key!r} is not of the form {PREFIX}/<map>[/shard/<i>]/{kind}/<id>"
        )
    return validate_id(parts[1], "map"), validate_id(parts[3], kind)


def parse_delta_key(key: str) -> tuple[str, str]:
    """`psr/<map>/delta/<scout>` or `psr/<map>/shard/<i>/delta/<scout>` -> (map_id, scout_id);
    ProtocolError('key_mismatch') otherwise."""
    return _parse(key, "delta")


def parse_alive_key(key: str) -> tuple[str, str]:
    """`psr/<map>/alive/<who>` -> (map_id, who)."""
    return _parse(key, "alive")


def parse_ack_key(key: str) -> tuple[str, str]:
    return _parse(key, "ack")
