"""8-connected geometric Dijkstra on a cost grid, compiled with numba.

The same distances as scikit-image's ``MCP_Geometric(costs, fully_connected=True)
.find_costs(starts, ends)`` -- bit for bit at the settled cells (tests/agent/test_dijkstra.py
checks against it): a step between neighbours a and b costs ``length / 2 * (cost[a] +
cost[b])`` (length 1, or sqrt(2) diagonally), sources start at 0, cells of infinite cost are
walls, and the search stops once every target is settled. A cell's final distance is the
minimum over its settled neighbours of ``d[u] + step(u, v)`` whatever the heap's order, so
the same float operations give the same bits.

Why not skimage itself: the planner runs one search per agent step on a ~300 x 300 window,
and ``MCP_Geometric`` builds its edge tables per call (2.2 ms of its 4.2 ms per search,
measured on 484 searches of two val episodes); this kernel takes 0.9 ms for the same
searches, with the heap, the neighbour loop and the early stop in one compiled function.
"""
from __future__ import annotations

import math

import numpy as np

from calnav.common.jit import compiled

HALF_STRAIGHT = 0.5               # length 1 / 2
HALF_DIAGONAL = math.sqrt(2.0) * 0.5   # length sqrt(2) / 2, rounded as skimage rounds it
ROW_STEPS = np.array([-1, -1, -1, 0, 0, 1, 1, 1], np.int64)
COL_STEPS = np.array([-1, 0, 1, -1, 1, -1, 0, 1], np.int64)


def geodesic(costs: np.ndarray, sources: np.ndarray, targets: np.ndarray | None = None) -> np.ndarray:
    """Distances (h, w) float64 from the ``sources`` cells over ``costs`` (h, w) float (> 0,
    inf = impassable). sources / targets (M, 2) int (row, col), inside the grid; a source on
    an impassable cell is skipped. targets: stop once each of them is settled (their values
    exact, other cells inf or an upper bound); None or empty = every reachable cell."""
    costs = np.ascontiguousarray(costs, dtype=np.float64)
    w = costs.shape[1]
    src = np.asarray(sources, np.int64).reshape(-1, 2)
    tgt = np.zeros((0, 2), np.int64) if targets is None else np.asarray(targets, np.int64).reshape(-1, 2)
    return _dijkstra8(costs, src[:, 0] * w + src[:, 1], tgt[:, 0] * w + tgt[:, 1], ROW_STEPS, COL_STEPS)


@compiled
def _put(keys, cells, pos, i, key, cell):
    """Heap slot ``i`` holds ``cell`` with ``key``."""
    keys[i] = key
    cells[i] = cell
    pos[cell] = i


@compiled
def _sift_up(keys, cells, pos, i, key, cell):
    """Place ``cell`` with ``key`` from heap slot ``i`` upwards (binary min-heap)."""
    while i > 0:
        parent = (i - 1) >> 1
        if keys[parent] <= key:
            break
        _put(keys, cells, pos, i, keys[parent], cells[parent])
        i = parent
    _put(keys, cells, pos, i, key, cell)


@compiled
def _sift_down(keys, cells, pos, size, key, cell):
    """Place ``cell`` with ``key`` from the root downwards in a heap of ``size`` entries."""
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and keys[child + 1] < keys[child]:
            child += 1
        if keys[child] >= key:
            break
        _put(keys, cells, pos, i, keys[child], cells[child])
        i = child
    _put(keys, cells, pos, i, key, cell)


@compiled
def _dijkstra8(costs, sources, targets, row_steps, col_steps):
    """The search of ``geodesic`` on flat cell indices (see there)."""
    h, w = costs.shape
    n = h * w
    c = costs.ravel()
    dist = np.full(n, np.inf)
    settled = np.zeros(n, np.bool_)
    is_target = np.zeros(n, np.bool_)
    remaining = 0
    for t in targets:
        if not is_target[t]:
            is_target[t] = True
            remaining += 1
    stop_early = remaining > 0
    keys = np.empty(n, np.float64)     # heap: one entry per cell (decrease-key through pos)
    cells = np.empty(n, np.int64)
    pos = np.full(n, -1, np.int64)
    size = 0
    for s in sources:
        if dist[s] > 0.0 and np.isfinite(c[s]):
            dist[s] = 0.0
            _sift_up(keys, cells, pos, size, 0.0, s)
            size += 1
    while size > 0:
        u, du = cells[0], keys[0]
        size -= 1
        pos[u] = -1
        if size > 0:   # the last entry fills the root's place
            _sift_down(keys, cells, pos, size, keys[size], cells[size])
        settled[u] = True
        if stop_early and is_target[u]:
            remaining -= 1
            if remaining == 0:
                break
        ur = u // w
        uc = u - ur * w
        cu = c[u]
        for k in range(8):
            vr = ur + row_steps[k]
            vc = uc + col_steps[k]
            if vr < 0 or vr >= h or vc < 0 or vc >= w:
                continue
            v = vr * w + vc
            cv = c[v]
            if settled[v] or not np.isfinite(cv):
                continue
            half = HALF_DIAGONAL if row_steps[k] != 0 and col_steps[k] != 0 else HALF_STRAIGHT
            nd = du + half * (cu + cv)
            if nd < dist[v]:
                dist[v] = nd
                i = pos[v]
                if i < 0:
                    i = size
                    size += 1
                _sift_up(keys, cells, pos, i, nd, v)
    return dist.reshape(h, w)
