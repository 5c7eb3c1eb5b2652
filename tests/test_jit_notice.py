"""The first-run numba compile is announced: `psrmap_common.jit.uncached` names kernels whose cache holds no code."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from psrmap_common.jit import COMPILE_NOTICE


def test_uncached_names_a_kernel_until_its_first_call_compiles_it(tmp_path: Path) -> None:
    (tmp_path / "tinykernel.py").write_text(
        "from numba import njit\n\n@njit(cache=True)\ndef twice(x):\n    return 2 * x\n"
    )
    code = (
        "from psrmap_common.jit import uncached\nimport tinykernel as k\n"
        "print(uncached([k.twice]))\nk.twice(1.0)\nprint(uncached([k.twice]))\n"
    )
    env_path = f"{tmp_path}:{':'.join(sys.path)}"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": env_path, "NUMBA_CACHE_DIR": str(tmp_path / "cache")})  # fmt: skip
    assert res.stdout.splitlines() == ["['twice']", "[]"]
    # a new process finds it in the cache: nothing to announce
    res = subprocess.run([sys.executable, "-c", "from psrmap_common.jit import uncached\nimport tinykernel as k\n"
                          "print(uncached([k.twice]))"], capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": env_path, "NUMBA_CACHE_DIR": str(tmp_path / "cache")})  # fmt: skip
    assert res.stdout.strip() == "[]"


def test_the_mission_announces_its_compile_in_one_line_first(tmp_path: Path) -> None:
    """With an empty cache, the mission's compile-ahead step says so in one line, naming the state estimator's
    and the planner's kernels, before it compiles anything (stopped right after the line here: the compile
    itself takes up to a minute, and the cache mechanism is the test above)."""
    code = (
        "from psrmap.mission.compile import compile_ahead\n"
        "def say(line):\n    print(line)\n    raise SystemExit(0)\n"
        "compile_ahead(say)\nprint('compiled without a notice')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120,
                         env={"PYTHONPATH": ":".join(sys.path), "NUMBA_CACHE_DIR": str(tmp_path)})  # fmt: skip
    (line,) = res.stdout.splitlines()
    assert line.startswith("[mission] " + COMPILE_NOTICE)
    assert {"propagate", "update", "dial8", "astar8"} <= set(line.split(": ", 1)[1].split(", "))
