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
    assert (
        parse(["query", "--map", "m", "--box", "0,0,1,1", "--connect", "tcp/127.0.0.1:1"]).stats == "value,n"
    )


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


@pytest.mark.parametrize("ms", ["-1", "nan", "500"])
def test_a_linger_outside_0_to_100_ms_is_a_usage_error_naming_the_range(capsys, ms):
    args = parse(["server", "--map", "m1", "--connect", "tcp/127.0.0.1:1", "--linger-ms", ms])
    with pytest.raises(SystemExit) as info:
        args.func(args)
    assert info.value.code == 2 and "0 (no wait) to 100 ms" in capsys.readouterr().err


def test_the_linger_reaches_the_server_config():
    from map_server.cli import server_config
    from map_server.service import ServerConfig

    args = parse(["server", "--map", "m1", "--connect", "tcp/127.0.0.1:1", "--linger-ms", "0"])
    assert server_config(args).linger_s == 0.0
    assert ServerConfig().linger_s == 0.002
    with pytest.raises(ValueError, match="linger_s"):
        ServerConfig(linger_s=1.0)
