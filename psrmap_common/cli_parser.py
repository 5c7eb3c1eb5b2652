"""The one argparse parser class every psrmap command line uses: no abbreviations, errors from the subcommand.

Plain argparse takes `--scout 2` as `--scouts 2` (prefix abbreviations) and reports an unknown flag of a
subcommand with the top-level usage (`psrmap [-h] COMMAND ...`). `Parser` turns abbreviations off
(`allow_abbrev=False`) and makes the parser that was handed the unknown arguments report them, with its own
usage and the closest flag it does know. Subparsers made by `add_subparsers` are `Parser`s too (argparse uses
the parent's class), so every command and nested action gets the same rules.
"""

from __future__ import annotations

import argparse
import difflib
import math
import sys
from collections.abc import Sequence
from typing import Any, NoReturn, TypeAlias

from psrmap_common.errors import UsageError

__all__ = [
    "Parser",
    "Subparsers",
    "command_parser",
    "run_command",
    "usage_exit",
    "non_negative_int",
    "positive_float",
    "positive_int",
]


# what `add_subparsers` returns: each command module's `register(subparsers)` adds its parsers to it
Subparsers: TypeAlias = "argparse._SubParsersAction[Parser]"


class Parser(argparse.ArgumentParser):
    """`argparse.ArgumentParser` with `allow_abbrev=False` and unknown arguments reported where they were given."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs["allow_abbrev"] = False
        super().__init__(*args, **kwargs)

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        ns, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}{self._suggestion(extras)}")
        return ns, extras

    def _suggestion(self, extras: list[str]) -> str:
        flags = [s for s in self._option_string_actions if s.startswith("--")]
        for word in extras:
            if word.startswith("--"):
                close = difflib.get_close_matches(word.split("=", 1)[0], flags, n=1, cutoff=0.6)
                if close:
                    return f" (did you mean {close[0]}?)"
        return ""


def command_parser(parser: argparse.ArgumentParser, argv: Sequence[str]) -> argparse.ArgumentParser:
    """The (sub)parser of the command `argv` names (`psrmap secure init ...` -> the `init` parser): the one whose
    usage a `psrmap_common.errors.UsageError` of that command is shown with."""
    words = iter(a for a in argv if not a.startswith("-"))
    while True:
        sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        word = next(words, None) if sub is not None else None
        if sub is None or word not in sub.choices:
            return parser
        parser = sub.choices[word]


def usage_exit(
    parser: argparse.ArgumentParser, argv: Sequence[str], message: str, usage: bool = True
) -> NoReturn:
    """Exit 2 with `message` as the command `argv` names reports it: with its usage (argparse's `error`), or
    (`usage=False`) one line `<prog>: error: <message>`."""
    p = command_parser(parser, argv)
    if usage:
        p.error(message)
    p.exit(2, f"{p.prog}: error: {message}\n")


def run_command(parser: argparse.ArgumentParser, argv: Sequence[str] | None = None) -> int:
    """Parse `argv` and run the command's `func`: its exit code, or exit 2 with that command's usage for a
    `UsageError` (the component packages' own `python -m ...` entry points; `psrmap` adds its error table)."""
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UsageError as exc:
        usage_exit(parser, sys.argv[1:] if argv is None else argv, str(exc), exc.usage)


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (seconds, metres, rates), else a usage error saying so."""
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: need a finite number > 0")
    return v


def _int_at_least(text: str, least: int) -> int:
    try:
        v = int(text)
    except ValueError:
        v = least - 1
    if v < least:
        raise argparse.ArgumentTypeError(f"{text!r}: need an integer >= {least}")
    return v


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 (seeds, epochs), else a usage error saying so."""
    return _int_at_least(text, 0)


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (counts: shards, runs, workers), else a usage error saying so."""
    return _int_at_least(text, 1)
