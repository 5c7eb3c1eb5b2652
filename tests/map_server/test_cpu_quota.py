"""benchmarks/cpu_quota.py: a process in a CpuQuota cgroup gets at most its share of a core (issue 25: shard
scaling shown with CPU quotas), and the cgroup is gone after close()."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from cpu_quota import CpuQuota, QuotaError, cgroup_version  # noqa: E402


def test_a_spinning_process_gets_at_most_its_quota_and_the_cgroup_is_removed():
    try:
        version = cgroup_version()
        usable = os.geteuid() == 0
    except QuotaError as exc:  # a machine without the cpu controller: the error says what is missing
        assert "cgroup cpu controller" in str(exc)
        return
    if not usable:
        with pytest.raises(QuotaError, match="root"):
            CpuQuota(0.2, "psrmap-test-quota")
        return
    q = CpuQuota(0.2, f"psrmap-test-quota-{os.getpid()}")
    spin = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        q.add(spin.pid)
        proc = psutil.Process(spin.pid)
        a, t0 = sum(proc.cpu_times()[:2]), time.perf_counter()
        time.sleep(2.0)
        used = (sum(proc.cpu_times()[:2]) - a) / (time.perf_counter() - t0)
        assert used <= 0.2 * 1.25, (version, used)
        assert q.stats()["nr_throttled"] > 0
    finally:
        spin.kill()
        spin.wait()
        q.close()
    assert not q.path.exists()
