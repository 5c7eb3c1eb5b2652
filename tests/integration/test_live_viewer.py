"""Live viewing: `--connect-viewer URL` streams a scout's walk and a whole mission to a running Rerun gRPC
server as they run (a real `rerun --serve-grpc` that saves what it receives, standing in for a viewer)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

from psrmap.mission import rerun_exe
from psrmap_common.session import free_port

pytestmark = pytest.mark.slow


class _Receiver:
    """`rerun --serve-grpc --save FILE` on a free loopback port."""

    def __init__(self, path: Path) -> None:
        self.path, self.port = path, free_port()
        self.url = f"rerun+http://127.0.0.1:{self.port}/proxy"
        # SIGINT stops it (entities()); a suite started in the background has SIGINT ignored, which a child
        # would inherit: a handler here instead makes the child start with the default action
        prev = signal.signal(signal.SIGINT, signal.default_int_handler)
        self.proc = subprocess.Popen(
            [
                *rerun_exe(),
                "--serve-grpc",
                "--bind",
                "127.0.0.1",
                "--port",
                str(self.port),
                "--save",
                str(path),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # `rerun` runs the viewer binary as a child: stop() ends both
        )
        signal.signal(signal.SIGINT, prev)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", self.port)) == 0:
                    return
            time.sleep(0.1)
        self.stop()
        raise RuntimeError("rerun --serve-grpc did not start")

    def stop(self) -> None:
        """Kill the receiver and its viewer child if they are still running (no process outlives the test)."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()

    def entities(self) -> set[str]:
        from rerun.chunk import RrdReader

        time.sleep(1.0)
        self.proc.send_signal(signal.SIGINT)  # flushes and closes the file
        try:
            self.proc.wait(timeout=20)
        finally:
            self.stop()
        with warnings.catch_warnings():  # `--save` writes a stream without the footer of a finished file
            warnings.simplefilter("ignore")
            return {c.entity_path for c in RrdReader(self.path).stream()}


def test_scout_streams_live_to_a_viewer(tmp_path: Path) -> None:
    rx = _Receiver(tmp_path / "live.rrd")
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "psrmap",
            "scout",
            "--scene",
            "ramps",
            "--sim-seconds",
            "4",
            "--quiet",
            "--connect-viewer",
            rx.url,
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    entities = rx.entities()
    assert {
        "/world/terrain",
        "/world/scouts/scout1/base",
        "/world/scouts/scout1/series/speed_mps",
    } <= entities


def test_a_bad_viewer_url_is_refused_with_the_valid_form(tmp_path: Path) -> None:
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "psrmap",
            "scout",
            "--sim-seconds",
            "1",
            "--connect-viewer",
            "http://127.0.0.1:9876",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert res.returncode == 2
    assert "rerun+http://HOST:PORT/proxy" in res.stderr


def test_mission_streams_every_component_live_and_prints_plain_lines(tmp_path: Path) -> None:
    """A mission streams every component to a live viewer; its stdout, captured (a file/CI, not a TTY), is a few
    plain lines: no progress-bar redraws, the scouts' status line, the report. (One mission walks for both.)"""
    rx = _Receiver(tmp_path / "live.rrd")
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "psrmap",
            "mission",
            "--scouts",
            "1",
            "--sim-seconds",
            "10",
            "--no-secure",
            "--run-dir",
            str(tmp_path / "run"),
            "--connect-viewer",
            rx.url,
        ],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert res.returncode in (0, 1), res.stderr[-2000:]
    lines = res.stdout.splitlines()
    assert "\r" not in res.stdout
    assert 5 <= len(lines) < 100, res.stdout
    assert any(line.startswith("[scouts] ") and "sim-s" in line for line in lines), res.stdout
    assert any(line.startswith("Mission finished") for line in lines)
    entities = rx.entities()
    for prefix in ("/world/terrain", "/world/scouts/scout1/", "/map/elevation/", "/map/cost", "/plans/"):
        assert any(e.startswith(prefix) for e in entities), (prefix, sorted(entities)[:30])
    assert (tmp_path / "run" / "mission.rrd").exists()  # the files are written as well
