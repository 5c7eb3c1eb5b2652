"""`FootholdTrack`: where the state estimate put the scout's recent footholds, by distance walked.

One point per stance: the foot's ground contact point (sphere centre minus its radius) when the stance has
settled, in the map frame as the estimate had it then. After a pose correction the whole track moves with the
estimate (`shift`), so the next match does not find the same offset again.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FootholdTrack"]


class FootholdTrack:
    def __init__(self, keep_m: float = 30.0, capacity: int = 4096) -> None:
        self.keep_m = keep_m
        self._pts = np.zeros((capacity, 3))
        self._s = np.zeros(capacity)  # distance walked (estimate) when each was placed [m]
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def add(self, points: np.ndarray, walked_m: float) -> None:
        """Footholds (k, 3) placed when the scout had walked `walked_m`; older than `keep_m` are dropped."""
        k = len(points)
        if k == 0:
            return
        keep = self._s[: self._n] >= walked_m - self.keep_m
        m = int(keep.sum())
        if m + k > len(self._pts):  # keep the newest that fit
            drop = m + k - len(self._pts)
            keep[np.flatnonzero(keep)[:drop]] = False
            m = int(keep.sum())
        self._pts[:m] = self._pts[: self._n][keep]
        self._s[:m] = self._s[: self._n][keep]
        self._pts[m : m + k] = points
        self._s[m : m + k] = walked_m
        self._n = m + k

    def window(self, length_m: float, walked_m: float) -> np.ndarray:
        """The footholds (k, 3) placed in the last `length_m` walked (a view's copy)."""
        sel = self._s[: self._n] >= walked_m - length_m
        return self._pts[: self._n][sel].copy()

    def walked(self, length_m: float, walked_m: float) -> np.ndarray:
        """The distance walked [m] when each of `window(length_m, walked_m)`'s footholds was placed."""
        sel = self._s[: self._n] >= walked_m - length_m
        return self._s[: self._n][sel].copy()

    def span_m(self, walked_m: float) -> float:
        """Distance walked that the kept footholds cover [m]."""
        return float(walked_m - self._s[0]) if self._n else 0.0

    def shift(self, pivot_old: np.ndarray, pivot_new: np.ndarray, dyaw: float) -> None:
        """Move every foothold as the pose correction moved the scout: rotate by `dyaw` about the old position,
        then carry it to the new one (x, y, z)."""
        if not self._n:
            return
        c, s = np.cos(dyaw), np.sin(dyaw)
        d = self._pts[: self._n] - pivot_old
        self._pts[: self._n, 0] = pivot_new[0] + c * d[:, 0] - s * d[:, 1]
        self._pts[: self._n, 1] = pivot_new[1] + s * d[:, 0] + c * d[:, 1]
        self._pts[: self._n, 2] = pivot_new[2] + d[:, 2]
