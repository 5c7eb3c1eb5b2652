"""Issue 25: only the server speaks for the map. Each attack of the hostile run, twice:
- refused by the router: a deployment from `psrmap secure init` (role ACL per message kind and direction), seen
  from a session that applies no trust of its own;
- ignored by the clients: an open router (no ACL, so the attack goes through on the wire) and clients whose
  `servers.json` asks them to believe attested servers only (psrmap_common.trust), each saying what it ignored.
Real router, loopback, free ports."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import threading

import msgpack
import numpy as np
import pytest
import zenoh
from helpers import plannable_delta, wait_until

from consumer_planner.client import ClientConfig, RegionWatch, query_region
from map_server.service import MapService, ServerConfig
from protocol import encode
from protocol.keys import (
    alive_key,
    alive_pattern,
    changes_key,
    delta_key,
    map_key,
    partition_key,
    server_id_key,
    server_id_pattern,
    status_key,
)
from protocol.messages import RegionQuery, Status, TileChanges
from protocol.partition import Partition
from protocol.testing import MAP, RES, make_delta
from psrmap.secure import secure_init
from psrmap_common.query import get_partition, get_replies, get_statuses, wait_for_server
from psrmap_common.session import free_endpoint, zenoh_config
from psrmap_common.trust import Trust
from scout_agent.publisher import ScoutPublisher

FAKE_VERSION = 10**12
ATTESTED = Trust(attested=True)


@pytest.fixture
def secured(tmp_path):
    """A router with the role ACL and a map server logged in as `server`; agents s1, s2 (scouts), p1, p2
    (planners), b1 (a ROS 2 bridge)."""
    ep = free_endpoint()
    lay = secure_init(tmp_path / "sec", MAP, ["s1", "s2"], ["p1", "p2"], endpoint=ep, bridges=["b1"])
    with zenoh.open(zenoh_config(config_file=lay.router)):
        cfg = ServerConfig(map_id=MAP, res=RES, db=str(tmp_path / "m.db"), connect=(ep,),
                           zenoh_config=str(lay.agents["server"]))  # fmt: skip
        with MapService(cfg) as service:
            yield ep, lay, service


@pytest.fixture
def open_router(tmp_path):
    """A router without ACL, a map server, and a client config folder whose servers.json asks for attested
    servers (what `psrmap secure init` writes beside every agent's file)."""
    ep = free_endpoint()
    with zenoh.open(zenoh_config(listen=[ep], mode="router")):
        with MapService(ServerConfig(map_id=MAP, res=RES, connect=(ep,))) as service:
            conf = tmp_path / "client.json5"
            conf.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [ep]}}))
            (tmp_path / "servers.json").write_text(json.dumps({"map": MAP, "servers": ["server"],
                                                               "trust": "attested"}))  # fmt: skip
            yield ep, conf, service


def _open(lay, who: str):
    return zenoh.open(zenoh_config(config_file=lay.agents[who]))


def _plain(ep: str):
    return zenoh.open(zenoh_config(connect=[ep], mode="client"))


def _heard(session, key: str, zid: str) -> bool:
    """Wait until a reply from `zid` on `key` comes back (the impostor's queryable reached the router)."""
    return wait_until(lambda: any(str(r.replier_id.zid) == zid for r in session.get(key, timeout=1.0,
                 target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE) if r.replier_id))  # fmt: skip


def _settle() -> None:
    """Time for a declaration the router refuses to have reached it (nothing to wait on: it never shows)."""
    threading.Event().wait(0.5)


def _fake_status() -> bytes:
    return encode(Status(MAP, RES, FAKE_VERSION, 5, 10**9, 0, {}, {}, {"worker": "ok"}))


def _impostor_queryables(session, region) -> list:
    def status(q):
        with q:
            q.reply(status_key(MAP), _fake_status())

    def region_reply(q):
        with q:
            q.reply(map_key(MAP), encode(region))

    return [
        session.declare_queryable(status_key(MAP), status),
        session.declare_queryable(map_key(MAP), region_reply),
    ]


def _fake_region(service):
    fake = service.region(RegionQuery(0, 0, 0.3, 0.3, ("slip",), ("all",)))
    fake.layers["slip"]["n"][:] = 1e9  # every cell of the box known, slip 0.777
    fake.layers["slip"]["events"][:] = 0.777e9
    return fake


