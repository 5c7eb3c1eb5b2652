"""The `psrmap` command table: fast start-up without losing a command or its help."""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys

import pytest

from psrmap.cli import COMMANDS, build_parser

HEAVY = ("mujoco", "pinocchio", "rerun", "zenoh", "numpy", "scipy", "matplotlib")


def _registered() -> dict[str, str]:
    """command -> help, as the component modules register them."""
    p = argparse.ArgumentParser()
    sub = p.add_subparsers()
    for module in dict.fromkeys(m for m, _ in COMMANDS.values()):
        importlib.import_module(module).register(sub)
    helps = {a.dest: a.help for a in sub._choices_actions}
    return {name: helps.get(name, "") for name in sub.choices}


def test_the_command_table_matches_what_the_modules_register() -> None:
    registered = _registered()
    assert set(registered) == set(COMMANDS)
    for name, (_, helptext) in COMMANDS.items():
        assert registered[name] == helptext, name


@pytest.mark.parametrize(
    "argv", [["--help"], ["router", "--help"], ["status", "--help"], ["query", "--help"]]
)
def test_light_commands_start_without_heavy_imports(argv: list[str]) -> None:
    code = (
        f"import sys\nfrom psrmap.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
        f"print('HEAVY:' + ','.join(m for m in {HEAVY!r} if m in sys.modules))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "usage: psrmap" in res.stdout
    heavy = res.stdout.strip().splitlines()[-1]
    assert heavy == "HEAVY:", f"psrmap {' '.join(argv)} imported {heavy}"


def test_every_command_parses_with_its_own_parser() -> None:
    for name in COMMANDS:
        parser = build_parser([name])
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        assert sub.choices[name].add_help, f"{name}: only a placeholder was built"


def test_status_lines_print_plain_periodic_lines(capsys: pytest.CaptureFixture[str]) -> None:
    from psrmap.progress import StatusLines, progress

    bar = progress(10, "work", "run")  # pytest's stderr is not a terminal
    assert isinstance(bar, StatusLines)
    bar = StatusLines(10, "work", "run", every_s=0.0)
    bar.set_postfix(last="a")
    bar.update(4)
    bar.close()
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("[work] 4/10 run (40 %), last=a")
    assert len(out) == 2 and "\r" not in "".join(out)


def _flag(parser: argparse.ArgumentParser, flag: str) -> argparse.Action | None:
    return next((a for a in parser._actions if flag in a.option_strings), None)


def _commands(parser: argparse.ArgumentParser, prefix: str = ""):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield f"{prefix}{name}", sub
                yield from _commands(sub, f"{prefix}{name} ")


# `psrmap mission --zenoh-config` names a `psrmap secure init` folder's router.json5 (every component's file is
# taken from beside it), not this process's own credentials: another meaning, so another flag help.
NOT_A_LINK = {("mission", "--zenoh-config")}


def test_every_client_command_has_the_same_link_flags() -> None:
    from psrmap_common.link import add_link_arguments

    reference = argparse.ArgumentParser()
    add_link_arguments(reference)
    have: dict[str, set[str]] = {}
    for name, sub in _commands(build_parser([], full=True)):
        for flag in ("--connect", "--zenoh-config"):
            action, ref = _flag(sub, flag), _flag(reference, flag)
            if action is None or (name, flag) in NOT_A_LINK:
                continue
            assert ref is not None
            have.setdefault(name, set()).add(flag)
            for attr in ("type", "default", "help", "metavar", "nargs", "required", "const"):
                assert getattr(action, attr) == getattr(ref, attr), (name, flag, attr)
            assert type(action) is type(ref), (name, flag)
    clients = {"status", "query", "plan", "compare", "export", "ros2", "scout", "router", "server"}
    assert clients <= set(have), sorted(clients - set(have))
    assert all(flags == {"--connect", "--zenoh-config"} for flags in have.values()), have


def test_a_usage_error_is_shown_with_its_own_commands_usage(capsys: pytest.CaptureFixture[str]) -> None:
    """A command raises `UsageError` (no parser reach-in); the entry point finds that command's parser, nested
    ones included, and exits 2 with its usage, like argparse's own errors; the packages' `python -m` too."""
    from map_server.cli import main as map_server_main
    from psrmap.cli import main
    from psrmap_common.cli_parser import command_parser

    parser = build_parser([], full=True)
    assert command_parser(parser, ["secure", "init", "d", "--map", "m"]).prog == "psrmap secure init"
    assert command_parser(parser, ["--help"]).prog == "psrmap"
    for run, prog in ((main, "psrmap server"), (map_server_main, "python -m map_server server")):
        with pytest.raises(SystemExit) as exc:
            run(["server", "--map", "m1"])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and f"usage: {prog} " in err and f"{prog}: error: give --connect" in err
