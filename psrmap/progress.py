"""Progress for long work: a tqdm bar on a terminal, a periodic one-line status anywhere else.

A log file or CI console is not a terminal: tqdm's carriage-return redraws become hundreds of lines there,
so `progress(...)` returns a `StatusLines` instead, which prints one plain line every `every_s` seconds and
one at the end. Both take `n`, `total`, `set_postfix`, `update`, `refresh` and `close` as used here.
"""

from __future__ import annotations

import sys
import time
from typing import Protocol, TextIO

__all__ = ["ProgressBar", "StatusLines", "is_terminal", "progress"]


class ProgressBar(Protocol):
    """What `progress` returns (a tqdm bar or `StatusLines`), as the callers use it."""

    n: float
    total: float

    def set_postfix(self, **kv: object) -> None: ...
    def update(self, k: float = 1) -> None: ...
    def refresh(self) -> None: ...
    def close(self) -> None: ...


def is_terminal(stream: TextIO | None = None) -> bool:
    s = stream if stream is not None else sys.stderr
    try:
        return bool(s.isatty())
    except (AttributeError, ValueError):
        return False


class StatusLines:
    """A progress counter that prints `desc: n/total unit (p %) k=v ...` at most every `every_s` seconds."""

    def __init__(
        self,
        total: float,
        desc: str,
        unit: str,
        every_s: float = 10.0,
        disable: bool = False,
        initial: float = 0,
        stream: TextIO | None = None,
    ) -> None:
        self.total, self.desc, self.unit, self.every_s, self.disable = total, desc, unit, every_s, disable
        self.n = initial
        self.stream = stream if stream is not None else sys.stdout
        self._postfix: dict[str, object] = {}
        self._t0 = self._last = time.monotonic()
        self._closed = False

    def set_postfix(self, **kv: object) -> None:
        self._postfix = kv

    def update(self, k: float = 1) -> None:
        self.n += k
        self.refresh()

    def refresh(self, force: bool = False) -> None:
        now = time.monotonic()
        if self.disable or (not force and now - self._last < self.every_s):
            return
        self._last = now
        pct = f" ({100 * self.n / self.total:.0f} %)" if self.total else ""
        extra = "".join(f", {k}={v}" for k, v in self._postfix.items())
        print(
            f"[{self.desc}] {self.n:g}/{self.total:g} {self.unit}{pct}{extra}, {now - self._t0:.0f} s",
            file=self.stream,
            flush=True,
        )

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.refresh(force=True)


def progress(
    total: float, desc: str, unit: str, disable: bool = False, every_s: float = 10.0, initial: float = 0
) -> ProgressBar:
    """A tqdm bar when stderr is a terminal, else `StatusLines` (on stdout, every `every_s` seconds)."""
    if is_terminal():
        from tqdm import tqdm  # lazy: only a terminal shows a tqdm bar

        return tqdm(total=total, desc=desc, unit=unit, disable=disable, dynamic_ncols=True, initial=initial)
    return StatusLines(total, desc, unit, every_s=every_s, disable=disable, initial=initial)