def _feed(service, ep, lay=None) -> None:
    """One real delta merged (cell 0,0), so a real map reply exists."""
    file = str(lay.agents["s1"]) if lay is not None else None
    with ScoutPublisher(MAP, "s1", RES, [ep], outbox=None, zenoh_config_file=file) as pub:
        assert pub.link.server_up.wait(10)
        d = make_delta(seq=0, scout="s1", layers=("slip",), cells=((0, 0),))
        pub.send(d.layers, d.t)
        assert pub.wait_acked(10)
    assert service.status().merged == 1


# ---------------------------------------------------------------------------------------- impostor queryable


def test_router_refuses_map_and_status_queryables_of_a_planner(secured):
    ep, lay, service = secured
    _feed(service, ep, lay)
    with _open(lay, "p1") as imp, _open(lay, "p2") as p2:
        ents = _impostor_queryables(imp, _fake_region(service))
        _settle()
        # no trust of its own: whatever comes back is what the router let through
        sts = get_statuses(p2, MAP, 3.0)
        assert [s.version for s in sts] == [service.status().version]
        replies = get_replies(p2, f"{map_key(MAP)}?x0=0;y0=0;x1=0.3;y1=0.3;stats=all", 3.0, fan_out=True)
        assert len(replies.ok) == 1
        for e in ents:
            e.undeclare()


def test_clients_ignore_an_impostor_queryable_and_say_so(open_router, caplog):
    ep, conf, service = open_router
    _feed(service, ep)
    with _plain(ep) as imp, _plain(ep) as p2:
        held = _impostor_queryables(imp, _fake_region(service))
        assert _heard(p2, status_key(MAP), str(imp.info.zid())) and _heard(
            p2, map_key(MAP), str(imp.info.zid())
        )
        assert FAKE_VERSION in [s.version for s in get_statuses(p2, MAP, 3.0)]  # without trust: fooled
        with caplog.at_level(logging.WARNING, logger="psrmap_common.trust"):
            sts = get_statuses(p2, MAP, 3.0, ATTESTED)
        assert [s.version for s in sts] == [service.status().version]
        assert f"ignored a reply on {status_key(MAP)!r} from Zenoh id {imp.info.zid()}" in caplog.text
        grid = query_region(p2, MAP, (0, 0, 0.3, 0.3), ClientConfig(zenoh_config=str(conf)), layers=("slip",))
        assert float(np.nanmax(grid.layers["slip"]["n"])) < 1e9
        base = [sys.executable, "-m", "psrmap"]
        args = ["--map", MAP, "--connect", ep, "--zenoh-config", str(conf), "--timeout", "3"]
        st = subprocess.run([*base, "status", *args], capture_output=True, text=True, timeout=60, check=False)
        assert st.returncode == 0, st.stderr
        assert json.loads(st.stdout)["version"] == service.status().version
        assert f"ignored a reply on {status_key(MAP)!r} from Zenoh id {imp.info.zid()}" in st.stderr
        q = subprocess.run([*base, "query", *args, "--box", "0,0,0.3,0.3", "--layers", "slip",
                            "--stats", "value,n"], capture_output=True, text=True, timeout=60, check=False)  # fmt: skip
        assert q.returncode == 0, q.stderr
        assert (
            json.loads(q.stdout)["layers"]["slip"]["cells_with_data"] == 1
        )  # the real cell, not 0.777 in all
        assert f"from Zenoh id {imp.info.zid()}" in q.stderr
        assert held


# ---------------------------------------------------------------------------------------- partition reply


def _lie_partition(session) -> object:
    def lie(q):
        with q:
            q.reply(partition_key(MAP), msgpack.packb(Partition(3, 8).to_dict()))

    return session.declare_queryable(partition_key(MAP), lie)


def test_router_refuses_partition_replies_of_scouts_and_planners(secured):
    ep, lay, service = secured
    with _open(lay, "s2") as s2, _open(lay, "p1") as p1, _open(lay, "p2") as p2:
        ents = [_lie_partition(s2), _lie_partition(p1)]
        _settle()
        assert get_partition(p2, MAP, 3.0) == Partition()  # servers disagreeing would raise
        with ScoutPublisher(
            MAP, "s1", RES, [ep], outbox=None, zenoh_config_file=str(lay.agents["s1"])
        ) as pub:
            assert pub.partition == Partition()
        for e in ents:
            e.undeclare()


