"""Issue 12: only known agents write, ack and answer — with Zenoh's own credentials and a router ACL written by
`psrmap secure init`; a planner believes only the map servers it was told about."""

from __future__ import annotations

import json
import subprocess
import sys
import threading

import numpy as np
import pytest
import zenoh
from helpers import wait_until

from consumer_planner.client import ClientConfig, query_region
from consumer_planner.errors import PlannerError
from map_server.service import MapService, ServerConfig
from protocol import encode
from protocol.keys import ack_key, delta_key, map_key
from protocol.messages import Ack, RegionQuery
from protocol.testing import MAP, RES, make_delta
from psrmap.secure import secure_init
from psrmap_common.query import wait_for_server
from psrmap_common.session import free_endpoint, zenoh_config
from psrmap_common.trust import Trust, load_trust
from scout_agent.publisher import ScoutPublisher


@pytest.fixture
def secured(tmp_path):
    """A router with credentials + ACL, and a map server logged in as `server`."""
    ep = free_endpoint()
    lay = secure_init(tmp_path / "sec", MAP, ["s1", "s2"], ["p1"], endpoint=ep)
    with zenoh.open(zenoh_config(config_file=lay.router)):
        cfg = ServerConfig(
            map_id=MAP,
            res=RES,
            db=str(tmp_path / "m.db"),
            connect=(ep,),
            zenoh_config=str(lay.agents["server"]),
        )
        with MapService(cfg) as service:
            yield ep, lay, service


def _open(lay, who: str):
    return zenoh.open(zenoh_config(config_file=lay.agents[who]))


def test_anonymous_and_wrong_password_are_refused(secured):
    ep, lay, _ = secured
    with pytest.raises(zenoh.ZError):
        zenoh.open(zenoh_config(connect=[ep], mode="client"))
    conf = zenoh_config(config_file=lay.agents["s1"])
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps("not-the-password"))
    with pytest.raises(zenoh.ZError):
        zenoh.open(conf)


def test_a_scout_writes_only_its_own_key_and_cannot_ack_for_another(secured):
    ep, lay, service = secured
    with (
        _open(lay, "s2") as s2,
        _open(lay, "p1") as p1,
        ScoutPublisher(MAP, "s1", RES, [ep], outbox=None, zenoh_config_file=str(lay.agents["s1"])) as pub,
    ):
        assert pub.link.server_up.wait(10)
        acks_seen_by_s2: list[bytes] = []
        s2.declare_subscriber(ack_key(MAP, "s2"), lambda s: acks_seen_by_s2.append(s.payload.to_bytes()))
        d = make_delta(seq=0, scout="s1", layers=("slip",))
        pub.send(d.layers, d.t)
        assert pub.wait_acked(10)  # its own key: merged and acked
        forged = encode(make_delta(seq=0, scout="s2", layers=("slip",)))
        # s1 publishing as s2 (on s2's key), the planner publishing a delta, s1 forging an ack for s2
        pub._session.put(delta_key(MAP, "s2"), forged)
        p1.put(delta_key(MAP, "s2"), forged)
        pub._session.put(ack_key(MAP, "s2"), encode(Ack(MAP, "s2", 7, 10**12)))
        d = make_delta(seq=1, scout="s1", layers=("slip",), cells=((9, 9),))
        pub.send(d.layers, d.t)  # a marker: once it is merged, the blocked puts had their chance
        assert pub.wait_acked(10)
        st = service.status()
        assert st.merged == 2 and set(st.scouts) <= {"s1", "s2"} and "s2" not in service.merger.book.latest()
        assert acks_seen_by_s2 == []


def test_the_planner_queries_and_a_rogue_queryable_is_not_heard(secured):
    ep, lay, service = secured
    with ScoutPublisher(MAP, "s1", RES, [ep], outbox=None, zenoh_config_file=str(lay.agents["s1"])) as pub:
        assert pub.link.server_up.wait(10)
        d = make_delta(seq=0, scout="s1", layers=("slip",), cells=((0, 0),))
        pub.send(d.layers, d.t)
        assert pub.wait_acked(10)
    fake = service.region(RegionQuery(0, 0, 0.3, 0.3, ("slip",), ("all",)))
    fake.layers["slip"]["n"][:] = 1e9  # the largest count used to win the planner's stitching
    with _open(lay, "s2") as rogue, _open(lay, "p1") as p1:

        def lie(query):
            with query:
                query.reply(map_key(MAP), encode(fake))

        rogue.declare_queryable(map_key(MAP), lie)
        grid = query_region(p1, MAP, (0, 0, 0.3, 0.3), ClientConfig(connect=(ep,)), layers=("slip",))
        assert float(np.nansum(grid.layers["slip"]["n"])) == float(d.layers["slip"]["n"].sum())


