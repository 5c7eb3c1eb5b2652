"""A compiled A* kernel for 8-connected cost grids, built on first use with the system C compiler.

Plain numpy cannot run a priority-queue search fast enough (a label-correcting sweep needs tens of
passes on terrain-like maps), scikit-image's MCP is a generic Cython Dijkstra, and numba is not a
dependency. The kernel below is ~100 lines of C: A* with a binary heap, an admissible and consistent
heuristic (cheapest cell cost x octile distance) and early exit at the goal. It is compiled once per
source hash into a user cache directory and loaded with ctypes; `load()` returns None when no compiler
is available, and `search.plan_path` then falls back to scikit-image.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

__all__ = ["load"]

_SOURCE = r"""
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

typedef struct { double f; int32_t v; } item;

static int push(item **heap, int64_t *n, int64_t *cap, double f, int32_t v) {
    if (*n == *cap) {
        int64_t nc = *cap * 2;
        item *nh = (item *)realloc(*heap, (size_t)nc * sizeof(item));
        if (!nh) return -1;
        *heap = nh; *cap = nc;
    }
    item *h = *heap;
    int64_t i = (*n)++;
    while (i > 0) {
        int64_t p = (i - 1) >> 1;
        if (h[p].f <= f) break;
        h[i] = h[p]; i = p;
    }
    h[i].f = f; h[i].v = v;
    return 0;
}

static item pop(item *h, int64_t *n) {
    item top = h[0];
    item last = h[--(*n)];
    int64_t i = 0, m = *n;
    for (;;) {
        int64_t c = 2 * i + 1;
        if (c >= m) break;
        if (c + 1 < m && h[c + 1].f < h[c].f) c++;
        if (last.f <= h[c].f) break;
        h[i] = h[c]; i = c;
    }
    if (m > 0) h[i] = last;
    return top;
}

/* cost: (h*w) row-major, +inf/NaN = impassable. Move cost = len * (cost[a] + cost[b]) / 2 with
   len = res (straight) or res*sqrt(2) (diagonal). hmin: a lower bound of every passable cell's cost
   (0 turns A* into Dijkstra). g: (h*w) scratch, out: path cells goal..start. Returns the number of
   path cells, 0 if the goal is unreachable, -1 if out of memory. */
int64_t astar8(const double *cost, int32_t h, int32_t w, double res, int32_t start, int32_t goal,
               double hmin, double *g, int32_t *parent, uint8_t *closed, int32_t *out, double *total) {
    const int dr[8] = {-1, -1, -1, 0, 0, 1, 1, 1};
    const int dc[8] = {-1, 0, 1, -1, 1, -1, 0, 1};
    const double diag = sqrt(2.0);
    int64_t n = (int64_t)h * w;
    for (int64_t i = 0; i < n; i++) { g[i] = INFINITY; closed[i] = 0; }
    int64_t cap = 1024, size = 0;
    item *heap = (item *)malloc((size_t)cap * sizeof(item));
    if (!heap) return -1;
    int32_t gr = goal / w, gc = goal % w;
    double hs = hmin * res, hd = hmin * res * (diag - 1.0);
    g[start] = 0.0; parent[start] = -1;
    if (push(&heap, &size, &cap, 0.0, start)) { free(heap); return -1; }
    int found = 0;
    while (size > 0) {
        item it = pop(heap, &size);
        int32_t u = it.v;
        if (closed[u]) continue;
        closed[u] = 1;
        if (u == goal) { found = 1; break; }
        int32_t r = u / w, c = u % w;
        double gu = g[u], cu = cost[u];
        for (int k = 0; k < 8; k++) {
            int32_t rr = r + dr[k], cc = c + dc[k];
            if (rr < 0 || rr >= h || cc < 0 || cc >= w) continue;
            int32_t v = rr * w + cc;
            double cv = cost[v];
            if (closed[v] || !(cv < INFINITY)) continue;
            double len = (dr[k] != 0 && dc[k] != 0) ? res * diag : res;
            double nv = gu + len * 0.5 * (cu + cv);
            if (nv < g[v]) {
                g[v] = nv; parent[v] = u;
                int32_t ar = abs(rr - gr), ac = abs(cc - gc);
                int32_t lo = ar < ac ? ar : ac, hi = ar < ac ? ac : ar;
                double hv = hs * hi + hd * lo;
                if (push(&heap, &size, &cap, nv + hv, v)) { free(heap); return -1; }
            }
        }
    }
    free(heap);
    if (!found) return 0;
    *total = g[goal];
    int64_t m = 0;
    for (int32_t v = goal; v != -1; v = parent[v]) out[m++] = v;
    return m;
}
"""

_lib: ctypes.CDLL | None = None
_tried = False


def _cache_dir() -> Path:
    base = os.environ.get("PSRMAP_CACHE") or os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "psrmap"


def _build(target: Path) -> bool:
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        return False
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        src = Path(tmp) / "astar8.c"
        src.write_text(_SOURCE)
        lib = Path(tmp) / target.name
        cmd = [cc, "-O2", "-shared", "-fPIC", "-o", str(lib), str(src), "-lm"]
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            print(f"consumer_planner: C build failed ({' '.join(cmd)}):\n{done.stderr}", file=sys.stderr)
            return False
        os.replace(lib, target)  # atomic: concurrent builders race harmlessly
    return True


def load() -> ctypes.CDLL | None:
    """The compiled kernel (built on first call), or None when it cannot be built here."""
    global _lib, _tried
    if _tried or os.environ.get("PSRMAP_NO_NATIVE"):
        return _lib
    _tried = True
    digest = hashlib.sha256(_SOURCE.encode()).hexdigest()[:16]
    suffix = ".dylib" if sys.platform == "darwin" else ".so"
    target = _cache_dir() / f"astar8-{digest}{suffix}"
    try:
        if not target.exists() and not _build(target):
            return None
        lib = ctypes.CDLL(str(target))
    except OSError as exc:
        print(f"consumer_planner: native kernel unavailable ({exc}); using scikit-image", file=sys.stderr)
        return None
    f = lib.astar8
    f.restype = ctypes.c_int64
    p = ctypes.c_void_p
    i32 = ctypes.c_int32
    f.argtypes = [p, i32, i32, ctypes.c_double, i32, i32, ctypes.c_double, p, p, p, p, p]
    _lib = lib
    return _lib