def test_a_scout_ignores_partition_replies_of_others(open_router, caplog):
    ep, conf, service = open_router
    with _plain(ep) as imp, _plain(ep) as c:
        held = _lie_partition(imp)
        assert _heard(c, partition_key(MAP), str(imp.info.zid()))
        with pytest.raises(Exception, match="different partitions"):  # without trust: the fleet cannot start
            get_partition(c, MAP, 3.0)
        with caplog.at_level(logging.WARNING, logger="psrmap_common.trust"):
            with ScoutPublisher(MAP, "s1", RES, [ep], outbox=None, zenoh_config_file=str(conf)) as pub:
                assert pub.partition == Partition()
        assert f"ignored a reply on {partition_key(MAP)!r} from Zenoh id {imp.info.zid()}" in caplog.text
        assert held


# ---------------------------------------------------------------------------------------- server tokens


def test_router_refuses_server_tokens_of_scouts_and_planners(tmp_path):
    ep = free_endpoint()
    lay = secure_init(tmp_path / "sec", MAP, ["s1"], ["p1", "p2"], endpoint=ep)
    with zenoh.open(zenoh_config(config_file=lay.router)):
        with _open(lay, "s1") as s1, _open(lay, "p1") as p1, _open(lay, "p2") as p2:
            held = []  # a token lives as long as its object
            for s in (s1, p1):
                for who in ("server", "server-0"):
                    held.append(s.liveliness().declare_token(alive_key(MAP, who)))
                held.append(s.liveliness().declare_token(server_id_key(MAP, str(s.info.zid()))))
            held.append(s1.liveliness().declare_token(alive_key(MAP, "s1")))  # its own: allowed
            _settle()

            def tokens() -> list[str]:
                return [str(r.ok.key_expr) for k in (alive_pattern(MAP), server_id_pattern(MAP))
                        for r in p2.liveliness().get(k, timeout=2) if r.ok is not None]  # fmt: skip

            assert wait_until(lambda: len(tokens()) == 1)
            assert tokens() == [alive_key(MAP, "s1")]
            assert not wait_for_server(p2, MAP, 1.0) and not wait_for_server(p2, MAP, 1.0, shard=0)
            assert get_statuses(p2, MAP, 1.0, ATTESTED) == []  # and nobody is attested as a server


# ---------------------------------------------------------------------------------------- tile-change notices


def _fake_notice() -> bytes:
    return encode(TileChanges(MAP, None, FAKE_VERSION, RES, 64, np.array([[0, 0]], np.int32)))


def test_router_refuses_tile_change_notices_of_a_planner(secured):
    ep, lay, service = secured
    with _open(lay, "p1") as p1, _open(lay, "p2") as p2, RegionWatch(p2, MAP, RES, (0, 0, 1, 1)) as watch:
        _settle()  # the watch's subscription has reached the router
        p1.put(changes_key(MAP), _fake_notice())
        p1.declare_publisher(changes_key(MAP)).put(_fake_notice())
        _feed(service, ep, lay)  # a real notice follows
        assert wait_until(lambda: bool(watch.versions))
        changes = watch.changed(1.0)
        assert changes and all(c.version < FAKE_VERSION for c in changes)
        assert watch.versions[None] < FAKE_VERSION


def test_a_watch_ignores_notices_from_others(open_router, caplog):
    ep, conf, service = open_router
    with _plain(ep) as imp, _plain(ep) as c, RegionWatch(c, MAP, RES, (0, 0, 1, 1), ATTESTED) as watch:
        pub = imp.declare_publisher(changes_key(MAP))

        def impostor_heard() -> bool:
            # resent until the watch has heard both (its subscription may reach the router after the first put)
            imp.put(changes_key(MAP), _fake_notice())  # no sender id
            pub.put(_fake_notice(), source_info=zenoh.SourceInfo(pub.id, 1))  # its own id
            return (
                "it carries no sender id" in caplog.text and f"from Zenoh id {imp.info.zid()}" in caplog.text
            )

        with caplog.at_level(logging.WARNING, logger="psrmap_common.trust"):
            assert wait_until(impostor_heard, poll_s=0.2), caplog.text
        assert watch.ignored >= 2 and not watch.versions  # every notice heard was ignored, none taken
        _feed(service, ep)
        assert wait_until(lambda: bool(watch.versions))
        changes = watch.changed(1.0)
        assert changes and all(c.version < FAKE_VERSION for c in changes)