def test_a_planner_believes_only_its_trusted_servers(tmp_path):
    """Without the router's ACL (say, a misconfigured router), the planner still ignores other repliers."""
    ep = free_endpoint()
    with zenoh.open(zenoh_config(listen=[ep], mode="router")):
        cfg = ServerConfig(map_id=MAP, res=RES, connect=(ep,))
        with (
            MapService(cfg) as service,
            zenoh.open(zenoh_config(connect=[ep], mode="client")) as rogue,
            zenoh.open(zenoh_config(connect=[ep], mode="client")) as client,
        ):
            assert wait_for_server(client, MAP)
            region = service.region(RegionQuery(0, 0, 0.3, 0.3, ("slip",), ("all",)))
            region.layers["slip"]["n"][:] = 1e9  # "the largest count wins" made this win the stitching
            rogue.declare_queryable(map_key(MAP), lambda q: q.reply(map_key(MAP), encode(region)))
            server_zid = str(service._session.info.zid())
            grid = query_region(
                client, MAP, (0, 0, 0.3, 0.3), ClientConfig(trusted_servers=(server_zid,)), layers=("slip",)
            )
            assert float(np.nanmax(grid.layers["slip"]["n"])) < 1e9
            with pytest.raises(PlannerError, match="not a trusted map server"):
                query_region(
                    client, MAP, (0, 0, 0.3, 0.3), ClientConfig(trusted_servers=("0" * 32,)), layers=("slip",)
                )


def test_secure_init_asks_clients_to_believe_attested_servers(tmp_path):
    lay = secure_init(tmp_path / "s", MAP, ["s1"], ["p1"])
    assert load_trust(str(lay.servers)) == Trust(attested=True, source=str(lay.servers))
    assert load_trust(None, lay.agents["p1"]).attested  # found beside the agent's file
    assert "id" not in json.loads(lay.agents["server"].read_text())  # nothing pinned: nothing to squat
    assert (lay.credentials.stat().st_mode & 0o077) == 0  # owner-only
    with pytest.raises(ValueError, match="distinct"):
        secure_init(tmp_path / "t", MAP, ["s1"], ["s1"])
    with pytest.raises(ValueError, match="no such file"):
        load_trust(str(tmp_path / "nope.json"))


