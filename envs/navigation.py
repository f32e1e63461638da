"""Navigable grid, agent motion and geodesic distances.

The navigable area is a 2D grid (``EnvConfig.nav_cell_m``, 5 cm) over the scene's xy bounds;
row = y index, col = x index, cell (0, 0)'s lower corner at ``origin_xy``.
Geodesic distance fields live in ``envs.geodesics``.
"""
from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, sparse

from calnav.envs.geodesics import GeodesicField, grid_graph
from calnav.envs.scene import Scene, sample_surface

FLOOR_TOL_M = 0.03          # a ray's first hit counts as floor within this of floor_z, metres
RAYS_PER_CELL_SIDE = 3      # sub-sampled ray points per cell side (1.7 cm apart: thin legs show)
RAY_START_BELOW_TOP_M = 0.005   # rays start this far below the agent's top, metres
CAST_CHUNK_RAYS = 1 << 20   # rays cast per call (bounds memory on big scenes)
FIELD_CACHE_SIZE = 8        # geodesic fields kept per NavGrid (LRU)
MOVE_SAMPLE_FRACTION = 0.5  # move_forward checks the segment every this many cells
OBSTACLE_SAMPLE_FRACTION = 0.5  # obstacle surfaces are sampled every this many cells
OBSTACLE_SEED = 0           # surface sampling is random but fixed: the grid is deterministic


def closed_solids(scene: Scene) -> bool:
    """Whether the scene is built of closed, outward-facing solids (``envs.primitives``: the
    procedural houses), so that face orientation tells inside from outside. Scans (calnav's
    scanned houses, labelled PLYs) say ``meta["closed_solids"] = False``: open surfaces whose
    normals are unreliable where the surface is thin or noisy."""
    return bool(scene.meta.get("closed_solids", True))


