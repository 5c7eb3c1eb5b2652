"""What believing only attested servers costs a client: status queries through a secured router (`psrmap secure
init` credentials and role ACL, a map server, a planner), each `--n` times with open trust (any replier) and with
attested trust (psrmap_common.trust: one liveliness query for the `serverid` tokens, then the query), interleaved in
rounds. Prints one JSON object: median and p95 per mode [ms].

    python benchmarks/trust.py [--n 200] [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path


def main() -> None:
    import zenoh

    from map_server.service import MapService, ServerConfig
    from psrmap.secure import secure_init
    from psrmap_common.query import get_statuses, wait_for_server
    from psrmap_common.session import free_endpoint, zenoh_config
    from psrmap_common.trust import Trust

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=200, help="queries per mode and round (default 200)")
    ap.add_argument("--rounds", type=int, default=2, help="rounds of both modes (default 2)")
    args = ap.parse_args()
    times: dict[str, list[float]] = {"open": [], "attested": []}
    with tempfile.TemporaryDirectory() as tmp:
        ep = free_endpoint()
        lay = secure_init(Path(tmp) / "sec", "bench", ["s1"], ["p1"], endpoint=ep)
        with zenoh.open(zenoh_config(config_file=lay.router)):
            cfg = ServerConfig(map_id="bench", res=0.4, connect=(ep,), zenoh_config=str(lay.agents["server"]))
            with MapService(cfg), zenoh.open(zenoh_config(config_file=lay.agents["p1"])) as p1:
                assert wait_for_server(p1, "bench")
                for _ in range(args.rounds):
                    for mode, trust in (("open", Trust()), ("attested", Trust(attested=True))):
                        for _ in range(args.n):
                            t0 = time.perf_counter()
                            got = get_statuses(p1, "bench", 2.0, trust)
                            times[mode].append(time.perf_counter() - t0)
                            if len(got) != 1:
                                raise SystemExit(f"{mode}: {len(got)} status replies, want 1")
    out = {
        mode: {
            "queries": len(ts),
            "median_ms": round(1e3 * statistics.median(ts), 3),
            "p95_ms": round(1e3 * sorted(ts)[int(0.95 * len(ts))], 3),
        }
        for mode, ts in times.items()
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
