"""`psrmap secure init`: per-agent Zenoh credentials and the router's access control list, with Zenoh's own
machinery (`transport/auth/usrpwd`, `access_control`; mutual TLS as an option).

Roles (`GRANTS`, the README's roles table; everything else is denied by the router, per message kind and direction):
- a server: subscribes to and receives every delta, puts acks and tile-change notices, declares the `map`,
  `status` and `partition` queryables and replies on them, holds `alive/server*` tokens and the token
  `psr/<map>/serverid/<its Zenoh id>`, watches the scouts' tokens;
- a scout `S`: puts only `psr/<map>/delta/S` (sharded: `psr/<map>/shard/<i>/delta/S`), holds only the token
  `psr/<map>/alive/S`, receives its own acks, asks the partition, sees the servers' tokens, and reads the map
  as a reader does (queries `map`, `status`, follows tile changes: it localizes against the map);
- a reader (a planner): queries `map`, `status`, `partition` and receives the replies, subscribes to tile
  changes, sees the tokens; and reads the ROS 2 bridge's topics (subscribes to them, asks their publication cache
  for the last sample, watches the ROS graph) — nothing else: a ROS 2 tool on rmw_zenoh (RViz, `ros2 topic echo`)
  logs in with a planner's file; the graph tokens of its own node are refused, so it receives but is not listed;
- a bridge (`psrmap ros2`): what a reader may, and puts exactly its ROS topics (`<domain>/<prefix>/{grid_map,
  cost,plan}/<type>/<hash>`, rmw_zenoh's layout, `--ros-domain`/`--ros-prefix`), serves their publication cache
  (`<topic>/@adv/pub/**`: queryable, heartbeat, publisher token) and holds its node's and publishers' graph
  tokens (`@ros2_lv/...`) — nothing of the map's own keys.
Whose replies to believe: each server start takes a fresh random Zenoh id and declares it in a `serverid` token,
which only server credentials may; clients (`psrmap_common.trust`) believe replies and notices only from the ids so
declared. No id is pinned, so none can be squatted while its server is down: Zenoh's ACL can match a session's
id (`zids` subjects) but cannot refuse a session, so a pinned id held by an impostor would lock the real server
out (its session is refused as a duplicate). The files: `credentials.txt` (the router's `user:password`
dictionary), `router.json5`, one `<agent>.json5` per agent holding its user name and password, and
`servers.json` ({"map", "servers": names, "trust": "attested"}) whose presence beside an agent's file tells its
clients to believe attested servers only; per robot router (`--robot-router NAME`) `NAME-router.json5` (a router
meshed to the base, logging in as `NAME-router`) and `NAME-credentials.txt` (its own agents' passwords only). With `--tls` the router listens on a `tls/`
endpoint and requires mutual TLS as well: `tls/ca.pem` signs the router's certificate (valid for `localhost`,
127.0.0.1 and the endpoint's host) and one client certificate per agent (common name = the agent id), ECDSA P-256,
valid `--days`; a client without a certificate from that CA cannot connect, whatever its password, and the ACL
matches the certificate's common name and the user name together. Rotation: run
`init` again into a new folder (fresh passwords), restart the router with its new file, then each agent with
its own; an agent is revoked by removing its line from `credentials.txt` and restarting the router.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import json
import secrets
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocol.keys import validate_id
from psrmap.ros2 import ros_keys
from psrmap_common.cli_parser import Subparsers
from psrmap_common.errors import UsageError
from psrmap_common.session import check_endpoint, endpoint_arg

__all__ = ["GRANTS", "Grant", "SecureLayout", "acl", "register", "roles_table", "secure_init"]

# Every message kind Zenoh's access control tells apart; a rule allows some of them in one direction. `in`
# (ingress at the router) is what an agent sends, `out` (egress) what the router passes on to it.
_DECLARE = ["declare_subscriber", "declare_queryable", "liveliness_token", "declare_liveliness_subscriber"]


@dataclass(frozen=True)
class Grant:
    """One line of the roles table: `role` may `messages` in direction `flow` on `keys` (`<map>` and `<id>` are
    filled in per map and agent)."""

    role: str  # server | scout | reader (planners) | bridge (what a reader may, and its ROS topics)
    flow: str  # "ingress" (the agent sends) or "egress" (the router passes it to the agent)
    messages: tuple[str, ...]
    keys: tuple[str, ...]  # under psr/<map>/, except those starting with a `_ROS_KEYS` placeholder
    why: str


# The ROS 2 bridge's keys, outside psr/<map>/ (`psrmap.ros2.ros_keys` fills them in): `<topic>` each of its
# topics' sample keys (`<topic>/@adv/pub/**`: their publication caches' queryables, heartbeats and
# publisher-detection tokens), `<topic_token>` / `<node_token>` its publishers' and its node's graph tokens,
# `<ros_graph>` the ROS graph of its domain.
_ROS_KEYS = ("<topic>", "<topic_token>", "<node_token>", "<ros_graph>")


# The roles table (README "Security and limits" shows it): everything not listed is denied by the router.
GRANTS: tuple[Grant, ...] = (
    Grant("server", "ingress", ("declare_subscriber",), ("delta/**", "shard/*/delta/**"), "subscribe to deltas"),
    Grant("server", "egress", ("put",), ("delta/**", "shard/*/delta/**"), "receive the deltas"),
    Grant("server", "ingress", ("put",), ("ack/**", "shard/*/ack/**", "changes/**"),
          "acks and tile-change notices"),
    Grant("server", "ingress", ("declare_queryable", "reply"), ("map", "status", "partition"),
          "serve map, status, partition"),
    Grant("server", "egress", ("query",), ("map", "status", "partition"), "receive the queries"),
    Grant("server", "ingress", ("liveliness_token",), ("alive/server", "alive/server-$*", "serverid/*"),
          "server tokens; its Zenoh id"),
    Grant("server", "ingress", ("declare_liveliness_subscriber", "liveliness_query"), ("alive/*",),
          "watch the scouts"),
    Grant("scout", "ingress", ("put",), ("delta/<id>", "shard/*/delta/<id>"), "its own deltas only"),
    Grant("scout", "ingress", ("liveliness_token",), ("alive/<id>",), "its own token only"),
    Grant("scout", "ingress", ("declare_subscriber",), ("ack/<id>", "shard/*/ack/<id>"), "its own acks"),
    Grant("scout", "egress", ("put",), ("ack/<id>", "shard/*/ack/<id>"), "receive its acks"),
    Grant("scout", "ingress", ("query",), ("partition", "map", "status"),
          "discover the shards; read the map it localizes against"),
    Grant("scout", "egress", ("reply",), ("partition", "map", "status"), "the servers' answers"),
    Grant("scout", "ingress", ("declare_subscriber",), ("changes/**",), "follow the map's tile changes"),
    Grant("scout", "egress", ("put",), ("changes/**",), "receive tile changes"),
    Grant("scout", "ingress", ("declare_liveliness_subscriber", "liveliness_query"),
          ("alive/server", "alive/server-$*", "serverid/*"), "see the servers"),
    Grant("reader", "ingress", ("query",), ("map", "status", "partition"), "ask the map"),
    Grant("reader", "egress", ("reply",), ("map", "status", "partition"), "the servers' answers"),
    Grant("reader", "ingress", ("declare_subscriber",), ("changes/**",), "watch tile changes"),
    Grant("reader", "egress", ("put",), ("changes/**",), "receive tile changes"),
    Grant("reader", "ingress", ("declare_liveliness_subscriber", "liveliness_query"), ("alive/*", "serverid/*"),
          "see servers and scouts"),
    Grant("reader", "ingress", ("declare_subscriber", "query"), ("<topic>", "<topic>/@adv/**"),
          "ROS topics: subscribe, ask the cache"),
    Grant("reader", "ingress", ("declare_liveliness_subscriber", "liveliness_query"),
          ("<ros_graph>", "<topic>/@adv/**"), "the ROS graph, the topics' publishers"),
    Grant("reader", "egress", ("put", "reply"), ("<topic>", "<topic>/@adv/**"), "ROS samples, cached ones"),
    Grant("reader", "egress", (*_DECLARE, "reply"), ("<topic>", "<topic>/@adv/**", "<ros_graph>"),
          "who publishes and subscribes; the ROS graph"),
    Grant("bridge", "ingress", ("put",), ("<topic>", "<topic>/@adv/pub/**"), "its ROS topics; cache heartbeat"),
    Grant("bridge", "ingress", ("declare_queryable", "reply"), ("<topic>", "<topic>/@adv/pub/**"),
          "its topics' publication cache"),
    Grant("bridge", "ingress", ("liveliness_token",), ("<node_token>", "<topic_token>", "<topic>/@adv/pub/**"),
          "its node's and publishers' graph tokens"),
    Grant("bridge", "egress", ("query",), ("<topic>", "<topic>/@adv/pub/**"), "late subscribers' cache queries"),
    *(Grant(r, "egress", tuple(_DECLARE), ("**",), "learn who subscribes, serves, is alive")
      for r in ("server", "scout", "reader")),
    *(Grant(r, "egress", ("reply",), ("alive/*", "serverid/*"), "liveliness answers")
      for r in ("server", "scout", "reader")),
)  # fmt: skip


# a role may also do all its base roles may
_INHERITS = {"bridge": ("reader",)}


def _expand(key: str, base: str, agent: str, ros: dict[str, list[str]]) -> list[str]:
    """One roles-table key as the router's key expressions: a ROS placeholder becomes each key it stands for,
    any other key lies under `base` with the agent's id for `<id>`."""
    for ph in _ROS_KEYS:
        if key.startswith(ph):
            return [k + key.removeprefix(ph) for k in ros[ph]]
    return [f"{base}/{key.replace('<id>', agent)}"]