def _free_floor(scene: Scene, rc, origin: np.ndarray, shape: tuple[int, int], cell: float,
                agent_height: float, floor_id: int) -> np.ndarray:
    """(H, W) bool: every sub-sampled point of the cell has bare floor under the agent.

    Per point two rays: one down from just below the agent's top, whose first hit must be
    a front-facing ``floor`` triangle within FLOOR_TOL_M of floor_z; and one up from
    FLOOR_TOL_M above the floor, which must hit nothing below the agent's top and no back
    face. The up ray catches points inside closed solids taller than the agent (walls,
    wardrobes): there the down ray starts inside the solid and may report the floor that
    coincides with the solid's bottom face. Assumes outward-facing (counter-clockwise)
    triangles on closed solids, as ``envs.primitives`` builds them. Scans (``closed_solids``
    False) have no inside: there any up hit above the agent's top is fine, whatever its facing
    (the underside of a scanned door lintel is a noisy sheet with normals of both signs).
    """
    import open3d as o3d

    h, w = shape
    s = RAYS_PER_CELL_SIDE
    sub = (np.arange(s) + 0.5) / s * cell  # sub-ray offsets inside a cell
    xs = (origin[0] + np.arange(w)[:, None] * cell + sub[None, :]).ravel()  # (W * s,)
    ys = (origin[1] + np.arange(h)[:, None] * cell + sub[None, :]).ravel()  # (H * s,)
    z_top = scene.floor_z + agent_height - RAY_START_BELOW_TOP_M
    z_low = scene.floor_z + FLOOR_TOL_M
    tri_class = np.append(scene.tri_class, np.int16(-1))  # extra row for misses
    closed = closed_solids(scene)
    ok = np.empty((len(ys), len(xs)), dtype=bool)
    rows_per_chunk = max(1, CAST_CHUNK_RAYS // (2 * len(xs)))
    for r0 in range(0, len(ys), rows_per_chunk):
        yy = ys[r0:r0 + rows_per_chunk]
        rays = np.zeros((2, len(yy), len(xs), 6), dtype=np.float32)  # [0] down, [1] up
        rays[..., 0] = xs[None, None, :]
        rays[..., 1] = yy[None, :, None]
        rays[0, ..., 2], rays[0, ..., 5] = z_top, -1.0
        rays[1, ..., 2], rays[1, ..., 5] = z_low, 1.0
        hit = rc.cast_rays(o3d.core.Tensor(rays))
        t = hit["t_hit"].numpy()
        nz = hit["primitive_normals"].numpy()[..., 2]
        prim = np.minimum(hit["primitive_ids"].numpy(), len(scene.triangles)).astype(np.intp)
        down_ok = (tri_class[prim[0]] == floor_id) & (np.abs(z_top - t[0] - scene.floor_z) < FLOOR_TOL_M) & (nz[0] > 0)
        above = z_low + t[1] >= z_top
        up_ok = np.isinf(t[1]) | ((above & (nz[1] < 0)) if closed else above)
        ok[r0:r0 + len(yy)] = down_ok & up_ok
    return ok.reshape(h, s, w, s).all(axis=(1, 3))


def _band_obstacles(scene: Scene, origin: np.ndarray, shape: tuple[int, int], cell: float,
                    z_lo: float, z_hi: float, passable_ids: tuple[int, ...]) -> np.ndarray:
    """(H, W) bool: cells that some obstacle surface crosses inside the agent's height band.

    Every triangle that is not floor or ceiling (``passable_ids``; void clutter counts as an
    obstacle) is sampled at OBSTACLE_SAMPLE_FRACTION cells spacing and its points with z in
    [z_lo, z_hi] mark their cells. This does not depend on where rays start or on face
    orientation, so it holds where ray tests are ambiguous: inside closed solids whose faces
    coincide with the floor or the ceiling (every wall).
    """
    keep = ~np.isin(scene.tri_class, passable_ids)
    tris = scene.vertices[scene.triangles[keep]].astype(np.float64)
    z = tris[..., 2]
    tris = tris[(z.max(axis=1) >= z_lo) & (z.min(axis=1) <= z_hi)]
    blocked = np.zeros(shape, dtype=bool)
    if len(tris) == 0:
        return blocked
    pts = sample_surface(tris, OBSTACLE_SAMPLE_FRACTION * cell, np.random.default_rng(OBSTACLE_SEED))
    pts = pts[(pts[:, 2] >= z_lo) & (pts[:, 2] <= z_hi)]
    col_row = np.floor((pts[:, :2] - origin) / cell).astype(np.int64)
    h, w = shape
    inside = (col_row[:, 0] >= 0) & (col_row[:, 0] < w) & (col_row[:, 1] >= 0) & (col_row[:, 1] < h)
    blocked[col_row[inside, 1], col_row[inside, 0]] = True
    return blocked


@dataclass(eq=False)
class NavGrid:
    """Where the agent (a cylinder) can stand.

    navigable: (H, W) bool, row = y index, col = x index; the largest 8-connected component
    of free floor eroded by the agent radius. free: (H, W) bool free floor before erosion.
    origin_xy: (2,) float64 world xy of cell (0, 0)'s lower corner, metres. cell_m: cell
    side, metres. floor_z: world z of the floor, metres.
    """

    navigable: np.ndarray
    origin_xy: np.ndarray
    cell_m: float
    floor_z: float = 0.0
    free: np.ndarray | None = None
    _fields: OrderedDict = field(default_factory=OrderedDict, init=False, repr=False)
    _graph: tuple | None = field(default=None, init=False, repr=False)

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
    def build(cls, scene: Scene, env_cfg, raycasting_scene=None) -> "NavGrid":
        """Rasterise ``scene`` for an agent of ``env_cfg`` (nav_cell_m, agent_radius_m,
        agent_height_m).

        A cell is free floor when at each of its RAYS_PER_CELL_SIDE^2 sub-sampled points (1.7
        cm apart, so thin legs are not missed) a down ray cast from just below the agent's
        top (agent_height_m above the floor) first hits a ``floor`` triangle within
        FLOOR_TOL_M of ``scene.floor_z``, and an up ray finds nothing overhead below the
        agent's top (see ``_free_floor``). Anything hit first above the floor (an obstacle in
        the agent's height band from obstacle_min_height_m up to agent_height_m, but also
        unlabelled low clutter) blocks the cell; things above the agent's top (shelves,
        ceilings) do not. Ray tests are ambiguous inside closed solids whose faces coincide
        with the floor or ceiling (walls), so obstacle surfaces crossing the height band are
        also rasterised directly (``_band_obstacles``). Free floor is eroded by a disk of radius
        agent_radius_m + cell_m / 2 (the half cell accounts for where the obstacle edge lies
        inside its cells: true clearance >= radius - cell / 6). Only the largest 8-connected
        component is kept: unreachable islands (inside closets with too-narrow doors, behind
        furniture) would give episodes with no path and infinite geodesics.
        Raises ValueError if nothing is navigable.
        """
        from calnav.envs.render import build_raycasting_scene

        if "floor" not in scene.class_names:
            raise ValueError(f"scene {scene.name!r} has no 'floor' class; cannot find navigable floor")
        floor_id = scene.class_names.index("floor")
        cell = float(env_cfg.nav_cell_m)
        lo, hi = scene.bounds()
        origin = lo[:2].astype(np.float64)
        w = max(1, int(np.ceil((hi[0] - lo[0]) / cell)))
        h = max(1, int(np.ceil((hi[1] - lo[1]) / cell)))
        rc = raycasting_scene if raycasting_scene is not None else build_raycasting_scene(scene)

        free = _free_floor(scene, rc, origin, (h, w), cell, env_cfg.agent_height_m, floor_id)
        passable = tuple(scene.class_names.index(n) for n in ("floor", "ceiling") if n in scene.class_names)
        free &= ~_band_obstacles(scene, origin, (h, w), cell, scene.floor_z + env_cfg.obstacle_min_height_m,
                                 scene.floor_z + env_cfg.agent_height_m, passable)
        # erosion: keep cells farther than radius + cell/2 from every blocked cell centre
        # (pad so the grid border counts as blocked)
        clearance = ndimage.distance_transform_edt(np.pad(free, 1))[1:-1, 1:-1] * cell
        navigable = clearance > env_cfg.agent_radius_m + cell / 2
        labels, n = ndimage.label(navigable, structure=np.ones((3, 3), dtype=bool))
        if n == 0:
            raise ValueError(
                f"scene {scene.name!r} has no navigable area for an agent of radius "
                f"{env_cfg.agent_radius_m} m and height {env_cfg.agent_height_m} m "
                f"(floor at z = {scene.floor_z} m must be labelled 'floor' and unobstructed)")
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        navigable = labels == int(np.argmax(sizes))
        return cls(navigable=navigable, origin_xy=origin, cell_m=cell, floor_z=float(scene.floor_z), free=free)

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
        return bool(self.is_navigable(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)).all())

    # ------------------------------------------------------------ geodesics
    def geodesic_field(self, goal_mask: np.ndarray, use_cache: bool = True) -> "GeodesicField":
        """Distance-to-goal field for ``goal_mask`` ((H, W) bool; only its navigable cells are
        goals). Cached (LRU, FIELD_CACHE_SIZE fields) by a hash of the mask."""
        goal_mask = np.asarray(goal_mask, dtype=bool)
        if goal_mask.shape != self.navigable.shape:
            raise ValueError(f"goal_mask must have the grid's shape {self.navigable.shape}, got {goal_mask.shape}")
        key = hashlib.blake2b(np.packbits(goal_mask).tobytes(), digest_size=16).digest()
        if use_cache and key in self._fields:
            self._fields.move_to_end(key)
            return self._fields[key]
        result = GeodesicField.compute(self, goal_mask)
        if use_cache:
            self._fields[key] = result
            while len(self._fields) > FIELD_CACHE_SIZE:
                self._fields.popitem(last=False)
        return result

    def geodesic_distance(self, a_xy, b_xy) -> float:
        """Geodesic distance (metres) from a to b's cell; inf if either is not navigable."""
        rc = self.to_cell(b_xy)
        mask = np.zeros(self.navigable.shape, dtype=bool)
        if self.in_grid(rc):
            mask[rc] = True
        return float(self.geodesic_field(mask).distance(a_xy))
