"""Navigable grid, agent motion and geodesic distances.

The navigable area is a 2D grid (``EnvConfig.nav_cell_m``, 5 cm) over the scene's xy bounds;
row = y index, col = x index, cell (0, 0)'s lower corner at ``origin_xy``. It is computed as
habitat-sim computes its navmesh, from the geometry alone (``envs.navmesh``). Geodesic distance
fields live in ``envs.geodesics``.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse

from calnav.common.jit import compiled
from calnav.envs.geodesics import MOVE_SAMPLE_FRACTION, GeodesicField, cached_field, grid_graph
from calnav.envs.navmesh import build_navmesh
from calnav.envs.scene import Scene

# Peak memory of a scene's navigation per grid cell, bytes: the span heightfield, the navmesh's
# (H, W) layers, the cell graph and the geodesic fields of episode generation. Measured (numpy's
# peak under tracemalloc, NavGrid.build + generating 5 episodes of house_val_0001): 415 B/cell at
# nav_cell_m = 0.025, 358 at 0.0125 (the scene's fixed share shrinks as cells get finer).
NAV_PEAK_BYTES_PER_CELL = 400


def estimate_bytes(extent_m: tuple[float, float], cell_m: float) -> int:
    """Peak bytes of building the navigation of a scene whose xy bounds are ``extent_m``
    (width, depth) metres on cells of ``cell_m`` metres (``NAV_PEAK_BYTES_PER_CELL`` per cell)."""
    cells = np.prod([np.ceil(side / cell_m) for side in extent_m])
    return int(cells * NAV_PEAK_BYTES_PER_CELL)


@compiled
def _segment_navigable(navigable, ox, oy, cell, ax, ay, bx, by, n):
    """``NavGrid.segment_navigable`` compiled: the ``n`` points a + t (b - a), t = i / (n - 1)
    as numpy's linspace makes them (the last exactly b), each on a navigable cell."""
    h, w = navigable.shape
    step = 1.0 / (n - 1) if n > 1 else 0.0
    for i in range(n):
        t = i * step + 0.0 if i < n - 1 or n == 1 else 1.0
        px = ax + t * (bx - ax)
        py = ay + t * (by - ay)
        col = int(np.floor((px - ox) / cell))
        row = int(np.floor((py - oy) / cell))
        if row < 0 or row >= h or col < 0 or col >= w or not navigable[row, col]:
            return False
    return True


