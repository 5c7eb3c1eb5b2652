"""Fixtures shared across the test tree: a real Zenoh router on loopback and a map server behind it."""

from __future__ import annotations

import contextlib
import subprocess
from collections.abc import Iterator
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
