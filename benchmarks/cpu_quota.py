"""A fixed share of a CPU core for one process, as a separate host would give it: a cgroup with a CPU quota.

`CpuQuota(share, name)` creates a cgroup whose processes together get at most `share` of one core (CFS
bandwidth: `share` × period per period), `add(pid)` moves a process there (all its threads, and those it starts
later), `stats()` reads how much CPU it used and how often it was throttled, and `close()` moves what is left
back to the root group and removes the cgroup. Needs root and the cpu controller:

- cgroup v1 (`/sys/fs/cgroup/cpu`, this machine: `mount | grep cgroup`): `cpu.cfs_period_us`, `cpu.cfs_quota_us`,
  `cgroup.procs`, `cpu.stat` (nr_throttled, throttled_time [ns]) and `cpuacct.usage` when mounted with it;
- cgroup v2 (`/sys/fs/cgroup` with `cpu` in `cgroup.controllers`): `cpu.max` = "quota period", `cpu.stat`
  (usage_usec, nr_throttled, throttled_usec).

`QuotaError` says what is missing when neither is usable.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["CpuQuota", "QuotaError", "cgroup_version"]

V1 = Path("/sys/fs/cgroup/cpu")
V2 = Path("/sys/fs/cgroup")
PERIOD_US = 100_000


class QuotaError(RuntimeError):
    """CPU quotas cannot be set here (no cpu controller, not root)."""


def cgroup_version() -> int:
    """1 or 2: the cgroup hierarchy whose cpu controller this machine offers; QuotaError when none."""
    if (V1 / "cpu.cfs_quota_us").exists():
        return 1
    ctl = V2 / "cgroup.controllers"
    if ctl.exists() and "cpu" in ctl.read_text().split():
        return 2
    raise QuotaError(
        "no cgroup cpu controller: need /sys/fs/cgroup/cpu (v1) or `cpu` in /sys/fs/cgroup/cgroup.controllers (v2)"
    )


class CpuQuota:
    """One cgroup with at most `share` of a core (0 < share; None: no cap) and, with `weight`, a CFS weight
    relative to the other groups and to the processes outside any (v1 `cpu.shares`, default 1024; v2
    `cpu.weight` = weight / 1024 × 100): a quota caps, a weight makes the cap reachable on a loaded machine."""

    def __init__(self, share: float | None, name: str, weight: int | None = None) -> None:
        if share is not None and not share > 0:
            raise QuotaError(f"cpu quota {share}: need a share of a core > 0")
        if os.geteuid() != 0:
            raise QuotaError("cpu quotas need root (cgroups are written under /sys/fs/cgroup)")
        self.version = cgroup_version()
        self.share = share
        quota = max(1000, int(round(share * PERIOD_US))) if share is not None else -1
        if self.version == 1:
            self.root = V1
            self.path = V1 / name
            self.path.mkdir(exist_ok=True)
            (self.path / "cpu.cfs_period_us").write_text(str(PERIOD_US))
            (self.path / "cpu.cfs_quota_us").write_text(str(quota))
            if weight is not None:
                (self.path / "cpu.shares").write_text(str(int(weight)))
        else:
            self.root = V2
            sub = V2 / "cgroup.subtree_control"
            if "cpu" not in sub.read_text().split():
                sub.write_text("+cpu")
            self.path = V2 / name
            self.path.mkdir(exist_ok=True)
            (self.path / "cpu.max").write_text(f"{quota if quota > 0 else 'max'} {PERIOD_US}")
            if weight is not None:
                (self.path / "cpu.weight").write_text(str(max(1, min(10000, int(weight * 100 / 1024)))))

    def add(self, pid: int) -> None:
        """Move process `pid` (every thread of it) into this cgroup."""
        (self.path / "cgroup.procs").write_text(str(pid))

    def stats(self) -> dict[str, float]:
        """CPU used [s] and throttling so far: cpu_s (when the kernel reports it), nr_throttled, throttled_s."""
        st = dict(line.split() for line in (self.path / "cpu.stat").read_text().splitlines() if line.strip())
        out: dict[str, float] = {"nr_throttled": float(st.get("nr_throttled", 0))}
        if self.version == 1:
            out["throttled_s"] = float(st.get("throttled_time", 0)) / 1e9
            acct = Path("/sys/fs/cgroup/cpuacct") / self.path.name / "cpuacct.usage"
            if acct.exists():
                out["cpu_s"] = float(acct.read_text()) / 1e9
        else:
            out["throttled_s"] = float(st.get("throttled_usec", 0)) / 1e6
            out["cpu_s"] = float(st.get("usage_usec", 0)) / 1e6
        return out

    def close(self) -> None:
        """Move any process left back to the root group and remove the cgroup (idempotent)."""
        if not self.path.exists():
            return
        try:
            for pid in (self.path / "cgroup.procs").read_text().split():
                try:
                    (self.root / "cgroup.procs").write_text(pid)
                except OSError:  # gone meanwhile
                    pass
            self.path.rmdir()
        except OSError:
            pass
