"""Components as processes: `spawn(ctx, name, target, config, ...)` runs `target(config)` (a component's
typed entry point) in a spawned process (Zenoh sessions do not survive a fork) with its output in a log
file, and `Proc.result()` returns the typed summary it sent back through a pipe, or why there is none.
"""

from __future__ import annotations

import logging
import os
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.context import SpawnContext, SpawnProcess
from pathlib import Path
from typing import Any, TypeVar

__all__ = ["Proc", "spawn"]

C = TypeVar("C")  # a component's config


def _run_component(
    target: Callable[[C], object], config: C, conn: Connection, log_path: str, env: dict[str, str]
) -> None:
    """Process target: `target(config)` with stdout/stderr sent to a log file (at the fd level); its typed
    result (or the error that stopped it) goes back through `conn`."""
    os.environ.update(env)
    log = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(log, 1)
    os.dup2(log, 2)
    sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    code = 0
    try:
        result = target(config)
        code = int(getattr(result, "exit_code", 0))
        conn.send(("ok", result))
    except Exception as exc:  # reported to the mission, which names the log
        traceback.print_exc()
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        code = 1
    finally:
        conn.close()
        sys.stdout.flush()
    sys.exit(code)


@dataclass
class Proc:
    name: str
    proc: SpawnProcess
    log: Path
    conn: Connection  # the parent's end of the result pipe

    def result(self, timeout: float | None = None) -> tuple[str, Any]:
        """("ok", typed result) or ("error", why), once the component finished (or it died)."""
        if self.conn.poll(timeout):
            try:
                return self.conn.recv()  # type: ignore[no-any-return]
            except EOFError:
                pass
        self.proc.join(timeout=5)
        return "error", f"exit code {self.proc.exitcode}; see {self.log}"


def spawn(
    ctx: SpawnContext, name: str, target: Callable[[C], object], config: C, run_dir: Path, env: dict[str, str]
) -> Proc:
    """Start `target(config)` (a component's typed entry point) in a spawned process."""
    log = run_dir / "logs" / f"{name}.log"
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(
        target=_run_component, args=(target, config, child, str(log), env), name=name, daemon=False
    )
    p.start()
    child.close()
    return Proc(name, p, log, parent)
