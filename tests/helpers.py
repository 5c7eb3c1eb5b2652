"""Helpers shared by the test modules (importable as `helpers`: pytest puts tests/ on sys.path for conftest.py):
waiting for a condition or a process's readiness line, map-server subprocesses, a transport double, and the
deltas several integration tests send."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from protocol.messages import CellDelta
from protocol.testing import MAP, RES, layer_cells, make_delta

ROOT = Path(__file__).resolve().parents[1]
TILE = 8  # small tiles: a few metres of walk cross many, so both shards of a 2-shard map get cells


def wait_until(pred: Callable[[], object], timeout_s: float = 10.0, poll_s: float = 0.05) -> bool:
    """True as soon as `pred()` is truthy (polled every `poll_s`), else `pred()` once more after `timeout_s`."""
    ev = threading.Event()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        ev.wait(poll_s)
    return bool(pred())


def spawn(*args: str) -> subprocess.Popen:
    """`python -m map_server ARGS` from this checkout, stdout piped (for `wait_line`)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-m", "map_server", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        env=env,
        cwd=ROOT,
    )


def wait_line(proc: subprocess.Popen, word: str, timeout_s: float = 20.0) -> str:
    """Block until the process prints a line containing `word` (its readiness message)."""
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        if sel.select(left):
            line = proc.stdout.readline().decode()
            if word in line:
                return line
            if not line:
                break
    raise AssertionError(f"process {proc.args} did not print {word!r} (rc={proc.poll()})")


def stop(proc: subprocess.Popen, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> int:
    """Send `sig` and reap the process; a process that does not exit in `timeout_s` is killed and fails."""
    proc.send_signal(sig)
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f"{proc.args} hung on signal {sig}") from None


class InMemoryTransport:
    """A transport double: remembers every `(key, payload)` put, optionally forwards to a sink."""

    def __init__(self, sink: Callable[[str, bytes], None] | None = None) -> None:
        self.sent: list[tuple[str, bytes]] = []
        self.sink = sink

    def put(self, key: str, payload: bytes) -> None:
        self.sent.append((key, payload))
        if self.sink is not None:
            self.sink(key, payload)


def walk(n: int, scout: str = "s1") -> list[CellDelta]:
    """n deltas of a scout walking along x: 3 cells each, crossing a tile every few deltas."""
    return [
        make_delta(seq=i, scout=scout, cells=((2 * i, 1), (2 * i + 1, 1), (2 * i, 9)), layers=("slip", "cot"), seed=i)
        for i in range(n)
    ]  # fmt: skip


def plannable_delta(seq: int, cells: list[tuple[int, int]]) -> CellDelta:
    """Scout s1's delta `seq` over `cells` with plausible slip and CoT (costs >= 0), for planner tests."""
    ix, iy = np.array([c[0] for c in cells]), np.array([c[1] for c in cells])
    one, rng = np.ones(ix.size), np.random.default_rng(seq)
    layers = {
        "slip": {"ix": ix, "iy": iy, "n": 10 * one, "events": np.zeros(ix.size)},
        "cot": layer_cells("cot", ix, iy, rng, scale=1.0) | {"work": rng.uniform(1, 3, ix.size), "dist": one},
    }
    return CellDelta(MAP, "s1", 7, seq, 1.0 + seq, RES, layers)