def acl(
    map_id: str,
    scouts: Sequence[str],
    planners: Sequence[str],
    servers: Sequence[str],
    tls: bool = False,
    bridges: Sequence[str] = (),
    ros_domain: int = 0,
    ros_prefix: str = "/psrmap",
    robots: dict[str, Sequence[str]] | None = None,
    upstream: str | None = None,
) -> dict[str, Any]:
    """The router's `access_control` section for one map: each agent gets its role's `GRANTS` (its own id in
    `<id>`; the ROS keys of a `psrmap ros2` on `ros_domain` under `ros_prefix`), matched on its user name — and,
    with `tls`, on its certificate's common name as well (Zenoh ANDs a subject's fields: one agent's certificate
    with another's password matches no subject, so it may do nothing). Planners are `reader`s.

    Robot routers (`robots`: name -> the agents that connect to it) log in to this router as `<name>-router` and
    may do what their agents may, together: no more. On a robot router itself (`upstream`: the base router's
    Zenoh id), the link to the base may carry what its agents may send and receive, the other way round."""
    base = f"psr/{map_id}"
    ros = ros_keys(ros_domain, ros_prefix)
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    agent_rules: dict[str, list[str]] = {}
    for role, names in (("server", servers), ("scout", scouts), ("reader", planners), ("bridge", bridges)):
        roles = (role, *_INHERITS.get(role, ()))
        for n in names:
            rid = f"{role}_{n}"
            ids = []
            for i, g in enumerate(x for x in GRANTS if x.role in roles):
                ids.append(f"{rid}_{i}")
                rules.append({
                    "id": ids[-1],
                    "messages": list(g.messages),
                    "flows": [g.flow],
                    "permission": "allow",
                    "key_exprs": [e for k in g.keys for e in _expand(k, base, n, ros)],
                })  # fmt: skip
            subject: dict[str, Any] = {"id": rid, "usernames": [n]}
            if tls:
                subject["cert_common_names"] = [n]
            subjects.append(subject)
            policies.append({"rules": ids, "subjects": [rid]})
            agent_rules[n] = ids
    for robot, agents in (robots or {}).items():
        ids = [i for a in agents for i in agent_rules[a]]
        if upstream is None:  # the base: the robot router's session speaks for its agents
            subjects.append({"id": f"robot_{robot}", "usernames": [robot_router_user(robot)]})
        else:  # the robot router: its link to the base carries its agents' traffic, each way
            flip = {"ingress": "egress", "egress": "ingress"}
            by_id = {r["id"]: r for r in rules}
            for rule in list(ids):
                rules.append(
                    {**by_id[rule], "id": f"{rule}_up", "flows": [flip[f] for f in by_id[rule]["flows"]]}
                )
            ids = [f"{rule}_up" for rule in ids]
            subjects.append({"id": f"robot_{robot}", "zids": [upstream]})
        policies.append({"rules": ids, "subjects": [f"robot_{robot}"]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def roles_table() -> str:
    """GRANTS as the README's roles table (README "Security and limits"; a test keeps the two equal): per role,
    what it may send (checked as it enters the router) and receive (as it leaves the router)."""

    def cell(role: str, flow: str) -> str:
        return "<br>".join(
            f"{', '.join(g.messages)}: {', '.join(f'`{k}`' for k in g.keys)}"
            for g in GRANTS
            if g.role == role and g.flow == flow
        )

    who = {"server": "server (`--servers`)", "scout": "scout `<id>` (`--scouts`)",
           "reader": "planner (`--planners`)", "bridge": "ROS 2 bridge (`--bridges`)"}  # fmt: skip

    def also(role: str) -> str:
        return "".join(f"what a {r} may, and:<br>" for r in _INHERITS.get(role, ()))

    lines = [
        "| role | may send (keys under `psr/<map>/`; ROS keys absolute) | may receive |",
        "|---|---|---|",
    ]
    lines += [
        f"| {who[r]} | {also(r)}{cell(r, 'ingress')} | {also(r)}{cell(r, 'egress')} |"
        for r in ("server", "scout", "reader", "bridge")
    ]
    return "\n".join(lines)


@dataclass(frozen=True)
class SecureLayout:
    """What `secure_init` wrote."""

    folder: Path
    router: Path
    agents: dict[str, Path]  # agent id -> its Zenoh config
    credentials: Path
    servers: Path  # servers.json: the map's server names; clients believe only attested servers
    robot_routers: dict[str, Path] = field(default_factory=dict)  # robot router name -> its Zenoh config


def robot_router_user(robot: str) -> str:
    """The user name a robot's router logs in to the base router with."""
    return f"{robot}-router"


def _agent_config(user: str, password: str, mode: str, endpoint: str) -> dict[str, Any]:
    return {
        "mode": mode,
        "connect": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"user": user, "password": password}}},
    }


