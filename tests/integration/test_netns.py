"""Across hosts: a base host (router + two map shards), a scout host (its own router meshed to the base, a
scout publishing deltas) and a rover host (`psrmap query`), each a Linux network namespace joined to the base
by a veth link. The scout host's link is cut for 10 s mid-walk and restored: the scout keeps measuring,
buffers, resends; the map the rover reads holds every delta exactly once. Run twice, side by side: on a lab
network (`--insecure`), and secured as the README's sharded section is (`psrmap secure init --robot-router s1`: every
agent logs in, the scout host's router logs in to the base as `s1-router`, the ACL at each router).

Needs root and `ip netns` (CI and the development machine run as root); skips with the reason otherwise."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from helpers import TILE, wait_line, walk

from protocol.partition import Partition
from protocol.testing import RES
from psrmap_mapcore import TiledMap, read_npz

ROOT = Path(__file__).resolve().parents[2]
MAP = "netmap"
N_DELTAS = 80  # at 5 Hz: a 16 s walk, the link cut from its 5th to its 15th second
CUT_AT, CUT_S = 25, 10.0  # cut the scout host's link after this many deltas, for this long

SCOUT = """
import json, sys, time
sys.path.insert(0, {tests!r})
from helpers import walk
from protocol.partition import Partition
from scout_agent.publisher import ScoutPublisher
ep, n, conf = sys.argv[1], int(sys.argv[2]), sys.argv[3] or None
unacked = []
with ScoutPublisher({map!r}, "s1", {res!r}, [ep], outbox=None, resend_after_s=1.0,
                    partition=Partition(2, {tile}), zenoh_config_file=conf) as pub:
    print("scout up", flush=True)
    for i, d in enumerate(walk(n)):
        assert pub.send(d.layers, d.t)
        pub.poll()
        unacked.append(pub.unacked)
        time.sleep(0.2)
    ok = pub.wait_acked(90)
    print(json.dumps({{"ok": ok, "max_unacked": max(unacked), **pub.stats()}}), flush=True)
"""


def sh(*cmd: str) -> None:
    subprocess.run(cmd, check=True, capture_output=True)


@contextlib.contextmanager
def network_hosts() -> Iterator[tuple[dict[str, str], dict[str, tuple[str, str, str]]]]:
    """Namespaces base, scout, rover; veth base<->scout (10.77.1.0/24) and base<->rover (10.77.2.0/24).
    Each call makes its own namespaces: two sets use the same addresses without meeting."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("needs root and iproute2 (`ip netns`) to build test hosts as network namespaces")
    tag = uuid.uuid4().hex[:6]
    ns = {h: f"psr{h[0]}{tag}" for h in ("base", "scout", "rover")}
    links = {"scout": (f"vbs{tag}", f"vsb{tag}", "10.77.1"), "rover": (f"vbr{tag}", f"vrb{tag}", "10.77.2")}
    made: list[str] = []
    try:
        for name in ns.values():
            sh("ip", "netns", "add", name)
            made.append(name)
            sh("ip", "-n", name, "link", "set", "lo", "up")
        for host, (b_end, h_end, net) in links.items():
            sh(
                "ip",
                "link",
                "add",
                b_end,
                "netns",
                ns["base"],
                "type",
                "veth",
                "peer",
                "name",
                h_end,
                "netns",
                ns[host],
            )
            sh("ip", "-n", ns["base"], "addr", "add", f"{net}.1/24", "dev", b_end)
            sh("ip", "-n", ns[host], "addr", "add", f"{net}.2/24", "dev", h_end)
            sh("ip", "-n", ns["base"], "link", "set", b_end, "up")
            sh("ip", "-n", ns[host], "link", "set", h_end, "up")
    except subprocess.CalledProcessError as exc:
        for name in made:
            subprocess.run(["ip", "netns", "del", name], check=False, capture_output=True)
        pytest.skip(f"cannot build network namespaces here: {exc.stderr.decode().strip()}")
    try:
        yield ns, links
    finally:
        for name in made:  # deleting a namespace removes its veth ends (and their peers)
            subprocess.run(["ip", "netns", "del", name], check=False, capture_output=True)


