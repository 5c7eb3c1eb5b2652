"""`psrmap secure init`: per-agent Zenoh credentials and the router's access control list, with Zenoh's own
machinery (`transport/auth/usrpwd`, `access_control`; mutual TLS as an option).

What each identity may do (everything else is denied by the router):
- a scout `S`: put on `psr/<map>/delta/S` (a sharded map: `psr/<map>/shard/<i>/delta/S`), declare the liveliness
  token `psr/<map>/alive/S`, receive acks on `psr/<map>/ack/S` (`psr/<map>/shard/<i>/ack/S`), see the servers'
  liveliness tokens, ask the map's partition (`psr/<map>/partition`);
- a server: receive every delta, put acks, declare the `map` and `status` queryables and reply to queries,
  declare its token and watch the scouts' tokens;
- a planner: query `psr/<map>/map`, `psr/<map>/status` and `psr/<map>/partition` and receive the replies, and
  subscribe to the tile change notifications `psr/<map>/changes/**` — nothing else.
The files: `credentials.txt` (the router's `user:password` dictionary), `router.json5`, one `<agent>.json5` per
agent holding its user name and password, and `servers.json` ({server: Zenoh id}; each server's config pins its
Zenoh id) from which planners learn whose replies to believe. With `--tls` the router listens on a `tls/`
endpoint and requires mutual TLS as well: `tls/ca.pem` signs the router's certificate (valid for `localhost`,
127.0.0.1 and the endpoint's host) and one client certificate per agent (common name = the agent id), ECDSA P-256,
valid `--days`; a client without a certificate from that CA cannot connect, whatever its password. Rotation: run
`init` again into a new folder (fresh passwords), restart the router with its new file, then each agent with
its own; an agent is revoked by removing its line from `credentials.txt` and restarting the router.
"""

from __future__ import annotations

import json
import secrets
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.session import endpoint_arg
from protocol.keys import validate_id

__all__ = ["SecureLayout", "acl", "register", "secure_init"]

_BOTH = ["ingress", "egress"]


def _rule(rid: str, messages: list[str], keys: list[str]) -> dict[str, Any]:
    return {"id": rid, "messages": messages, "flows": _BOTH, "permission": "allow", "key_exprs": keys}