def test_listening_beyond_loopback_needs_credentials_or_insecure():
    port = free_endpoint().rsplit(":", 1)[1]
    res = subprocess.run(
        [sys.executable, "-m", "psrmap", "router", "--listen", f"tcp/0.0.0.0:{port}"],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 2 and "without credentials" in res.stderr and "--insecure" in res.stderr


def test_mutual_tls_admits_only_clients_with_a_certificate_from_the_ca(tmp_path):
    ep = free_endpoint().replace("tcp/127.0.0.1", "tcp/localhost")
    lay = secure_init(tmp_path / "sec", MAP, ["s1"], ["p1"], endpoint=ep, tls=True)
    router = json.loads(lay.router.read_text())
    assert (
        router["listen"]["endpoints"][0].startswith("tls/")
        and router["transport"]["link"]["tls"]["enable_mtls"]
    )
    with zenoh.open(zenoh_config(config_file=lay.router)):
        with zenoh.open(zenoh_config(config_file=lay.agents["s1"])) as s1:  # certificate + password
            assert str(s1.info.zid())
        conf = zenoh_config(config_file=lay.agents["s1"])
        conf.insert_json5("transport/link/tls/connect_certificate", json.dumps(""))
        conf.insert_json5("transport/link/tls/connect_private_key", json.dumps(""))
        with pytest.raises(zenoh.ZError):  # the right password, but no client certificate
            zenoh.open(conf)


def test_a_sharded_map_works_under_the_acl(tmp_path):
    """Two shard servers with their own identities; a scout discovers the partition, writes each shard its own
    part on its own keys and gets acks; a planner reads the stitched map and the tile changes."""
    from consumer_planner.client import RegionWatch
    from protocol.partition import Partition
    from psrmap_common.query import get_status

    ep = free_endpoint()
    lay = secure_init(tmp_path / "sec", MAP, ["s1"], ["p1"], servers=["m0", "m1"], endpoint=ep)
    with zenoh.open(zenoh_config(config_file=lay.router)):
        cfgs = [
            ServerConfig(map_id=MAP, res=RES, tile=8, connect=(ep,), zenoh_config=str(lay.agents[f"m{i}"]),
                         shards=2, shard=i)
            for i in range(2)
        ]  # fmt: skip
        with MapService(cfgs[0]), MapService(cfgs[1]), _open(lay, "p1") as p1:
            for i in range(2):
                assert wait_for_server(p1, MAP, shard=i)
            with RegionWatch(p1, MAP, RES, (0.0, 0.0, 10.0, 1.0)) as watch:
                with ScoutPublisher(
                    MAP, "s1", RES, [ep], outbox=None, zenoh_config_file=str(lay.agents["s1"])
                ) as pub:
                    assert pub.partition == Partition(2, 8)
                    d = make_delta(seq=0, scout="s1", layers=("slip",), cells=((0, 0), (9, 0)))  # both shards
                    assert pub.send(d.layers, d.t) == 2
                    assert pub.wait_acked(10)
                assert wait_until(lambda: len({c.shard for c in watch.changed(0.2)}) > 0)
            st = get_status(p1, MAP)
            assert st is not None and st.merged == 2 and st.cells == 2 and st.health["shards_answered"] == 2
            grid = query_region(p1, MAP, (0.0, 0.0, 4.0, 0.3), ClientConfig(connect=(ep,)))
            assert int(np.count_nonzero(grid.layers["slip"]["n"] > 0)) == 2


def test_robot_routers_mesh_to_the_base_with_their_own_credentials(tmp_path):
    """`secure init --robot-router s1 --robot-router rover=p1`: a base router (two shards on it), robot routers
    connected to it as `s1-router` / `rover-router`. The scout on its robot's router merges into the base's
    shards and is acked; the planner on the rover's router reads the map; an anonymous client on a robot router
    is refused; the robot router's link may carry only what its own agents may (the base refuses a delta of
    s2 coming through s1's router), and a robot router's password is not an agent's."""
    from protocol.partition import Partition
    from psrmap_common.query import get_status

    base_ep, s1_ep, rover_ep = free_endpoint(), free_endpoint(), free_endpoint()
    lay = secure_init(tmp_path / "sec", MAP, ["s1", "s2"], ["p1"], servers=["m0", "m1"], endpoint=base_ep,
                      robots={"s1": ["s1"], "rover": ["p1"]})  # fmt: skip
    assert json.loads(lay.agents["s1"].read_text())["connect"]["endpoints"] == ["tcp/127.0.0.1:7447"]
    assert sorted(p.name for p in lay.robot_routers.values()) == ["rover-router.json5", "s1-router.json5"]

    def robot(name: str, ep: str):  # listens on a free port here, instead of the file's 7447
        return zenoh.open(zenoh_config(listen=[ep], config_file=lay.robot_routers[name]))

    with zenoh.open(zenoh_config(config_file=lay.router)):
        cfgs = [ServerConfig(map_id=MAP, res=RES, tile=8, connect=(base_ep,), shards=2, shard=i,
                             zenoh_config=str(lay.agents[f"m{i}"])) for i in range(2)]  # fmt: skip
        with MapService(cfgs[0]) as m0, MapService(cfgs[1]), robot("s1", s1_ep), robot("rover", rover_ep):
            with pytest.raises(zenoh.ZError):  # anonymous on a robot router
                zenoh.open(zenoh_config(connect=[s1_ep], mode="client"))
            for who in ("s2", "p1"):  # agents of another robot (or of the base) cannot log in to s1's router
                with pytest.raises(zenoh.ZError):
                    zenoh.open(zenoh_config(connect=[s1_ep], config_file=lay.agents[who]))
            with ScoutPublisher(MAP, "s1", RES, [s1_ep], outbox=None,
                                zenoh_config_file=str(lay.agents["s1"])) as pub:  # fmt: skip
                assert pub.link.server_up.wait(20) and pub.partition == Partition(2, 8)
                d = make_delta(seq=0, scout="s1", layers=("slip",), cells=((0, 0), (9, 0)))  # both shards
                assert pub.send(d.layers, d.t) == 2
                assert pub.wait_acked(20)
            with zenoh.open(zenoh_config(connect=[rover_ep], config_file=lay.agents["p1"])) as p1:
                st = get_status(p1, MAP)
                assert st is not None and st.merged == 2 and st.health["shards_answered"] == 2
                grid = query_region(p1, MAP, (0.0, 0.0, 4.0, 0.3),
                                    ClientConfig(connect=(rover_ep,), zenoh_config=str(lay.agents["p1"])))  # fmt: skip
                assert int(np.count_nonzero(grid.layers["slip"]["n"] > 0)) == 2
                # s1 (on its router) writes as s2: s1's router refuses it, and so would the base
                with zenoh.open(zenoh_config(connect=[s1_ep], config_file=lay.agents["s1"])) as s1:
                    s1.put(delta_key(MAP, "s2"), encode(make_delta(seq=0, scout="s2", layers=("slip",),
                                                                   cells=((1, 1),))))  # fmt: skip
                    threading.Event().wait(1.0)
                assert get_status(p1, MAP).merged == 2
            # the robot router's own user, logged in to the base as a client, may do what s1 may: not write as s2
            rconf = json.loads(lay.robot_routers["s1"].read_text())["transport"]["auth"]["usrpwd"]
            conf = zenoh_config(connect=[base_ep], mode="client")
            conf.insert_json5("transport/auth/usrpwd", json.dumps({"user": rconf["user"],
                                                                   "password": rconf["password"]}))  # fmt: skip
            with zenoh.open(conf) as imp:
                imp.put(f"psr/{MAP}/shard/0/delta/s2", encode(make_delta(seq=0, scout="s2", layers=("slip",),
                                                                         cells=((2, 2),))))  # fmt: skip
                threading.Event().wait(1.0)
            assert m0.status().merged == 1