def test_a_watching_planner_does_not_replan_on_notices_from_others(open_router):
    """`psrmap plan --watch` with a servers.json: an impostor's notices inside the corridor cost no replan; the
    server's own notice for a real change triggers exactly one."""
    from consumer_planner.component import MapSource, PlanConfig, watch_plan

    ep, conf, service = open_router

    delta = plannable_delta

    cfg = PlanConfig(MapSource(map_id=MAP, connect=(ep,), zenoh_config=str(conf), margin_m=0.4), (0.0, 0.0),
                     (3.0, 0.8))  # fmt: skip
    plans: list = []
    stop = threading.Event()
    with ScoutPublisher(MAP, "s1", RES, [ep], outbox=None) as pub, _plain(ep) as imp:
        first = delta(0, [(2, 1), (3, 1)])
        assert pub.send(first.layers, first.t) and pub.wait_acked(10)
        out: list = []
        t = threading.Thread(target=lambda: out.append(watch_plan(cfg, lambda *a: plans.append(a), stop,
                                                                  resync_s=60.0, period_s=0.05)), daemon=True)  # fmt: skip
        t.start()
        try:
            assert wait_until(lambda: len(plans) == 1)
            _settle()  # the watch's subscription has reached the router
            fake = imp.declare_publisher(changes_key(MAP))
            for k in range(5):  # the corridor's tile, a version far ahead, its own id and none
                fake.put(_fake_notice(), source_info=zenoh.SourceInfo(fake.id, k))
                imp.put(changes_key(MAP), _fake_notice())
            threading.Event().wait(1.0)  # 20 periods of the watch
            n_after_fake = len(plans)
            near = delta(1, [(5, 2)])
            assert pub.send(near.layers, near.t) and pub.wait_acked(10)
            assert wait_until(lambda: len(plans) == 2, 5.0)
        finally:
            stop.set()
            t.join(timeout=20)
    assert n_after_fake == 1
    assert plans[1][0] is not None and all(c.version < FAKE_VERSION for c in plans[1][2]), plans[1][1]
    assert out[0].plans == 2 and out[0].resyncs == 0


# ---------------------------------------------------------------------------------------- id takeover


def test_a_server_id_cannot_be_taken_over_while_the_server_is_down(tmp_path):
    """The impostor opens a session with the stopped server's Zenoh id and serves a fake map: the real server
    still starts (with a fresh id), the router refuses the impostor's queryables, and clients believe the
    restarted server only."""
    ep = free_endpoint()
    lay = secure_init(tmp_path / "sec", MAP, ["s1"], ["p1", "p2"], endpoint=ep)
    cfg = ServerConfig(map_id=MAP, res=RES, db=str(tmp_path / "m.db"), connect=(ep,),
                       zenoh_config=str(lay.agents["server"]))  # fmt: skip
    with zenoh.open(zenoh_config(config_file=lay.router)), _open(lay, "p2") as p2:
        with MapService(cfg) as service:
            _feed(service, ep, lay)
            old = str(service._session.info.zid())
            version = service.status().version
        conf = zenoh_config(config_file=lay.agents["p1"])
        conf.insert_json5("id", json.dumps(old))
        with zenoh.open(conf) as imp:
            assert str(imp.info.zid()) == old
            fake = MapService(
                ServerConfig(map_id=MAP, res=RES, connect=(ep,), zenoh_config=str(lay.agents["server"]))
            )
            with fake:  # an honest-looking map to copy a reply shape from (its own fresh id, server creds)
                region = _fake_region(fake)
            held = _impostor_queryables(imp, region)
            _settle()
            with MapService(cfg) as service:  # the real server starts while the impostor holds the old id
                new = str(service._session.info.zid())
                assert new != old
                sts = get_statuses(p2, MAP, 3.0)  # the router alone: only the real server answers
                assert [(s.version, s.merged) for s in sts] == [(version, 1)]
                client = ClientConfig(connect=(ep,), zenoh_config=str(lay.agents["p2"]))
                assert client.believed().attested
                grid = query_region(p2, MAP, (0, 0, 0.3, 0.3), client, layers=("slip",))
                assert float(np.nanmax(grid.layers["slip"]["n"])) < 1e9
            assert held