def acl(
    map_id: str, scouts: Sequence[str], planners: Sequence[str], servers: Sequence[str]
) -> dict[str, Any]:
    """The router's `access_control` section for one map."""
    base = f"psr/{map_id}"
    rules, subjects, policies = [], [], []
    for s in scouts:
        rid = f"scout_{s}"
        rules.append(_rule(f"{rid}_writes", ["put"], [f"{base}/delta/{s}", f"{base}/shard/*/delta/{s}"]))
        # the router must tell the scout that the server subscribes to the deltas (egress only: the scout may
        # not subscribe itself), or Zenoh's write filter stops sending after the first put
        rules.append(
            {
                **_rule(
                    f"{rid}_server_listens",
                    ["declare_subscriber"],
                    [f"{base}/delta/**", f"{base}/shard/*/delta/**"],
                ),
                "flows": ["egress"],
            }
        )
        rules.append(_rule(f"{rid}_token", ["liveliness_token"], [f"{base}/alive/{s}"]))
        rules.append(
            _rule(
                f"{rid}_acks", ["declare_subscriber", "put"], [f"{base}/ack/{s}", f"{base}/shard/*/ack/{s}"]
            )
        )
        rules.append(
            _rule(
                f"{rid}_server_up",
                ["declare_liveliness_subscriber", "liveliness_token", "liveliness_query"],
                [f"{base}/alive/server", f"{base}/alive/server-$*"],
            )
        )
        rules.append(
            _rule(f"{rid}_partition", ["query", "reply", "declare_queryable"], [f"{base}/partition"])
        )
        subjects.append({"id": rid, "usernames": [s]})
        policies.append(
            {
                "rules": [
                    f"{rid}_writes",
                    f"{rid}_server_listens",
                    f"{rid}_token",
                    f"{rid}_acks",
                    f"{rid}_server_up",
                    f"{rid}_partition",
                ],
                "subjects": [rid],
            }
        )
    for s in servers:
        rid = f"server_{s}"
        rules.append(
            _rule(
                rid,
                [
                    "put",
                    "declare_subscriber",
                    "declare_queryable",
                    "query",
                    "reply",
                    "liveliness_token",
                    "liveliness_query",
                    "declare_liveliness_subscriber",
                ],
                [f"{base}/**"],
            )
        )
        subjects.append({"id": rid, "usernames": [s]})
        policies.append({"rules": [rid], "subjects": [rid]})
    for p in planners:
        rid = f"planner_{p}"
        rules.append(
            _rule(
                rid,
                ["query", "reply", "declare_queryable"],
                [f"{base}/map", f"{base}/status", f"{base}/partition"],
            )
        )
        rules.append(
            _rule(
                f"{rid}_server_up",
                ["declare_liveliness_subscriber", "liveliness_token", "liveliness_query"],
                [f"{base}/alive/server", f"{base}/alive/server-$*"],
            )
        )
        rules.append(_rule(f"{rid}_changes", ["declare_subscriber", "put"], [f"{base}/changes/**"]))
        subjects.append({"id": rid, "usernames": [p]})
        policies.append({"rules": [rid, f"{rid}_server_up", f"{rid}_changes"], "subjects": [rid]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


@dataclass(frozen=True)
class SecureLayout:
    """What `secure_init` wrote."""

    folder: Path
    router: Path
    agents: dict[str, Path]  # agent id -> its Zenoh config
    credentials: Path
    servers: Path  # servers.json: server name -> its pinned Zenoh id


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
    import datetime
    import ipaddress

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
) -> SecureLayout:
    """Write the router's and every agent's Zenoh config into `folder` (created; files readable by the owner
    only). Ids must be valid map/agent ids and distinct."""
    validate_id(map_id, "map")
    names = [*scouts, *planners, *servers]
    for n in names:
        validate_id(n, "agent")
    if len(set(names)) != len(names) or "router" in names:
        raise ValueError(f"agent ids must be distinct and not 'router'; got {names}")
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    out.chmod(0o700)
    passwords = {n: secrets.token_urlsafe(24) for n in [*names, "router"]}
    certs: dict[str, tuple[Path, Path]] = {}
    if tls:
        proto, _, addr = endpoint.partition("/")
        endpoint = f"tls/{addr}"
        certs = _write_tls(out / "tls", names, addr.rsplit(":", 1)[0].strip("[]"), days)
    cred = out / "credentials.txt"
    cred.write_text("".join(f"{n}:{pw}\n" for n, pw in passwords.items()))
    router_conf: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "auth": {
                "usrpwd": {
                    "user": "router",
                    "password": passwords["router"],
                    "dictionary_file": str(cred.resolve()),
                }
            }
        },
        "access_control": acl(map_id, scouts, planners, servers),
    }
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
    agents = {}
    zids = {s: _zid() for s in servers}
    for n in names:
        agents[n] = out / f"{n}.json5"
        conf = _agent_config(n, passwords[n], "client", endpoint)
        if tls:
            conf["transport"]["link"] = {
                "tls": {
                    "root_ca_certificate": str(certs["ca"][0].resolve()),
                    "enable_mtls": True,
                    "connect_certificate": str(certs[n][0].resolve()),
                    "connect_private_key": str(certs[n][1].resolve()),
                }
            }
        if n in zids:
            conf["id"] = zids[n]
        agents[n].write_text(json.dumps(conf, indent=2))
    trust = out / "servers.json"
    trust.write_text(json.dumps(zids, indent=2))
    for p in [cred, *files.values(), *agents.values()]:
        p.chmod(0o600)
    return SecureLayout(out, files["router"], agents, cred, trust)


def _zid() -> str:
    """A random Zenoh id: 16 bytes in hex, without a leading 0 (Zenoh refuses those)."""
    while (z := secrets.token_hex(16)).startswith("0"):
        pass
    return z


def _ids(text: str) -> list[str]:
    return [t for t in (v.strip() for v in text.split(",")) if t]


def register(sub: Any) -> None:
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
    i.set_defaults(func=_cmd_init, _parser=i)


def _cmd_init(args: Any) -> int:
    try:
        lay = secure_init(
            args.dir, args.map, args.scouts, args.planners, args.servers, args.endpoint, args.tls, args.days
        )
    except ValueError as exc:
        args._parser.error(str(exc))
    print(
        json.dumps(
            {
                "router": str(lay.router),
                "agents": {k: str(v) for k, v in lay.agents.items()},
                "credentials": str(lay.credentials),
                "servers": str(lay.servers),
            },
            indent=2,
        )
    )
    return 0
