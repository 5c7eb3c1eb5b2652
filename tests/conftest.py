"""Fixtures shared across the test tree: a real Zenoh router on loopback and a map server behind it."""

from __future__ import annotations

import contextlib
import fcntl
import os
import subprocess
import tempfile
from collections.abc import Generator, Iterator
from pathlib import Path

import pytest
import zenoh

from map_server.service import MapService, ServerConfig
from psrmap_common.query import wait_for_server
from psrmap_common.session import free_endpoint, zenoh_config


@pytest.fixture(autouse=True)
def _private_state_dir(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Scouts keep their outbox under $XDG_STATE_HOME: every test (and its subprocesses) gets its own."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path_factory.mktemp("state")))


@pytest.fixture(scope="module")
def router() -> Iterator[str]:
    """The endpoint of an embedded Zenoh router on a free loopback port (one per test module)."""
    ep = free_endpoint()
    with zenoh.open(zenoh_config(listen=[ep], mode="router")):
        yield ep


@contextlib.contextmanager
def _served_map(router: str, db: Path, map_id: str, res: float) -> Iterator[tuple[MapService, zenoh.Session]]:
    cfg = ServerConfig(map_id=map_id, res=res, db=str(db), connect=(router,))
    with MapService(cfg) as service, zenoh.open(zenoh_config(connect=[router], mode="client")) as client:
        assert wait_for_server(client, map_id)
        yield service, client


@pytest.fixture
def served_map(router: str, tmp_path: Path):
    """`with served_map(map_id, res) as (service, client):` a map server on the module's router, persisting
    under the test's tmp_path, and a client session that has seen it answer."""
    return lambda map_id, res: _served_map(router, tmp_path / f"{map_id}.db", map_id, res)


@pytest.fixture
def procs() -> Iterator[list[subprocess.Popen]]:
    """Processes a test starts (append them): killed and reaped when the test ends, whatever happened."""
    started: list[subprocess.Popen] = []
    yield started
    for p in started:
        if p.poll() is None:
            p.kill()
            p.wait()
        if p.stdout is not None:
            p.stdout.close()


# -- two workers (`pytest -n 2`, pytest-xdist) ------------------------------------------------------------------
# Most tests wait on subprocesses, so two workers share the 2 cores well; a test marked `serial` asserts a latency or
# a rate and must have the machine to itself. Every test holds a shared lock; a serial one holds it exclusively, so
# it starts when the other worker's current test ends, and that worker waits for it. The gate gives a serial test
# waiting for its turn priority over the next shared ones (no starvation).


@contextlib.contextmanager
def _flock(path: Path, how: int) -> Iterator[None]:
    with path.open("a") as f:
        fcntl.flock(f, how)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


@contextlib.contextmanager
def _turn(serial: bool) -> Iterator[None]:
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if run is None:  # one process: every test has the machine to itself already
        yield
        return
    base = Path(tempfile.gettempdir()) / f"psrmap-pytest-{run}"
    gate, turn = base.with_suffix(".gate"), base.with_suffix(".turn")
    if serial:
        with _flock(gate, fcntl.LOCK_EX), _flock(turn, fcntl.LOCK_EX):
            yield
        return
    with contextlib.ExitStack() as held:
        with _flock(gate, fcntl.LOCK_EX):
            held.enter_context(_flock(turn, fcntl.LOCK_SH))
        yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Generator[None, None, None]:
    """Setup, call and teardown (module fixtures included) under the test's turn."""
    with _turn(item.get_closest_marker("serial") is not None):
        yield


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under `-n 2` the modules with slow tests are handed out first (each module goes to one worker whole:
    `--dist loadscope`, its module fixtures set up once), so the suite does not end on one long module alone."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        return
    slow = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.path not in slow)  # stable: collection order otherwise