def test_clients_do_not_believe_a_stopped_servers_id(tmp_path, caplog):
    """Open router: the impostor holds the old id and answers, the restarted server has a new, attested id."""
    ep = free_endpoint()
    with zenoh.open(zenoh_config(listen=[ep], mode="router")), _plain(ep) as c:
        with MapService(ServerConfig(map_id=MAP, res=RES, connect=(ep,))) as service:
            old = str(service._session.info.zid())
        conf = zenoh_config(connect=[ep], mode="client")
        conf.insert_json5("id", json.dumps(old))
        with zenoh.open(conf) as imp, MapService(ServerConfig(map_id=MAP, res=RES, connect=(ep,))) as service:

            def status(q):
                with q:
                    q.reply(status_key(MAP), _fake_status())

            held = imp.declare_queryable(status_key(MAP), status)
            assert _heard(c, status_key(MAP), old)
            assert FAKE_VERSION in [
                s.version for s in get_statuses(c, MAP, 3.0, (old,))
            ]  # a pinned id: fooled
            with caplog.at_level(logging.WARNING, logger="psrmap_common.trust"):
                sts = get_statuses(c, MAP, 3.0, ATTESTED)
            assert [s.version for s in sts] == [service.status().version]
            assert f"from Zenoh id {old}" in caplog.text
            held.undeclare()


# ---------------------------------------------------------------------------------------- mTLS identity


def test_a_planners_certificate_cannot_carry_a_scouts_password(tmp_path):
    ep = free_endpoint().replace("tcp/127.0.0.1", "tcp/localhost")
    lay = secure_init(tmp_path / "sec", MAP, ["s1"], ["p1"], endpoint=ep, tls=True)
    tls_ep = json.loads(lay.agents["s1"].read_text())["connect"]["endpoints"][0]
    with zenoh.open(zenoh_config(config_file=lay.router)):
        cfg = ServerConfig(map_id=MAP, res=RES, connect=(tls_ep,), zenoh_config=str(lay.agents["server"]))
        with MapService(cfg) as service:
            mixed = zenoh_config(config_file=lay.agents["s1"])  # s1's user and password ...
            p1_tls = json.loads(lay.agents["p1"].read_text())["transport"]["link"]["tls"]
            for k in ("connect_certificate", "connect_private_key"):  # ... with p1's certificate
                mixed.insert_json5(f"transport/link/tls/{k}", json.dumps(p1_tls[k]))
            with zenoh.open(mixed) as m:
                m.put(delta_key(MAP, "s1"), encode(make_delta(seq=0, scout="s1", layers=("slip",))))
                token = m.liveliness().declare_token(alive_key(MAP, "s1"))
                assert not wait_until(lambda: service.alive.get("s1", False), 1.0)
                token.undeclare()
            # the matching pair still works, and its delta is the only one merged
            with ScoutPublisher(MAP, "s1", RES, [tls_ep], outbox=None,
                                zenoh_config_file=str(lay.agents["s1"])) as pub:  # fmt: skip
                assert pub.link.server_up.wait(10)
                d = make_delta(seq=0, scout="s1", layers=("slip",), cells=((5, 5),))
                pub.send(d.layers, d.t)
                assert pub.wait_acked(10)
            st = service.status()
            assert st.merged == 1 and service.map.cells == 1


# ---------------------------------------------------------------------------------------- the roles table


def test_the_acl_grants_each_role_only_its_table_and_the_readme_shows_it(tmp_path):
    from pathlib import Path

    from psrmap.ros2 import ros_keys
    from psrmap.secure import acl, roles_table

    a = acl(MAP, ["s1"], ["p1"], ["m0"], tls=True, bridges=["b1"])
    rules = {r["id"]: r for r in a["rules"]}
    by_subject = {p["subjects"][0]: [rules[i] for i in p["rules"]] for p in a["policies"]}
    sent = {s: {(m, k) for r in rs if r["flows"] == ["ingress"] for m in r["messages"] for k in r["key_exprs"]}
            for s, rs in by_subject.items()}  # fmt: skip
    speak = {"declare_queryable", "reply", "put", "liveliness_token"}
    assert not {m for m, _ in sent["reader_p1"]} & speak  # a reader only asks and listens
    assert {k for m, k in sent["scout_s1"] if m in speak} == {
        f"psr/{MAP}/delta/s1", f"psr/{MAP}/shard/*/delta/s1", f"psr/{MAP}/alive/s1"}  # fmt: skip
    assert ("declare_queryable", f"psr/{MAP}/partition") in sent["server_m0"]
    # a bridge speaks only on its ROS topics (their caches) and its graph tokens, never on the map's keys
    bridge_speaks = {k for m, k in sent["bridge_b1"] if m in speak}
    assert not {k for k in bridge_speaks if k.startswith("psr/")}
    topics = ros_keys()["<topic>"]
    assert bridge_speaks == {*topics, *(f"{t}/@adv/pub/**" for t in topics), *ros_keys()["<topic_token>"],
                             *ros_keys()["<node_token>"]}  # fmt: skip
    assert {(m, k) for m, k in sent["reader_p1"]} <= sent["bridge_b1"]  # and what a reader may
    assert all(s["cert_common_names"] == s["usernames"] for s in a["subjects"])  # certificate = user
    readme = Path(__file__).resolve().parents[2] / "README.md"
    assert roles_table() in readme.read_text()


