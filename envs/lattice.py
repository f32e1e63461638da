"""A* over the agent's action lattice, compiled: the search at the heart of the oracle
(``envs.oracle.ShortestPathFollower``) and of the episode check that every generated episode can
be solved with the task's discrete actions.

States are (x, y, heading) reached from the start by forward steps of ``step_m`` and turns of
``turn_rad`` (the heading kept as the exact float the env's turn arithmetic gives, keyed by the
number of turns modulo ``n_headings``); a forward step is allowed when its straight segment stays
on navigable cells (``envs.navigation``'s segment test). Positions within one ``bin_m`` square per
heading count as one state (the first reached at the lowest cost). Cost = path length + ``turn_cost``
per turn; heuristic = ``weight`` x the geodesic field (``envs.geodesics``' point distance); the
goal: the field's distance below ``stop_distance``. The caller replays the actions with the env's
own motion, so a plan is never trusted beyond what the env does.
"""
from __future__ import annotations

import heapq
import math

import numpy as np

from calnav.common.jit import compiled
from calnav.envs.geodesics import _point_distance
from calnav.envs.navigation import MOVE_SAMPLE_FRACTION, _segment_navigable

FORWARD, LEFT, RIGHT = 1, 2, 3          # envs.task.Action values of the lattice's moves
_KEY_OFFSET = 1 << 20                   # bin indices are shifted by this to stay positive
_KEY_SPAN = 1 << 21


@compiled
def _key(x, y, k, bin_m, n_headings):
    kx = int(math.floor(x / bin_m + 0.5)) + _KEY_OFFSET
    ky = int(math.floor(y / bin_m + 0.5)) + _KEY_OFFSET
    return (kx * _KEY_SPAN + ky) * n_headings + (k % n_headings)


@compiled
def lattice_search(navigable, ox, oy, cell, dist, goal, sx, sy, syaw, step_m, turn_rad, n_headings,
                   stop_distance, bin_m, weight, budget, turn_cost):
    """(actions int64 array ending before STOP, found) of the cheapest lattice path from
    (sx, sy, syaw) into the goal region, expanding at most ``budget`` states. navigable (H, W)
    bool; dist (H, W) float64 field metres; goal (H, W) bool its goal cells; origin (ox, oy),
    cell: the grid's."""
    xs = [sx]
    ys = [sy]
    hs = [syaw]
    ks = [0]
    gs = [0.0]
    parent = [-1]
    action = [0]
    best = {_key(sx, sy, 0, bin_m, n_headings): 0.0}
    heap = [(_point_distance(dist, goal, ox, oy, cell, sx, sy), 0.0, 0, 0)]
    tie = 0
    expanded = 0
    two_pi = 2 * math.pi
    while len(heap) > 0 and expanded < budget:
        _, neg_g, _, s = heapq.heappop(heap)
        g = -neg_g
        x, y, hd, k = xs[s], ys[s], hs[s], ks[s]
        key = _key(x, y, k, bin_m, n_headings)
        if g > best.get(key, np.inf) + 1e-12:
            continue
        expanded += 1
        if _point_distance(dist, goal, ox, oy, cell, x, y) < stop_distance:
            n = 0
            t = s
            while parent[t] >= 0:
                n += 1
                t = parent[t]
            out = np.empty(n, np.int64)
            t = s
            for i in range(n - 1, -1, -1):
                out[i] = action[t]
                t = parent[t]
            return out, True
        for move in range(3):
            if move == 0:
                nx, ny, nh, nk, cost, a = x, y, (hd + turn_rad) % two_pi, k + 1, turn_cost, LEFT
            elif move == 1:
                nx, ny, nh, nk, cost, a = x, y, (hd - turn_rad) % two_pi, k - 1, turn_cost, RIGHT
            else:
                ex = x + step_m * math.cos(hd)
                ey = y + step_m * math.sin(hd)
                m = int(math.ceil(math.sqrt((ex - x) ** 2 + (ey - y) ** 2) / (MOVE_SAMPLE_FRACTION * cell))) + 1
                if not _segment_navigable(navigable, ox, oy, cell, x, y, ex, ey, m):
                    continue
                nx, ny, nh, nk, cost, a = ex, ey, hd, k, step_m, FORWARD
            key2 = _key(nx, ny, nk, bin_m, n_headings)
            g2 = g + cost
            if g2 < best.get(key2, np.inf) - 1e-12:
                h = _point_distance(dist, goal, ox, oy, cell, nx, ny)
                if not np.isfinite(h):
                    continue
                best[key2] = g2
                xs.append(nx)
                ys.append(ny)
                hs.append(nh)
                ks.append(nk)
                gs.append(g2)
                parent.append(s)
                action.append(a)
                tie += 1
                heapq.heappush(heap, (g2 + weight * max(0.0, h - stop_distance), -g2, tie, len(xs) - 1))
    return np.empty(0, np.int64), False
