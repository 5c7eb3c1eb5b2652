from __future__ import annotations

import argparse

import pytest

from map_server.cli import register


def parse(argv):
    parser = argparse.ArgumentParser(prog="psrmap")
    register(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(argv)


def test_subcommands_registered():
    args = parse(["server", "--map", "m1", "--res", "0.4", "--connect", "tcp/127.0.0.1:1"])
    assert (args.map, args.res, args.connect) == ("m1", 0.4, ["tcp/127.0.0.1:1"])
    assert parse(["router", "--listen", "tcp/127.0.0.1:1"]).listen == ["tcp/127.0.0.1:1"]
    assert parse(["query", "--map", "m", "--box", "0,0,1,1", "--connect", "x"]).stats == "value,n"


def test_server_without_endpoints_is_a_usage_error(capsys):
    args = parse(["server", "--map", "m1"])
    with pytest.raises(SystemExit) as info:
        args.func(args)
    assert info.value.code == 2
    assert "give --connect" in capsys.readouterr().err


def test_bad_box_is_a_usage_error(capsys):
    args = parse(["query", "--map", "m", "--box", "0,0,1", "--connect", "tcp/127.0.0.1:1"])
    with pytest.raises(SystemExit) as info:
        args.func(args)
    assert info.value.code == 2 and "x0,y0,x1,y1" in capsys.readouterr().err