@dataclass(eq=False)
class NavGrid:
    """Where the agent (a cylinder) can stand.

    navigable: (H, W) bool, row = y index, col = x index; the navmesh's islands (``envs.navmesh``:
    walkable ground eroded by the agent radius, islands under ``region_min_size``^2 cells
    dropped). free: (H, W) bool walkable ground before the erosion. floor_heights: (H, W)
    float32 height of the ground under each cell, metres (NaN off the ground): the agent stands
    there. islands: (H, W) int32 island id per navigable cell (-1 elsewhere; 0 = the largest).
    origin_xy: (2,) float64 world xy of cell (0, 0)'s lower corner, metres. cell_m: cell side,
    metres. floor_z: the scene's reference floor height, metres. stats: the navmesh's figures.
    """

    navigable: np.ndarray
    origin_xy: np.ndarray
    cell_m: float
    floor_z: float = 0.0
    free: np.ndarray | None = None
    floor_heights: np.ndarray | None = None
    islands: np.ndarray | None = None
    stats: dict = field(default_factory=dict)
    _fields: OrderedDict = field(default_factory=OrderedDict, init=False, repr=False)
    _graph: tuple | None = field(default=None, init=False, repr=False)

    layered = False   # one storey; ``envs.layered_navigation.LayeredNavGrid`` (True) has a layer per storey

    @property
    def graph(self) -> tuple[sparse.csr_matrix, np.ndarray, np.ndarray]:
        """(CSR graph over navigable cells, (H, W) node index, (N, 2) node cells); built on
        first use (cached)."""
        if self._graph is None:
            self._graph = grid_graph(self.navigable, self.cell_m)
        return self._graph

    @property
    def shape(self) -> tuple[int, int]:
        return self.navigable.shape

    # ------------------------------------------------------------- building
    @classmethod
    def build(cls, scene: Scene, env_cfg, raycasting_scene=None):
        """The navigable grid of ``scene`` for the agent of ``env_cfg`` (``nav_cell_m``,
        ``agent_radius_m``, ``agent_height_m``, ``navmesh``): ``envs.navmesh.build_navmesh``.
        ``raycasting_scene`` is accepted for callers that hold one; the navmesh does not cast
        rays. A house with storeys (``scene.meta["storey_z"]``, more than one) gets a
        ``LayeredNavGrid`` instead. Raises ValueError if nothing is navigable."""
        if len(scene.meta.get("storey_z", ())) > 1:
            from calnav.envs.layered_navigation import LayeredNavGrid

            return LayeredNavGrid.build(scene, env_cfg)
        mesh = build_navmesh(scene, env_cfg)
        return cls(navigable=mesh.navigable, origin_xy=mesh.origin_xy, cell_m=mesh.cell_m,
                   floor_z=float(scene.floor_z), free=mesh.ground, floor_heights=mesh.floor_z,
                   islands=mesh.islands, stats=mesh.stats)

    def floor_height(self, xy) -> float:
        """Height of the ground under world point ``xy`` (2,), metres: where an agent standing
        there has its feet (the scene's floor_z off the ground or off the grid)."""
        rc = self.to_cell(xy)
        if self.floor_heights is None or not self.in_grid(rc):
            return float(self.floor_z)
        z = float(self.floor_heights[rc])
        return z if np.isfinite(z) else float(self.floor_z)

    def island_of(self, xy) -> int:
        """Island id (0 = the largest) of world point ``xy`` (2,); -1 when it is not navigable."""
        rc = self.to_cell(xy)
        if not self.in_grid(rc) or not self.navigable[rc]:
            return -1
        return int(self.islands[rc]) if self.islands is not None else 0

    # ---------------------------------------------------------- coordinates
    def to_cell(self, xy) -> tuple[int, int] | np.ndarray:
        """World xy (2,) -> (row, col) ints; (N, 2) -> (N, 2) int64 [row, col]. May lie
        outside the grid (check with ``in_grid``)."""
        xy = np.asarray(xy, dtype=np.float64)
        col_row = np.floor((xy - self.origin_xy) / self.cell_m).astype(np.int64)
        rc = col_row[..., ::-1]
        return (int(rc[0]), int(rc[1])) if rc.ndim == 1 else rc

    def to_world(self, rc) -> np.ndarray:
        """(row, col) (2,) or (N, 2) -> world xy of the cell centres, float64 metres."""
        rc = np.asarray(rc, dtype=np.float64)
        return self.origin_xy + (rc[..., ::-1] + 0.5) * self.cell_m

    def in_grid(self, rc) -> np.ndarray | bool:
        rc = np.asarray(rc)
        h, w = self.navigable.shape
        inside = (rc[..., 0] >= 0) & (rc[..., 0] < h) & (rc[..., 1] >= 0) & (rc[..., 1] < w)
        return bool(inside) if inside.ndim == 0 else inside

    def is_navigable(self, xy) -> bool | np.ndarray:
        """xy (2,) -> bool; (N, 2) -> (N,) bool. False outside the grid."""
        rc = np.atleast_2d(np.asarray(self.to_cell(np.atleast_2d(xy))))
        inside = self.in_grid(rc)
        out = np.zeros(len(rc), dtype=bool)
        out[inside] = self.navigable[rc[inside, 0], rc[inside, 1]]
        return bool(out[0]) if np.ndim(xy) == 1 else out

    def sample_navigable(self, rng: np.random.Generator, n: int = 1) -> np.ndarray:
        """(n, 2) float64 world xy of uniformly drawn navigable cell centres."""
        cells = np.argwhere(self.navigable)
        return self.to_world(cells[rng.integers(0, len(cells), size=n)])

    # --------------------------------------------------------------- motion
    def move_forward(self, xy, yaw: float, distance: float) -> tuple[np.ndarray, bool]:
        """Habitat MOVE_FORWARD with sliding off: move ``distance`` metres along heading
        ``yaw`` (radians, counter-clockwise from +x) if the whole straight segment stays
        navigable (checked every MOVE_SAMPLE_FRACTION cells), else do not move at all.
        Returns (new xy (2,) float64, moved)."""
        start = np.asarray(xy, dtype=np.float64)
        end = start + distance * np.array([np.cos(yaw), np.sin(yaw)])
        return (end, True) if self.segment_navigable(start, end) else (start.copy(), False)

    def segment_navigable(self, a_xy, b_xy) -> bool:
        """Whether the straight segment a -> b stays on navigable cells (sampled at most every
        MOVE_SAMPLE_FRACTION cells, both ends included)."""
        a, b = np.asarray(a_xy, dtype=np.float64), np.asarray(b_xy, dtype=np.float64)
        n = int(np.ceil(np.linalg.norm(b - a) / (MOVE_SAMPLE_FRACTION * self.cell_m))) + 1
        return bool(_segment_navigable(self.navigable, float(self.origin_xy[0]), float(self.origin_xy[1]),
                                       float(self.cell_m), float(a[0]), float(a[1]), float(b[0]), float(b[1]), n))

    # ------------------------------------------------------------ geodesics
    def geodesic_field(self, goal_mask: np.ndarray, use_cache: bool = True) -> "GeodesicField":
        """Distance-to-goal field for ``goal_mask`` ((H, W) bool; only its navigable cells are
        goals). Cached (LRU, FIELD_CACHE_SIZE fields) by a hash of the mask."""
        return cached_field(self._fields, goal_mask, self.navigable.shape,
                            lambda m: GeodesicField.compute(self, m), use_cache)

    def geodesic_distance(self, a_xy, b_xy) -> float:
        """Geodesic distance (metres) from a to b's cell; inf if either is not navigable."""
        rc = self.to_cell(b_xy)
        mask = np.zeros(self.navigable.shape, dtype=bool)
        if self.in_grid(rc):
            mask[rc] = True
        return float(self.geodesic_field(mask).distance(a_xy))
