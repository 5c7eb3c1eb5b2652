from __future__ import annotations

import pytest

from psrmap.cli import build_parser, main


def parse(argv):
    return build_parser(argv).parse_args(argv)


def test_subcommands_registered():
    args = parse(["server", "--map", "m1", "--res", "0.4", "--connect", "tcp/127.0.0.1:1"])
    assert (args.map, args.res, args.connect) == ("m1", 0.4, ["tcp/127.0.0.1:1"])
    assert parse(["router", "--listen", "tcp/127.0.0.1:1"]).listen == ["tcp/127.0.0.1:1"]
    assert (
        parse(["query", "--map", "m", "--box", "0,0,1,1", "--connect", "tcp/127.0.0.1:1"]).stats == "value,n"
    )


def test_server_without_endpoints_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["server", "--map", "m1"])
    assert info.value.code == 2
    assert "give --connect" in capsys.readouterr().err


def test_bad_box_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["query", "--map", "m", "--box", "0,0,1", "--connect", "tcp/127.0.0.1:1"])
    assert info.value.code == 2 and "x0,y0,x1,y1" in capsys.readouterr().err


@pytest.mark.parametrize("ms", ["-1", "nan", "500"])
def test_a_linger_outside_0_to_100_ms_is_a_usage_error_naming_the_range(capsys, ms):
    with pytest.raises(SystemExit) as info:
        main(["server", "--map", "m1", "--connect", "tcp/127.0.0.1:1", "--linger-ms", ms])
    assert info.value.code == 2 and "0 (no wait) to 100 ms" in capsys.readouterr().err


def test_the_linger_reaches_the_server_config():
    from map_server.cli import server_config
    from map_server.service import ServerConfig

    args = parse(["server", "--map", "m1", "--connect", "tcp/127.0.0.1:1", "--linger-ms", "0"])
    assert server_config(args).linger_s == 0.0
    assert ServerConfig().linger_s == 0.002
    with pytest.raises(ValueError, match="linger_s"):
        ServerConfig(linger_s=1.0)
