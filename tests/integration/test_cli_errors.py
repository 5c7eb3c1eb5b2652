"""Bad command-line input is a usage error (exit 2) that names what would have been valid — never a traceback."""

from __future__ import annotations

import socket

import pytest

from psrmap.cli import main


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])  # closed again when the block ends: nothing listens there


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["server", "--map", "bad.id", "--connect", "tcp/127.0.0.1:1"], "must match [A-Za-z0-9_-]+"),
        (["status", "--map", "a/b", "--connect", "tcp/127.0.0.1:1"], "must match [A-Za-z0-9_-]+"),
        (
            ["plan", "--map", "x y", "--connect", "tcp/127.0.0.1:1", "--from", "1,1", "--to", "2,2"],
            "must match",
        ),
        (["scout", "--scout-id", "bad.id"], "scout 'bad.id' must match"),
        (["scout", "--scene", "mars"], "choose from"),
        (["scout", "--slope", "40"], "valid range is 0–25 degrees"),
        (["query", "--map", "m", "--connect", "tcp/127.0.0.1:1", "--box", "1,2"], "give x0,y0,x1,y1"),
        (["mission", "--scouts", "0"], "need at least 1"),
        (["router", "--listen", "tcp/127.0.0.1:notaport"], "need tcp/HOST:PORT with a port 1-65535"),
        (["router", "--listen", "127.0.0.1:7452"], "did you mean tcp/127.0.0.1:7452?"),
        (["status", "--map", "m", "--connect", "127.0.0.1:7447"], "did you mean tcp/127.0.0.1:7447?"),
        (["plan", "--map", "m", "--connect", "tpc/h:1", "--from", "1,1", "--to", "2,2"], "protocols: tcp"),
        (["secure", "init", "d", "--map", "m", "--scouts", "a", "--endpoint", "h:7447"], "did you mean tcp/"),
        # no abbreviations: `--scout` is not `--scouts`; an unknown flag is named by its own subcommand
        (["mission", "--scout", "2"], "psrmap mission: error: unrecognized arguments: --scout 2"),
        (["mission", "--scots", "2"], "unrecognized arguments: --scots 2 (did you mean --scouts?)"),
        (["secure", "init", "d", "--map", "m", "--scout", "a"], "psrmap secure init: error:"),
        # numbers checked before any work: a negative walk, a NaN, a zero timeout, a negative seed
        (["scout", "--sim-seconds", "-1"], "argument --sim-seconds: '-1': need a finite number > 0"),
        (["scout", "--sim-seconds", "nan"], "argument --sim-seconds: 'nan': need a finite number > 0"),
        (["evaluate", "--sim-seconds", "-2"], "need a finite number > 0"),
        (["mission", "--seed", "-1"], "argument --seed: '-1': need an integer >= 0"),
        (["status", "--map", "m", "--connect", "tcp/127.0.0.1:1", "--timeout", "0"], "argument --timeout"),
    ],
)
def test_bad_arguments_name_what_is_valid(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_unreachable_router_is_a_clear_error(capsys):
    ep = f"tcp/127.0.0.1:{_closed_port()}"
    for argv, message in (
        (["status", "--map", "m", "--connect", ep], "a router must be listening there"),
        (["scout", "--map", "m", "--connect", ep, "--sim-seconds", "1", "--quiet"], "is `psrmap router"),
    ):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        assert message in capsys.readouterr().err


@pytest.mark.parametrize("command", ["mission", "scout"])
def test_viewer_without_a_display_is_one_line_before_any_work(command, monkeypatch, capsys, tmp_path):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main([command, "--viewer"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert f"psrmap {command}: error: --viewer: no display here" in err
    assert not (tmp_path / "runs").exists()  # nothing started


@pytest.mark.parametrize("command", ["mission", "scout"])
@pytest.mark.serial  # asserts how fast it fails
def test_connect_viewer_to_nothing_fails_fast_with_a_message(command, capsys, tmp_path, monkeypatch):
    import time

    monkeypatch.chdir(tmp_path)
    url = f"rerun+http://127.0.0.1:{_closed_port()}/proxy"
    t0 = time.monotonic()
    with pytest.raises(SystemExit) as exc:
        main([command, "--connect-viewer", url])
    assert time.monotonic() - t0 < 5.0
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert f"--connect-viewer {url}: no Rerun viewer answers at 127.0.0.1:" in err
    assert not (tmp_path / "runs").exists()


@pytest.mark.serial  # asserts how fast it fails
def test_an_anonymous_client_on_a_secured_router_is_told_it_needs_credentials(tmp_path, capsys):
    import subprocess
    import sys
    import time

    from psrmap.secure import secure_init

    ep = f"tcp/127.0.0.1:{_closed_port()}"
    lay = secure_init(tmp_path / "secure", "m", ["s1"], ["p1"], endpoint=ep)
    router = subprocess.Popen([sys.executable, "-m", "psrmap", "router", "--zenoh-config", str(lay.router)],
                              stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert router.stdout is not None and '"up"' in router.stdout.readline()
        for argv, message in (
            (["status", "--map", "m", "--connect", ep], "refused this session: it requires credentials"),
            (["status", "--map", "m", "--connect", ep, "--zenoh-config", str(lay.agents["s1"])], None),
        ):
            t0 = time.monotonic()
            code = None
            try:
                main(argv)
            except SystemExit as exc:
                code = exc.code
            err = capsys.readouterr().err
            if message is None:  # with its credentials the same client gets in (and finds no server)
                assert "refused this session" not in err and "no server of map 'm'" in err, err
            else:
                assert code == 2 and message in err and "a router must be listening" not in err, err
                assert time.monotonic() - t0 < 10
    finally:
        router.terminate()
        router.wait(10)
        if router.stdout:
            router.stdout.close()
