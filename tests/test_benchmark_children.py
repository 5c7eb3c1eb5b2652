"""Benchmarks that start services leave none behind: a benchmark stopped by SIGTERM or killed by SIGKILL takes
the map-server processes it spawned (`benchmarks/ingest.spawn`, used by shards, soak, paging, ...) with it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = """
import sys, time
sys.path.insert(0, {bench!r})
from ingest import spawn
from psrmap_common.session import free_endpoint
ep = free_endpoint()
r = spawn("router", "--listen", ep)
s = spawn("router", "--listen", free_endpoint(), "--connect", ep)
print("PIDS", r.pid, s.pid, flush=True)
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc; PR_SET_PDEATHSIG is Linux's")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_a_stopped_benchmark_leaves_no_service_running(sig: signal.Signals) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-c", SCRIPT.format(bench=str(ROOT / "benchmarks"))], env=env,
                         stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert p.stdout is not None
    pids = [int(x) for x in p.stdout.readline().split()[1:]]
    assert len(pids) == 2 and all(_alive(c) for c in pids)
    p.send_signal(sig)
    p.wait(30)
    p.stdout.close()
    # SIGTERM: the parent stops its children cleanly before it exits; SIGKILL: the kernel kills them (PDEATHSIG).
    # A clean stop under load took over 20 s once (CI with three walks beside it); an orphan never stops
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and any(_alive(c) for c in pids):
        time.sleep(0.1)
    left = [c for c in pids if _alive(c)]
    for c in left:  # do not leave them to the next test either
        os.kill(c, signal.SIGKILL)
    assert not left, f"{sig.name}: services still running: {left}"
