"""What the simulator made of a scene: its navmesh figures and the passages too narrow for the
agent (``calnav check-scene``).

A passage is where walkable ground continues but the navigable space (the ground eroded by the
agent's radius) is cut: two pieces of eroded ground joined through ground whose clearance is
below the agent's. Its width is twice the clearance at its narrowest point on the widest route
between the pieces (the maximin route: cells taken in order of decreasing clearance, pieces
joined as their ground meets, Kruskal's way); the agent fits through a width above
2 x (radius + cell / 2), as the navmesh erodes.
"""
from __future__ import annotations

import numpy as np

from calnav.common.jit import compiled
from calnav.envs.heightfield import find_root
from calnav.envs.navmesh import NavMesh

MIN_PIECE_M2 = 0.05        # eroded pieces smaller than this are specks, not rooms, m^2


@compiled
def _joins(order, clearance, piece, h, w):
    """Kruskal over ground cells in ``order`` (decreasing clearance): rows (piece a, piece b,
    clearance, cell) each time ground joins two pieces' sets (a's set holds the larger piece,
    pieces ranked by id, 1 = largest)."""
    parent = np.arange(h * w)
    rep = np.zeros(h * w, np.int64)    # the best (lowest id) piece of each set, 0 = none
    active = np.zeros(h * w, np.bool_)
    out_a = np.zeros(len(order), np.int64)
    out_b = np.zeros(len(order), np.int64)
    out_v = np.zeros(len(order))
    out_c = np.zeros(len(order), np.int64)
    k = 0
    for c in order:
        active[c] = True
        rep[c] = piece[c]
        r, q = c // w, c % w
        for dr in range(-1, 2):
            for dq in range(-1, 2):
                rr, qq = r + dr, q + dq
                if (dr == 0 and dq == 0) or rr < 0 or rr >= h or qq < 0 or qq >= w:
                    continue
                n = rr * w + qq
                if not active[n]:
                    continue
                a = find_root(parent, c)
                b = find_root(parent, n)
                if a == b:
                    continue
                pa, pb = rep[a], rep[b]
                if pa > 0 and pb > 0 and pa != pb:
                    out_a[k], out_b[k], out_v[k], out_c[k] = min(pa, pb), max(pa, pb), clearance[c], c
                    k += 1
                parent[b] = a
                rep[a] = pb if pa == 0 else (pa if pb == 0 else min(pa, pb))
    return out_a[:k], out_b[:k], out_v[:k], out_c[:k]


def narrow_passages(mesh: NavMesh, agent_radius_m: float) -> list[dict]:
    """One row per piece of eroded ground (but the largest of its walkable area) that ground
    joins to a larger piece: the piece's area and whether it is kept as an island, the area of
    the piece it joins, the passage's width and where its narrowest point is (world xy), and
    the width the agent needs. Pieces no ground reaches (behind walls) are not passages."""
    h, w = mesh.ground.shape
    area = mesh.cell_m ** 2
    sizes = np.bincount(mesh.eroded.ravel())
    sizes[0] = 0
    rank = np.argsort(-sizes, kind="stable")   # piece ids by decreasing size
    big = rank[sizes[rank] * area >= MIN_PIECE_M2]
    relabel = np.zeros(len(sizes), np.int64)
    relabel[big] = np.arange(1, len(big) + 1)   # 1 = the largest piece
    piece = relabel[mesh.eroded.ravel()]
    cells = np.flatnonzero(mesh.ground.ravel())
    order = cells[np.argsort(-mesh.clearance.ravel()[cells], kind="stable")]
    a, b, v, c = _joins(order, mesh.clearance.ravel(), piece, h, w)
    need = 2 * (agent_radius_m + mesh.cell_m / 2)
    rows = []
    for pa, pb, clear, cell in zip(a, b, v, c):
        small = big[pb - 1]
        kept = bool((mesh.islands.ravel()[mesh.eroded.ravel() == small] >= 0).any())
        xy = mesh.origin_xy + (np.array([cell % w, cell // w]) + 0.5) * mesh.cell_m
        rows.append({"piece_m2": float(sizes[small] * area), "kept": kept, "joins_m2": float(sizes[big[pa - 1]] * area),
                     "width_m": float(2 * clear), "needed_m": float(need), "at_xy": [float(xy[0]), float(xy[1])]})
    return sorted(rows, key=lambda r: -r["piece_m2"])


def navmesh_figures(mesh: NavMesh, floor_z: float) -> dict:
    """Areas (m^2), islands, and how far the walkable ground lies above the scene's reference
    floor height (median / 95th percentile, metres)."""
    above = mesh.floor_z[mesh.ground] - floor_z
    return {**mesh.stats, "navigable_fraction": mesh.stats["navigable_m2"] / max(mesh.stats["ground_m2"], 1e-12),
            "floor_above_median_m": float(np.median(above)) if above.size else float("nan"),
            "floor_above_p95_m": float(np.percentile(above, 95)) if above.size else float("nan")}
