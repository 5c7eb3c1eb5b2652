"""One mapping at the command line from each package's root exception to a one-line message and exit code."""

from __future__ import annotations

import argparse

import pytest

import psrmap.cli as cli
from map_server.errors import MapServerConfigError
from protocol.errors import ProtocolError
from psrmap.errors import EXIT_CODES, MissionRunError, exit_code_for
from psrmap.mission.config import MissionError
from psrmap_common.errors import SessionError
from scout_agent.errors import ScoutConfigError, ScoutLinkError


@pytest.mark.parametrize(
    ("exc", "code"),
    [
        (ProtocolError("bad_value", "res = -1: need > 0"), 2),
        (ScoutConfigError("bad start"), 2),
        (MapServerConfigError("db of another map"), 2),
        (MissionError("[mission] res: need > 0"), 2),
        (ScoutLinkError("no ack"), 1),
        (SessionError("router refused"), 1),
        (MissionRunError("scout1 exited early"), 1),
    ],
)
def test_each_root_exception_has_its_exit_code(exc: Exception, code: int) -> None:
    assert exit_code_for(exc) == code


def test_a_programming_error_is_not_mapped() -> None:
    assert exit_code_for(KeyError("x")) is None
    assert exit_code_for(ValueError("x")) is None


def test_every_mapped_class_exists() -> None:
    import importlib

    for module, name, _ in EXIT_CODES:
        assert isinstance(getattr(importlib.import_module(module), name), type), f"{module}.{name}"


def _parser_raising(exc: BaseException):
    def build(argv=None, full=False):
        p = argparse.ArgumentParser(prog="psrmap")
        sub = p.add_subparsers(dest="command")

        def boom(args):
            raise exc

        sub.add_parser("status").set_defaults(func=boom)
        return p

    return build


def test_main_prints_one_line_and_returns_the_code(monkeypatch, capsys) -> None:
    monkeypatch.setattr(
        cli, "build_parser", _parser_raising(MissionRunError("map server server died (code 1)"))
    )
    assert cli.main(["status"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["psrmap status: error: map server server died (code 1)"]


def test_main_lets_a_programming_error_keep_its_traceback(monkeypatch) -> None:
    monkeypatch.setattr(cli, "build_parser", _parser_raising(KeyError("bug")))
    with pytest.raises(KeyError):
        cli.main(["status"])
