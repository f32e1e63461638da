"""A* over the agent's action lattice on a house with storeys: ``envs.lattice.lattice_search``
with the layer in the state. A forward step is allowed when ``envs.layered_navigation``'s
``segment_layer`` lets it through (up or down stairs) and lands on the layer it returns; the
heuristic reads the geodesic field of the layer the state is on. The single-storey search stays
in ``envs.lattice``, untouched, so single-storey plans are the same to the bit.
"""
from __future__ import annotations

import heapq
import math

import numpy as np

from calnav.common.jit import compiled
from calnav.envs.geodesics import MOVE_SAMPLE_FRACTION, _point_distance
from calnav.envs.lattice import FORWARD, LEFT, RIGHT, _key
from calnav.envs.layered_navigation import segment_layer


@compiled
def layered_lattice_search(navigable, floor, climb, ox, oy, cell, dist, goal, sx, sy, slayer, syaw, step_m,
                           turn_rad, n_headings, stop_distance, bin_m, weight, budget, turn_cost):
    """(actions int64 ending before STOP, found) of the cheapest lattice path from (sx, sy,
    slayer, syaw) into the goal region, at most ``budget`` expansions. navigable (L, H, W)
    bool, floor (L, H, W) float32, dist (L, H, W) float64, goal (L, H, W) bool."""
    n_layers = navigable.shape[0]
    xs = [sx]
    ys = [sy]
    ls = [slayer]
    hs = [syaw]
    ks = [0]
    parent = [-1]
    action = [0]
    best = {_key(sx, sy, 0, bin_m, n_headings) * n_layers + slayer: 0.0}
    heap = [(_point_distance(dist[slayer], goal[slayer], ox, oy, cell, sx, sy), 0.0, 0, 0)]
    tie = 0
    expanded = 0
    two_pi = 2 * math.pi
    while len(heap) > 0 and expanded < budget:
        _, neg_g, _, s = heapq.heappop(heap)
        g = -neg_g
        x, y, lay, hd, k = xs[s], ys[s], ls[s], hs[s], ks[s]
        key = _key(x, y, k, bin_m, n_headings) * n_layers + lay
        if g > best.get(key, np.inf) + 1e-12:
            continue
        expanded += 1
        if _point_distance(dist[lay], goal[lay], ox, oy, cell, x, y) < stop_distance:
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
            nl = lay
            if move == 0:
                nx, ny, nh, nk, cost, a = x, y, (hd + turn_rad) % two_pi, k + 1, turn_cost, LEFT
            elif move == 1:
                nx, ny, nh, nk, cost, a = x, y, (hd - turn_rad) % two_pi, k - 1, turn_cost, RIGHT
            else:
                ex = x + step_m * math.cos(hd)
                ey = y + step_m * math.sin(hd)
                m = int(math.ceil(math.sqrt((ex - x) ** 2 + (ey - y) ** 2) / (MOVE_SAMPLE_FRACTION * cell))) + 1
                nl = segment_layer(navigable, floor, ox, oy, cell, lay, x, y, ex, ey, m, climb)
                if nl < 0:
                    continue
                nx, ny, nh, nk, cost, a = ex, ey, hd, k, step_m, FORWARD
            key2 = _key(nx, ny, nk, bin_m, n_headings) * n_layers + nl
            g2 = g + cost
            if g2 < best.get(key2, np.inf) - 1e-12:
                h = _point_distance(dist[nl], goal[nl], ox, oy, cell, nx, ny)
                if not np.isfinite(h):
                    continue
                best[key2] = g2
                xs.append(nx)
                ys.append(ny)
                ls.append(nl)
                hs.append(nh)
                ks.append(nk)
                parent.append(s)
                action.append(a)
                tie += 1
                heapq.heappush(heap, (g2 + weight * max(0.0, h - stop_distance), -g2, tie, len(xs) - 1))
    return np.empty(0, np.int64), False