def _write_tls(folder: Path, names: Sequence[str], host: str, days: int) -> dict[str, tuple[Path, Path]]:
    """A CA, the router's server certificate and one client certificate per agent (PEM, owner-only keys);
    returns name -> (certificate, key) with "ca" -> (ca.pem, ca.key)."""
    # lazy: cryptography (~40 ms) only for --tls; `psrmap secure --help` and plain init never load it
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    folder.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)
    life = (now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=days))

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def save(cn: str, cert: x509.Certificate, key: ec.EllipticCurvePrivateKey) -> tuple[Path, Path]:
        c, k = folder / f"{cn}.pem", folder / f"{cn}.key"
        c.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        k.write_bytes(
            key.private_bytes(
                serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
            )
        )
        k.chmod(0o600)
        return c, k

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder()
        .subject_name(name("psrmap-ca"))
        .issuer_name(name("psrmap-ca"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(life[0])
        .not_valid_after(life[1])
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    out = {"ca": save("ca", ca, ca_key)}
    alt: list[x509.GeneralName] = [
        x509.DNSName("localhost"),
        x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
    ]
    try:
        alt.append(x509.IPAddress(ipaddress.ip_address(host)))
    except ValueError:
        if host != "localhost":
            alt.append(x509.DNSName(host))
    for cn in ["router", *names]:
        key = ec.generate_private_key(ec.SECP256R1())
        b = (
            x509.CertificateBuilder()
            .subject_name(name(cn))
            .issuer_name(ca.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(life[0])
            .not_valid_after(life[1])
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        )
        if cn == "router":
            b = b.add_extension(x509.SubjectAlternativeName(alt), critical=False)
        out[cn] = save(cn, b.sign(ca_key, hashes.SHA256()), key)
    return out


def secure_init(
    folder: str | Path,
    map_id: str,
    scouts: Sequence[str],
    planners: Sequence[str],
    servers: Sequence[str] = ("server",),
    endpoint: str = "tcp/127.0.0.1:7447",
    tls: bool = False,
    days: int = 365,
    bridges: Sequence[str] = (),
    ros_domain: int = 0,
    ros_prefix: str = "/psrmap",
    robots: dict[str, Sequence[str]] | None = None,
    robot_listen: str = "tcp/127.0.0.1:7447",
) -> SecureLayout:
    """Write the router's and every agent's Zenoh config into `folder` (created; files readable by the owner
    only). Ids must be valid map/agent ids and distinct; `bridges` run `psrmap ros2 --domain ros_domain
    --prefix ros_prefix`. Each robot router (`robots`: name -> the agents on that robot) gets
    `<name>-router.json5`: a router listening on `robot_listen` for its agents (whose files connect there),
    checking their passwords (`<name>-credentials.txt`: theirs only) and the role ACL, and connecting to the
    base router at `endpoint` as user `<name>-router`; the base router's ACL gives that session what its agents
    may, together."""
    validate_id(map_id, "map")
    if not 0 <= ros_domain <= 232 or not ros_prefix.startswith("/"):
        raise ValueError(f"ROS domain {ros_domain}, prefix {ros_prefix!r}: need a domain 0..232 and a prefix "
                         "starting with '/' (as psrmap ros2 --domain/--prefix)")  # fmt: skip
    names = [*scouts, *planners, *servers, *bridges]
    for n in names:
        validate_id(n, "agent")
    if len(set(names)) != len(names) or "router" in names:
        raise ValueError(f"agent ids must be distinct and not 'router'; got {names}")
    robots = {r: list(a) for r, a in (robots or {}).items()}
    placed = [a for agents in robots.values() for a in agents]
    for r in robots:
        validate_id(r, "robot router")
    if unknown := sorted(set(placed) - set(names)):
        raise ValueError(f"robot routers name agents {unknown} that are none of {names}")
    if len(set(placed)) != len(placed) or {robot_router_user(r) for r in robots} & set(names):
        raise ValueError(f"each agent connects to at most one robot router, and no agent is called <robot>-router; "
                         f"got {robots}")  # fmt: skip
    if robots and tls:
        raise ValueError("robot routers with --tls: not supported yet (user/password only)")
    check_endpoint(robot_listen)
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    out.chmod(0o700)
    passwords = {n: secrets.token_urlsafe(24) for n in [*names, "router", *map(robot_router_user, robots)]}
    base_zid = _zid()  # robot routers know the base's link by it
    certs: dict[str, tuple[Path, Path]] = {}
    if tls:
        proto, _, addr = endpoint.partition("/")
        endpoint = f"tls/{addr}"
        certs = _write_tls(out / "tls", names, addr.rsplit(":", 1)[0].strip("[]"), days)
    cred = out / "credentials.txt"
    cred.write_text("".join(f"{n}:{pw}\n" for n, pw in passwords.items()))

    def router(user: str, dictionary: Path, upstream: str | None) -> dict[str, Any]:
        return {
            "mode": "router",
            "listen": {"endpoints": [endpoint if upstream is None else robot_listen]},
            "connect": {"endpoints": [] if upstream is None else [endpoint]},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {
                "auth": {
                    "usrpwd": {
                        "user": user,
                        "password": passwords[user],
                        "dictionary_file": str(dictionary.resolve()),
                    }
                }
            },
            "access_control": acl(
                map_id, scouts, planners, servers, tls, bridges, ros_domain, ros_prefix, robots, upstream
            ),  # fmt: skip
        }

    router_conf = {"id": base_zid, **router("router", cred, None)}
    if tls:
        router_conf["transport"]["link"] = {
            "tls": {
                "root_ca_certificate": str(certs["ca"][0].resolve()),
                "enable_mtls": True,
                "listen_certificate": str(certs["router"][0].resolve()),
                "listen_private_key": str(certs["router"][1].resolve()),
            }
        }
    files = {"router": out / "router.json5"}
    files["router"].write_text(json.dumps(router_conf, indent=2))
    robot_files = {}
    for r, local in robots.items():
        rcred = out / f"{r}-credentials.txt"
        rcred.write_text("".join(f"{n}:{passwords[n]}\n" for n in local))
        robot_files[r] = out / f"{r}-router.json5"
        robot_files[r].write_text(json.dumps(router(robot_router_user(r), rcred, base_zid), indent=2))
        files[f"{r}-credentials"] = rcred
    on_robot = {a: robot_listen for agents in robots.values() for a in agents}
    agents = {}
    for n in names:
        agents[n] = out / f"{n}.json5"
        conf = _agent_config(n, passwords[n], "client", on_robot.get(n, endpoint))
        if tls:
            conf["transport"]["link"] = {
                "tls": {
                    "root_ca_certificate": str(certs["ca"][0].resolve()),
                    "enable_mtls": True,
                    "connect_certificate": str(certs[n][0].resolve()),
                    "connect_private_key": str(certs[n][1].resolve()),
                }
            }
        agents[n].write_text(json.dumps(conf, indent=2))
    trust = out / "servers.json"
    trust.write_text(json.dumps({"map": map_id, "servers": list(servers), "trust": "attested"}, indent=2))
    for p in [cred, *files.values(), *agents.values(), *robot_files.values()]:
        p.chmod(0o600)
    return SecureLayout(out, files["router"], agents, cred, trust, robot_files)


def _zid() -> str:
    """A random Zenoh id: 16 bytes in hex, without a leading 0 (Zenoh refuses those)."""
    while (z := secrets.token_hex(16)).startswith("0"):
        pass
    return z


def _ids(text: str) -> list[str]:
    return [t for t in (v.strip() for v in text.split(",")) if t]


def _robot(text: str) -> tuple[str, list[str]]:
    """argparse type of `--robot-router NAME[=ID,...]`."""
    name, _, agents = text.partition("=")
    return name, _ids(agents) if agents else [name]


def register(sub: Subparsers) -> None:
    p = sub.add_parser("secure", help="credentials and access control for a mission's Zenoh network")
    s = p.add_subparsers(dest="secure_command", metavar="ACTION", required=True)
    i = s.add_parser(
        "init",
        help="write the router's and every agent's Zenoh config into DIR",
        description=__doc__.split("\n\n")[0],
    )
    i.add_argument("dir", metavar="DIR", help="output folder (created, owner-only)")
    i.add_argument("--map", required=True, help="map id the ACL covers")
    i.add_argument("--scouts", type=_ids, required=True, metavar="ID,...", help="scout ids")
    i.add_argument("--planners", type=_ids, default=[], metavar="ID,...", help="planner ids")
    i.add_argument(
        "--servers", type=_ids, default=["server"], metavar="ID,...", help="server ids (default server)"
    )
    i.add_argument("--bridges", type=_ids, default=[], metavar="ID,...",
                   help="ROS 2 bridge ids (psrmap ros2: reads the map, publishes its ROS topics)")  # fmt: skip
    i.add_argument("--ros-domain", type=int, default=0, metavar="N",
                   help="the bridges' ROS_DOMAIN_ID (psrmap ros2 --domain; default 0)")  # fmt: skip
    i.add_argument("--ros-prefix", default="/psrmap", metavar="NS",
                   help="the bridges' topic namespace (psrmap ros2 --prefix; default /psrmap)")  # fmt: skip
    i.add_argument("--robot-router", type=_robot, action="append", default=[], metavar="NAME[=ID,...]",
                   help="also write NAME-router.json5: a robot's own router, meshed to the router at --endpoint "
                   "with its own credentials; the agents ID,... (default: the agent NAME) connect to it "
                   "(repeatable)")  # fmt: skip
    i.add_argument("--robot-listen", type=endpoint_arg, default="tcp/127.0.0.1:7447", metavar="ENDPOINT",
                   help="where each robot router listens for its agents (default tcp/127.0.0.1:7447)")  # fmt: skip
    i.add_argument(
        "--endpoint",
        type=endpoint_arg,
        default="tcp/127.0.0.1:7447",
        help="the router's endpoint (agents connect to it)",
    )
    i.add_argument(
        "--tls", action="store_true", help="also require mutual TLS (writes a CA and certificates)"
    )
    i.add_argument("--days", type=int, default=365, help="certificate lifetime with --tls (default 365)")
    i.set_defaults(func=_cmd_init)


def _cmd_init(args: argparse.Namespace) -> int:
    try:
        lay = secure_init(
            args.dir,
            args.map,
            args.scouts,
            args.planners,
            args.servers,
            args.endpoint,
            args.tls,
            args.days,
            args.bridges,
            args.ros_domain,
            args.ros_prefix.rstrip("/") or "/",
            dict(args.robot_router),
            args.robot_listen,
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    print(
        json.dumps(
            {
                "router": str(lay.router),
                "agents": {k: str(v) for k, v in lay.agents.items()},
                "credentials": str(lay.credentials),
                "servers": str(lay.servers),
                "robot_routers": {k: str(v) for k, v in lay.robot_routers.items()},
            },
            indent=2,
        )
    )
    return 0
