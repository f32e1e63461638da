"""Navigation on a house with storeys: the layered grid (``envs.navmesh_layers``), agent motion
up and down its stairs, and geodesic distances through them.

A position is (xy, layer): world xy (2,) metres and the layer (storey) whose floor the agent
stands on. Motion follows ``envs.navigation.NavGrid.move_forward`` (all or nothing, the segment
sampled every half cell), with one addition: where the next sample's cell is not navigable in
the current layer, the agent steps onto the layer above or below when that cell is navigable
there and its floor lies within the navmesh's climb of the floor it comes from (the stairs'
layer change; ``envs.navmesh_layers.transitions`` are the same steps for the graph). Geodesic
graph: each layer's 16-connected grid graph (``envs.geodesics.grid_graph``) plus those
transitions (8-neighbour moves between layers). Single-storey scenes keep ``NavGrid``.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import dijkstra

from calnav.common.jit import compiled
from calnav.envs.geodesics import MOVE_SAMPLE_FRACTION, _point_distance, cached_field, grid_graph
from calnav.envs.navmesh_layers import NEIGHBOURS_8, build_layered_navmesh, transitions


@compiled
def segment_layer(navigable, floor, ox, oy, cell, layer, ax, ay, bx, by, n, climb):
    """The layer the straight segment a -> b ends on when every one of its ``n`` samples (as
    ``envs.navigation._segment_navigable`` places them) is navigable in the layer the agent is
    on, changing layer at stairs (module docstring); -1 when it is blocked. navigable (L, H, W)
    bool, floor (L, H, W) float32 metres."""
    n_layers, h, w = navigable.shape
    step = 1.0 / (n - 1) if n > 1 else 0.0
    cur = layer
    col = int(np.floor((ax - ox) / cell))
    row = int(np.floor((ay - oy) / cell))
    if row < 0 or row >= h or col < 0 or col >= w:
        return -1
    prev_z = floor[cur, row, col]
    for i in range(n):
        t = i * step + 0.0 if i < n - 1 or n == 1 else 1.0
        px = ax + t * (bx - ax)
        py = ay + t * (by - ay)
        col = int(np.floor((px - ox) / cell))
        row = int(np.floor((py - oy) / cell))
        if row < 0 or row >= h or col < 0 or col >= w:
            return -1
        if navigable[cur, row, col]:
            prev_z = floor[cur, row, col]
            continue
        found = -1
        for other in (cur - 1, cur + 1):
            if 0 <= other < n_layers and navigable[other, row, col] and abs(floor[other, row, col] - prev_z) <= climb:
                found = other
                break
        if found < 0:
            return -1
        cur = found
        prev_z = floor[cur, row, col]
    return cur


@dataclass(eq=False)
class LayeredNavGrid:
    """Where the agent can stand in a house with storeys.

    navigable, free: (L, H, W) bool (after / before the radius erosion); floor_heights: (L, H,
    W) float32 metres (NaN off the ground); islands: (L, H, W) int32 (-1 off the navigable
    cells); storey_z: (L,) floor height of each storey, metres; bounds: (L - 1,) heights where
    one layer's band ends and the next begins, metres; climb_m: the navmesh's highest step;
    origin_xy (2,), cell_m, floor_z, stats as ``NavGrid``. Rows are y, columns x.
    """

    navigable: np.ndarray
    origin_xy: np.ndarray
    cell_m: float
    floor_heights: np.ndarray
    free: np.ndarray
    islands: np.ndarray
    storey_z: np.ndarray
    bounds: np.ndarray
    climb_m: float
    floor_z: float = 0.0
    stats: dict = field(default_factory=dict)
    _fields: OrderedDict = field(default_factory=OrderedDict, init=False, repr=False)
    _graph: tuple | None = field(default=None, init=False, repr=False)

    layered = True

    @classmethod
    def build(cls, scene, env_cfg) -> "LayeredNavGrid":
        """The layered grid of a house with ``scene.meta["storey_z"]`` (``envs.navmesh_layers``)."""
        mesh = build_layered_navmesh(scene, env_cfg)
        return cls(navigable=mesh.navigable, origin_xy=mesh.origin_xy, cell_m=mesh.cell_m,
                   floor_heights=mesh.floor_z, free=mesh.ground, islands=mesh.islands, storey_z=mesh.storey_z,
                   bounds=mesh.bounds, climb_m=float(env_cfg.navmesh.agent_max_climb_m),
                   floor_z=float(scene.floor_z), stats=mesh.stats)

    @property
    def n_layers(self) -> int:
        return int(self.navigable.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of one layer."""
        return self.navigable.shape[1:]

    # ---------------------------------------------------------- coordinates
    def to_cell(self, xy) -> tuple[int, int] | np.ndarray:
        """World xy (2,) -> (row, col); (N, 2) -> (N, 2) int64 (``NavGrid.to_cell``)."""
        col_row = np.floor((np.asarray(xy, dtype=np.float64) - self.origin_xy) / self.cell_m).astype(np.int64)
        rc = col_row[..., ::-1]
        return (int(rc[0]), int(rc[1])) if rc.ndim == 1 else rc

    def to_world(self, rc) -> np.ndarray:
        """(row, col) (2,) or (N, 2) -> world xy of the cell centres, metres."""
        return self.origin_xy + (np.asarray(rc, dtype=np.float64)[..., ::-1] + 0.5) * self.cell_m

    def in_grid(self, rc) -> np.ndarray | bool:
        rc = np.asarray(rc)
        h, w = self.shape
        inside = (rc[..., 0] >= 0) & (rc[..., 0] < h) & (rc[..., 1] >= 0) & (rc[..., 1] < w)
        return bool(inside) if inside.ndim == 0 else inside

    def is_navigable(self, xy, layer: int) -> bool:
        rc = self.to_cell(xy)
        return bool(self.in_grid(rc) and 0 <= layer < self.n_layers and self.navigable[(layer, *rc)])

    def island_of(self, xy, layer: int) -> int:
        """Island id of (xy, layer); -1 when it is not navigable."""
        return int(self.islands[(layer, *self.to_cell(xy))]) if self.is_navigable(xy, layer) else -1

    # -------------------------------------------------------------- storeys
    def floor_height(self, xy, layer: int) -> float:
        """Height of layer ``layer``'s ground under world point ``xy``, metres (that storey's
        floor height off its ground: a camera never drops through a floor)."""
        rc = self.to_cell(xy)
        if self.in_grid(rc):
            z = float(self.floor_heights[(layer, *rc)])
            if np.isfinite(z):
                return z
        return float(self.storey_z[layer])

    def storey_at(self, z: float) -> int:
        """The layer whose height band holds a floor at height ``z`` metres."""
        return int(np.searchsorted(self.bounds, z, side="right"))

    def locate(self, xy, height_m: float, tolerance_m: float = 0.3) -> int | None:
        """The layer whose ground under ``xy`` lies within ``tolerance_m`` of ``height_m`` (the
        nearest), or None."""
        rc = self.to_cell(xy)
        if not self.in_grid(rc):
            return None
        dz = np.abs(self.floor_heights[:, rc[0], rc[1]].astype(np.float64) - height_m)
        dz[~np.isfinite(dz)] = np.inf
        k = int(np.argmin(dz))
        return k if dz[k] <= tolerance_m else None

    def snap_point(self, xyz, max_distance_m: float) -> tuple[np.ndarray, int] | None:
        """(xy (2,), layer) of the navigable cell centre nearest to world point ``xyz`` (3,) in
        3-D (its floor height against xyz's z), or None when none lies within ``max_distance_m``."""
        p = np.asarray(xyz, dtype=np.float64)
        reach = int(math.ceil(max_distance_m / self.cell_m)) + 1
        r0, c0 = self.to_cell(p[:2])
        h, w = self.shape
        rs, cs = slice(max(0, r0 - reach), min(h, r0 + reach + 1)), slice(max(0, c0 - reach), min(w, c0 + reach + 1))
        cand = np.argwhere(self.navigable[:, rs, cs])
        if len(cand) == 0:
            return None
        rc = cand[:, 1:] + [rs.start, cs.start]
        xy = self.to_world(rc)
        z = self.floor_heights[cand[:, 0], rc[:, 0], rc[:, 1]].astype(np.float64)
        d = np.sqrt(((xy - p[:2]) ** 2).sum(axis=1) + (z - p[2]) ** 2)
        i = int(np.argmin(d))
        return (xy[i], int(cand[i, 0])) if d[i] <= max_distance_m else None

    def sample_navigable(self, rng: np.random.Generator, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """((n, 2) world xy, (n,) int64 layers) of uniformly drawn navigable cell centres."""
        cells = np.argwhere(self.navigable)
        pick = cells[rng.integers(0, len(cells), size=n)]
        return self.to_world(pick[:, 1:]), pick[:, 0].astype(np.int64)

    # --------------------------------------------------------------- motion
    def move_forward(self, xy, layer: int, yaw: float, distance: float) -> tuple[np.ndarray, int, bool]:
        """MOVE_FORWARD by ``distance`` metres along ``yaw`` (``NavGrid.move_forward``), up or
        down stairs: (new xy (2,), new layer, moved)."""
        start = np.asarray(xy, dtype=np.float64)
        end = start + distance * np.array([np.cos(yaw), np.sin(yaw)])
        new = self.segment_layer(start, layer, end)
        return (end, new, True) if new >= 0 else (start.copy(), int(layer), False)

    def segment_layer(self, a_xy, layer: int, b_xy) -> int:
        """The layer the straight segment a -> b ends on, starting on ``layer``; -1 when blocked."""
        a, b = np.asarray(a_xy, dtype=np.float64), np.asarray(b_xy, dtype=np.float64)
        n = int(np.ceil(np.linalg.norm(b - a) / (MOVE_SAMPLE_FRACTION * self.cell_m))) + 1
        return int(segment_layer(self.navigable, self.floor_heights, float(self.origin_xy[0]), float(self.origin_xy[1]),
                                 float(self.cell_m), int(layer), float(a[0]), float(a[1]), float(b[0]), float(b[1]), n,
                                 float(self.climb_m)))

    # ------------------------------------------------------------ geodesics
    @property
    def graph(self) -> tuple[sparse.csr_matrix, np.ndarray]:
        """(CSR graph over every layer's navigable cells, metres; (L, H, W) node index, -1 off
        the navigable cells), built on first use."""
        if self._graph is None:
            node = np.full(self.navigable.shape, -1, np.int64)
            blocks, offset = [], 0
            for k in range(self.n_layers):
                g, node_k, _ = grid_graph(self.navigable[k], self.cell_m)
                node[k][node_k >= 0] = node_k[node_k >= 0] + offset
                blocks.append(g)
                offset += g.shape[0]
            rows, cols, lengths = [], [], []
            for a, b, k, ok in transitions(self.navigable, self.floor_heights, self.climb_m):
                dr, dc = NEIGHBOURS_8[k]
                r, c = np.nonzero(ok)
                rows.append(node[a, r, c])
                cols.append(node[b, r + dr, c + dc])
                lengths.append(np.full(len(r), math.hypot(dr, dc) * self.cell_m))
            cross = sparse.csr_matrix((np.concatenate(lengths + [np.zeros(0)]),
                                       (np.concatenate(rows + [np.zeros(0, np.int64)]),
                                        np.concatenate(cols + [np.zeros(0, np.int64)]))), shape=(offset, offset))
            self._graph = (sparse.block_diag(blocks, format="csr") + cross).tocsr(), node
        return self._graph

    def geodesic_field(self, goal_mask: np.ndarray, use_cache: bool = True) -> "LayeredGeodesicField":
        """Distance-to-goal field for ``goal_mask`` ((L, H, W) bool); cached by its hash."""
        return cached_field(self._fields, goal_mask, self.navigable.shape,
                            lambda m: LayeredGeodesicField.compute(self, m), use_cache)

class LayeredGeodesicField:
    """Geodesic distance to a goal set over a ``LayeredNavGrid``. distances_m (alias
    ``values``): (L, H, W) float64 metres (inf off the navigable cells or unreachable, 0 on
    goal cells); goal_mask: (L, H, W) bool."""

    def __init__(self, grid: LayeredNavGrid, goal_mask: np.ndarray, distances_m: np.ndarray):
        self.grid, self.goal_mask, self.distances_m = grid, goal_mask, distances_m

    @property
    def values(self) -> np.ndarray:
        return self.distances_m

    @classmethod
    def compute(cls, grid: LayeredNavGrid, goal_mask: np.ndarray) -> "LayeredGeodesicField":
        goals = goal_mask & grid.navigable
        out = np.full(grid.navigable.shape, np.inf)
        if goals.any():
            graph, node = grid.graph
            # every edge is stored both ways with one length: distances from the goals are to them
            dist = dijkstra(graph, directed=True, indices=node[goals], min_only=True)
            out[grid.navigable] = dist[node[grid.navigable]]
        return cls(grid, goals, out)

    def distance(self, xy, layer) -> float | np.ndarray:
        """Geodesic distance in metres from (xy, layer): (2,), int -> float; (N, 2), (N,) ->
        (N,). Bilinear over the layer's nearest cell centres, as ``GeodesicField.distance``."""
        g = self.grid
        ox, oy, cell = float(g.origin_xy[0]), float(g.origin_xy[1]), float(g.cell_m)
        if np.ndim(xy) == 1:
            k = int(layer)
            return float(_point_distance(self.distances_m[k], self.goal_mask[k], ox, oy, cell, float(xy[0]),
                                         float(xy[1])))
        pts, layers = np.asarray(xy, np.float64), np.asarray(layer, np.int64)
        return np.array([_point_distance(self.distances_m[k], self.goal_mask[k], ox, oy, cell, float(p[0]), float(p[1]))
                         for p, k in zip(pts, layers)])
