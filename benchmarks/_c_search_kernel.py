"""The planner's previous search kernel (C, compiled at run time with the system compiler, loaded with
ctypes), kept only as the baseline of `benchmarks/plan.py`: the packaged numba kernels in
`psrmap_common/pathsearch/kernels.py` replaced it (no compiler at run time, no segfault on bad input) and must
stay within 1.5x of it. Needs `cc`; `load()` returns None without one.
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

typedef struct { double f; int64_t v; } item;

/* 4-ary min-heap on f (shallower than a binary heap: fewer cache misses per pop) */
static int push(item **heap, int64_t *n, int64_t *cap, double f, int64_t v) {
    if (*n == *cap) {
        int64_t nc = *cap * 2;
        item *nh = (item *)realloc(*heap, (size_t)nc * sizeof(item));
        if (!nh) return -1;
        *heap = nh; *cap = nc;
    }
    item *h = *heap;
    int64_t i = (*n)++;
    while (i > 0) {
        int64_t p = (i - 1) >> 2;
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
        int64_t c = 4 * i + 1;
        if (c >= m) break;
        int64_t e = c + 4 < m ? c + 4 : m, b = c;
        for (int64_t k = c + 1; k < e; k++) if (h[k].f < h[b].f) b = k;
        if (last.f <= h[b].f) break;
        h[i] = h[b]; i = b;
    }
    if (m > 0) h[i] = last;
    return top;
}

/* cost: (H*W) row-major grid padded with a border of +inf (so no bounds checks); +inf/NaN cells are
   impassable. Move cost = len * (cost[a] + cost[b]) / 2, len = res straight, res*sqrt(2) diagonal.
   hmin: a lower bound of every passable cell's cost (0 turns A* into Dijkstra). g, parent, closed:
   (H*W) scratch; out: path cells goal..start (padded indices). Returns the number of path cells,
   0 if the goal is unreachable, -1 if out of memory. */
int64_t astar8(const double *cost, int64_t H, int64_t W, double res, int64_t start, int64_t goal,
               double hmin, double *g, int64_t *parent, uint8_t *closed, int64_t *out, double *total) {
    const double diag = sqrt(2.0);
    const int64_t off[8] = {-W - 1, -W, -W + 1, -1, 1, W - 1, W, W + 1};
    const double len[8] = {res * diag, res, res * diag, res, res, res * diag, res, res * diag};
    int64_t n = H * W;
    for (int64_t i = 0; i < n; i++) { g[i] = INFINITY; closed[i] = 0; }
    int64_t cap = 4096, size = 0;
    item *heap = (item *)malloc((size_t)cap * sizeof(item));
    if (!heap) return -1;
    int64_t gr = goal / W, gc = goal % W;
    double hs = hmin * res, hd = hmin * res * (diag - 1.0);  /* octile distance x cheapest cost */
    g[start] = 0.0; parent[start] = -1;
    if (push(&heap, &size, &cap, 0.0, start)) { free(heap); return -1; }
    int found = 0;
    while (size > 0) {
        item it = pop(heap, &size);
        int64_t u = it.v;
        if (closed[u]) continue;
        closed[u] = 1;
        if (u == goal) { found = 1; break; }
        double gu = g[u], cu = cost[u];
        for (int k = 0; k < 8; k++) {
            int64_t v = u + off[k];
            double cv = cost[v];
            if (closed[v] || !(cv < INFINITY)) continue;
            double nv = gu + len[k] * 0.5 * (cu + cv);
            if (nv < g[v]) {
                g[v] = nv; parent[v] = u;
                double hv = 0.0;
                if (hmin > 0.0) {
                    int64_t ar = llabs(v / W - gr), ac = llabs(v % W - gc);
                    hv = ar < ac ? hs * ac + hd * ar : hs * ar + hd * ac;
                }
                if (push(&heap, &size, &cap, nv + hv, v)) { free(heap); return -1; }
            }
        }
    }
    free(heap);
    if (!found) return 0;
    *total = g[goal];
    int64_t m = 0;
    for (int64_t v = goal; v != -1; v = parent[v]) out[m++] = v;
    return m;
}

/* Exact Dijkstra with a bucket queue (Dial): bucket width delta <= the cheapest edge, so no cell in
   the lowest bucket can improve another one in it, and every cell of that bucket is final when it is
   reached. Same arguments as astar8 plus delta and nbuckets (> max edge / delta + 1). O(1) per push. */
int64_t dial8(const double *cost, int64_t H, int64_t W, double res, int64_t start, int64_t goal,
              double delta, int64_t nbuckets, double *g, int64_t *parent, uint8_t *closed, int64_t *out,
              double *total) {
    const double diag = sqrt(2.0);
    const int64_t off[8] = {-W - 1, -W, -W + 1, -1, 1, W - 1, W, W + 1};
    const double len[8] = {res * diag, res, res * diag, res, res, res * diag, res, res * diag};
    int64_t n = H * W;
    for (int64_t i = 0; i < n; i++) { g[i] = INFINITY; closed[i] = 0; }
    int64_t **bk = (int64_t **)calloc((size_t)nbuckets, sizeof(int64_t *));
    int64_t *bn = (int64_t *)calloc((size_t)nbuckets, sizeof(int64_t));
    int64_t *bc = (int64_t *)calloc((size_t)nbuckets, sizeof(int64_t));
    int64_t pending = 0, ret = 0;
    if (!bk || !bn || !bc) { ret = -1; goto done; }
    g[start] = 0.0; parent[start] = -1;
    bk[0] = (int64_t *)malloc(64 * sizeof(int64_t));
    if (!bk[0]) { ret = -1; goto done; }
    bc[0] = 64; bk[0][bn[0]++] = start; pending = 1;
    int found = 0;
    for (int64_t k = 0; pending > 0 && !found; k++) {
        int64_t b = k % nbuckets;
        for (int64_t j = 0; j < bn[b]; j++) {
            int64_t u = bk[b][j];
            if (closed[u]) continue;
            closed[u] = 1;
            if (u == goal) { found = 1; break; }
            double gu = g[u], cu = cost[u];
            for (int q = 0; q < 8; q++) {
                int64_t v = u + off[q];
                double cv = cost[v];
                if (closed[v] || !(cv < INFINITY)) continue;
                double nv = gu + len[q] * 0.5 * (cu + cv);
                if (nv < g[v]) {
                    g[v] = nv; parent[v] = u;
                    int64_t kv = (int64_t)(nv / delta);
                    if (kv <= k) kv = k + 1;
                    int64_t t = kv % nbuckets;
                    if (bn[t] == bc[t]) {
                        int64_t nc = bc[t] ? 2 * bc[t] : 64;
                        int64_t *nb = (int64_t *)realloc(bk[t], (size_t)nc * sizeof(int64_t));
                        if (!nb) { ret = -1; goto done; }
                        bk[t] = nb; bc[t] = nc;
                    }
                    bk[t][bn[t]++] = v; pending++;
                }
            }
        }
        pending -= bn[b];
        bn[b] = 0;
    }
    if (found) {
        *total = g[goal];
        for (int64_t v = goal; v != -1; v = parent[v]) out[ret++] = v;
    }
done:
    if (bk) for (int64_t i = 0; i < nbuckets; i++) free(bk[i]);
    free(bk); free(bn); free(bc);
    return ret;
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
        cmd = [cc, "-O3", "-shared", "-fPIC", "-o", str(lib), str(src), "-lm"]
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
        print(f"baseline C kernel unavailable ({exc})", file=sys.stderr)
        return None
    f = lib.astar8
    f.restype = ctypes.c_int64
    p = ctypes.c_void_p
    i64 = ctypes.c_int64
    f.argtypes = [p, i64, i64, ctypes.c_double, i64, i64, ctypes.c_double, p, p, p, p, p]
    d = lib.dial8
    d.restype = ctypes.c_int64
    d.argtypes = [p, i64, i64, ctypes.c_double, i64, i64, ctypes.c_double, i64, p, p, p, p, p]
    _lib = lib
    return _lib
