"""How much Rerun logging slows a scout: the same walk with and without `--rrd`, alternated, medians.

    python benchmarks/rerun_overhead.py [--sim-seconds 30] [--repeat 3] [--scene lunar --seed 7]

Each run is the real product path (`python -m psrmap scout ... --json`, estimators and local map
included); the figure is the real-time factor the scout reports for its own loop. Runs alternate
(plain, logged, plain, logged, ...) so that drift in machine load hits both alike. Goal: logging costs
at most 15 % (ratio logged / plain RTF ≥ 0.85). Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def run(extra: list[str], base: list[str]) -> dict:
    cmd = [sys.executable, "-m", "psrmap", "scout", *base, "--json", "--quiet", *extra]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(
        allow_abbrev=False, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--sim-seconds", type=float, default=30.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scene", default="lunar", choices=("lunar", "ramps"))
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    base = ["--scene", args.scene, "--sim-seconds", str(args.sim_seconds)]
    base += ["--seed", str(args.seed), "--route", "direct"] if args.scene == "lunar" else ["--slope", "10"]
    plain, logged, sizes = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            plain.append(run([], base)["real_time_factor"])
            rrd = Path(tmp) / f"scout{i}.rrd"
            logged.append(run(["--rrd", str(rrd)], base)["real_time_factor"])
            sizes.append(rrd.stat().st_size)
    p50_plain, p50_logged = statistics.median(plain), statistics.median(logged)
    ratio = p50_logged / p50_plain
    print(
        json.dumps(
            {
                "benchmark": "rerun_overhead",
                "scene": args.scene,
                "sim_seconds": args.sim_seconds,
                "repeat": args.repeat,
                "rtf_plain": plain,
                "rtf_logged": logged,
                "rtf_plain_median": round(p50_plain, 2),
                "rtf_logged_median": round(p50_logged, 2),
                "ratio_logged_over_plain": round(ratio, 3),
                "slowdown_pct": round(100 * (1 - ratio), 1),
                "goal_slowdown_pct_max": 15.0,
                "rrd_bytes_median": int(statistics.median(sizes)),
            }
        )
    )


if __name__ == "__main__":
    main()