def in_ns(ns: str, *args: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        ["ip", "netns", "exec", ns, sys.executable, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        env=env,
        cwd=ROOT,
    )


@pytest.mark.slow
def test_scout_host_link_cut_for_10s_loses_and_doubles_nothing(procs, tmp_path):
    """The lab network (`--insecure`) and the secured deployment side by side, each on hosts of its own: most
    of a run is the scout's walk and the cut, waiting, so the two overlap."""
    with network_hosts() as lab, network_hosts() as sec, ThreadPoolExecutor(2) as pool:
        runs = {
            name: pool.submit(_link_cut, hosts, procs, tmp_path / name, secured)
            for name, hosts, secured in (("insecure", lab, False), ("secured", sec, True))
        }
        failures = {name: run.exception() for name, run in runs.items()}
    for name, exc in failures.items():
        if exc is not None:
            raise AssertionError(f"{name} deployment: {exc}") from exc


def _link_cut(hosts, procs: list[subprocess.Popen], tmp_path: Path, secured: bool) -> None:
    ns, links = hosts
    tmp_path.mkdir()
    base_scout, base_rover = "tcp/10.77.1.1:7447", "tcp/10.77.2.1:7447"
    robot_ep = "tcp/10.77.1.2:7447"
    if secured:  # the README's secured deployment: credentials for every agent and the scout host's router
        from psrmap.secure import secure_init

        lay = secure_init(tmp_path / "sec", MAP, ["s1"], ["p1"], servers=["m0", "m1"], endpoint=base_scout,
                          robots={"s1": ["s1"]}, robot_listen=robot_ep)  # fmt: skip
        cred = {n: ["--zenoh-config", str(f)] for n, f in [*lay.agents.items(), ("router", lay.router),
                                                            ("s1-router", lay.robot_routers["s1"])]}  # fmt: skip
    else:
        cred = {n: ["--insecure"] for n in ("router", "s1-router")}
    router = in_ns(ns["base"], "-m", "psrmap", "router", "--listen", base_scout, "--listen", base_rover,
                   *cred["router"])  # fmt: skip
    procs.append(router)
    wait_line(router, "router")
    # the two shards and the scout host's router start side by side (each waits only for the base router)
    servers = [
        in_ns(ns["base"], "-m", "psrmap", "server", "--map", MAP, "--res", str(RES), "--tile", str(TILE),
              "--db", str(tmp_path / f"s{i}.db"), "--connect", base_scout,
              "--shards", "2", "--shard", str(i), *cred.get(f"m{i}", []))
        for i in range(2)
    ]  # fmt: skip
    scout_router = in_ns(ns["scout"], "-m", "psrmap", "router", "--listen", robot_ep, "--connect", base_scout,
                         *cred["s1-router"])  # fmt: skip
    procs.extend([*servers, scout_router])
    for p in servers:
        wait_line(p, "server")
    wait_line(scout_router, "router")
    if secured:  # an anonymous client on the scout host's router, and one on the base, are refused
        anons = [in_ns(ns[host], "-m", "psrmap", "status", "--map", MAP, "--connect", ep)
                 for ep, host in ((robot_ep, "scout"), (base_rover, "rover"))]  # fmt: skip
        procs.extend(anons)
        for anon in anons:
            assert anon.wait(60) != 0
    script = tmp_path / "scout.py"
    script.write_text(SCOUT.format(tests=str(ROOT / "tests"), map=MAP, res=RES, tile=TILE))
    scout = in_ns(ns["scout"], str(script), robot_ep, str(N_DELTAS), cred["s1"][1] if secured else "")
    procs.append(scout)
    wait_line(scout, "scout up", 30)
    time.sleep(CUT_AT * 0.2)
    b_end = links["scout"][0]
    sh("ip", "-n", ns["base"], "link", "set", b_end, "down")  # the scout host drops off the network ...
    time.sleep(CUT_S)
    sh("ip", "-n", ns["base"], "link", "set", b_end, "up")  # ... and comes back
    line = wait_line(scout, '"ok"', 150)
    stats = json.loads(line)
    assert stats["ok"], stats  # every part acknowledged by its shard
    assert stats["resent"] > 0 and stats["max_unacked"] >= 20, stats  # it buffered through the cut and resent
    # the rover host reads the map over its own link
    out = tmp_path / "rover.npz"
    rover = in_ns(ns["rover"], "-m", "psrmap", "query", "--map", MAP, "--connect", base_rover, "--box",
                  "0,0,90,5", "--stats", "all", "--out", str(out), *cred.get("p1", []))  # fmt: skip
    procs.append(rover)
    assert rover.wait(60) == 0
    grid = read_npz(out)
    ref = TiledMap(RES, TILE)
    for d in walk(N_DELTAS):
        ref.merge(d.layers)
    box = (grid.ix0, grid.iy0, grid.ix0 + grid.w - 1, grid.iy0 + grid.h - 1)
    for layer, st in ref.region(*box, ("slip", "cot"), ("all",)).items():
        for stat, want in st.items():
            np.testing.assert_allclose(
                grid.layers[layer][stat], want, equal_nan=True, err_msg=f"{layer}.{stat}"
            )
    sent = stats["sent_per_shard"]
    status = in_ns(ns["rover"], "-m", "psrmap", "status", "--map", MAP, "--connect", base_rover,
                   *cred.get("p1", []))  # fmt: skip
    procs.append(status)
    st = json.loads(status.communicate(timeout=60)[0])
    assert st["merged"] == sum(sent) and st["rejected"] == {}, st  # nothing lost, nothing doubled
    assert Partition(2, TILE).shards == len(st["shard_status"])