# ---------------------------------------------------------------------------------------- the ROS 2 bridge


def test_a_secured_bridge_publishes_ros_topics_a_planner_reads_but_speaks_for_no_map(secured):
    """`psrmap ros2` with `secure init --bridges` credentials: its grid map reaches an independent subscriber
    logged in as a planner (live and, joining late, from the publication cache), and its graph tokens are seen;
    the same credentials cannot put a delta nor answer the map queryable (the router refuses both)."""
    import zenoh.ext as zext

    from psrmap.ros2 import BridgeConfig, ros_keys, run_bridge

    ep, lay, service = secured
    _feed(service, ep, lay)
    grid_key = ros_keys()["<topic>"][0]
    live: list[bytes] = []
    stop = threading.Event()
    done: list[dict] = []
    bcfg = BridgeConfig(MAP, None, (ep,), zenoh_config=str(lay.agents["b1"]))
    t = threading.Thread(target=lambda: done.append(run_bridge(bcfg, stop, log=lambda *a: None)), daemon=True)
    with _open(lay, "p1") as p1:
        sub = p1.declare_subscriber(grid_key, lambda s: live.append(s.payload.to_bytes()))
        t.start()
        try:
            assert wait_until(lambda: bool(live), 20.0), "the planner received no grid map"
            tokens = [str(r.ok.key_expr) for r in p1.liveliness().get("@ros2_lv/0/**", timeout=3.0) if r.ok]
            assert any("/NN/%/%/psrmap_bridge" in k for k in tokens), tokens
            assert any("/MP/%/%/psrmap_bridge/%psrmap%grid_map/" in k for k in tokens), tokens
            late: list[bytes] = []  # joins after the map was published: served from the bridge's cache
            with _open(lay, "p2") as p2:
                asub = zext.declare_advanced_subscriber(
                    p2, grid_key, lambda s: late.append(s.payload.to_bytes()),
                    history=zext.HistoryConfig(detect_late_publishers=True, max_samples=1))  # fmt: skip
                assert wait_until(lambda: bool(late), 10.0), "a late planner got nothing from the cache"
                asub.undeclare()
            assert late[0] == live[0] and late[0][:4] == b"\x00\x01\x00\x00"  # CDR little endian
            # the bridge's credentials speak for no map: a delta and a map queryable are refused
            with _open(lay, "b1") as b1:
                b1.put(delta_key(MAP, "b1"), encode(make_delta(seq=0, scout="b1", layers=("slip",),
                                                               cells=((5, 5),))))  # fmt: skip
                b1.put(delta_key(MAP, "s1"), encode(make_delta(seq=7, scout="s1", layers=("slip",),
                                                               cells=((6, 6),))))  # fmt: skip
                q = b1.declare_queryable(map_key(MAP), lambda q: q.reply(map_key(MAP), b"fake"))
                _settle()
                replies = get_replies(p1, f"{map_key(MAP)}?x0=0;y0=0;x1=0.3;y1=0.3;stats=all", 3.0,
                                      fan_out=True)  # fmt: skip
                assert len(replies.ok) == 1 and service.status().merged == 1
                q.undeclare()
        finally:
            stop.set()
            t.join(timeout=20)
            sub.undeclare()
    assert done and done[0]["published"]["grid_map"] >= 1


def test_a_bridge_logged_in_as_a_planner_is_refused_its_topics(secured):
    """The reason for the bridge role: a planner's credentials may read ROS topics but not publish them."""
    from psrmap.ros2 import BridgeConfig, ros_keys, run_bridge

    ep, lay, service = secured
    _feed(service, ep, lay)
    live: list[bytes] = []
    with _open(lay, "p1") as p1:
        sub = p1.declare_subscriber(ros_keys()["<topic>"][0], lambda s: live.append(s.payload.to_bytes()))
        bcfg = BridgeConfig(MAP, None, (ep,), zenoh_config=str(lay.agents["p2"]), once=True, linger_s=2.0)
        out = run_bridge(bcfg, log=lambda *a: None)
        sub.undeclare()
    assert out["published"]["grid_map"] == 1 and not live
