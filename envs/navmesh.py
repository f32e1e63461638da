"""Navigable space as habitat-sim computes its navmesh (Recast), from the scene's geometry only.

    heightfield = every triangle rasterised into spans (``envs.heightfield``), walkable where
                  its slope is below agent_max_slope_deg
    filters     = low hanging obstacles (step onto what is at most agent_max_climb_m high),
                  ledges (no drop of more than the climb next to a walkable cell: hole edges),
                  low height (the agent must fit under what is above)
    surfaces    = walkable spans linked to their 4-neighbours (step <= climb, room to stand)
    ground      = the storey's surfaces: the largest one and every other within one climb of
                  its height (table tops, sofa seats, bed tops and a scan's wall tops are not)
    navigable   = ground eroded by the agent radius, islands below region_min_size^2 cells dropped

Semantic labels play no part: an unlabelled floor is floor. What differs from habitat-sim: the
result is a 2D grid (one storey; calnav's houses with storeys get one layer per storey from
``envs.navmesh_layers``, which reuses ``build_heightfield``) rather than polygons, and the
erosion is the Euclidean clearance ``agent_radius_m + cell / 2`` from any cell that is not
ground (Recast's chamfer erosion by ceil(radius / cell) cells keeps the same cells along the
axes), so the agent's planner, which dilates its obstacles by that clearance, sees the same gaps.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from calnav.envs import heightfield as hf
from calnav.envs.scene import Scene


def closed_solids(scene: Scene) -> bool:
    """Whether the scene is built of closed, outward-facing solids (``envs.primitives``: the
    procedural houses), so that a face's orientation tells up from down. Scans (calnav's scanned
    houses, labelled PLYs) say ``meta["closed_solids"] = False``: open surfaces whose winding
    may be either way (a PLY converted from y-up by swapping axes flips every face), so there a
    surface's slope is judged from |normal z|."""
    return bool(scene.meta.get("closed_solids", True))


@dataclass
class NavMesh:
    """A scene's navigable space on the 2D grid.

    navigable: (H, W) bool, row = y index, col = x index. ground: (H, W) bool walkable ground
    before the erosion (cells at an impassable step excluded). floor_z: (H, W) float32 height
    of the ground surface, metres (NaN off the ground). clearance: (H, W) float64 distance
    from each cell centre to the nearest cell that is not ground, metres. islands: (H, W)
    int32 island id of each navigable cell (-1 elsewhere), ids 0..n-1 by decreasing area.
    eroded: (H, W) int32 every piece of the eroded ground before small ones are dropped (0 =
    none, pieces 1..m). origin_xy: (2,) float64 world xy of cell (0, 0)'s lower corner.
    cell_m: cell side, metres. stats: the figures ``calnav check-scene`` reports (areas m^2).
    """

    navigable: np.ndarray
    ground: np.ndarray
    floor_z: np.ndarray
    clearance: np.ndarray
    islands: np.ndarray
    eroded: np.ndarray
    origin_xy: np.ndarray
    cell_m: float
    stats: dict


def triangle_walkable(scene: Scene, max_slope_deg: float) -> np.ndarray:
    """(F,) bool: the triangle's surface is at most ``max_slope_deg`` from horizontal (its
    normal's z above cos(slope); |z| on open scans, see ``closed_solids``); degenerate
    triangles are not walkable."""
    tris = scene.vertices[scene.triangles].astype(np.float64)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    length = np.linalg.norm(n, axis=1)
    nz = n[:, 2] / np.maximum(length, 1e-300)
    if not closed_solids(scene):
        nz = np.abs(nz)
    return (length > 0) & (nz > math.cos(math.radians(max_slope_deg)))


def _units(env_cfg) -> tuple[float, int, int]:
    """(cell height m, walkable height units, walkable climb units): Recast rounds the agent's
    height up and its climb down."""
    nm = env_cfg.navmesh
    ch = float(nm.cell_height_m)
    return ch, int(math.ceil(env_cfg.agent_height_m / ch - 1e-9)), int(math.floor(nm.agent_max_climb_m / ch + 1e-9))


def build_heightfield(scene: Scene, env_cfg) -> dict:
    """The filtered span heightfield of ``scene`` (``envs.heightfield`` conventions) with its
    surface links and labels: a dict of shape (h, w), origin (3,), the CSR span arrays start /
    smin / smax / area / ztop, con (S, 4), surface (S,) labels (-1 off any surface)."""
    nm = env_cfg.navmesh
    cell = float(env_cfg.nav_cell_m)
    ch, walk_height, climb = _units(env_cfg)
    lo, hi = scene.bounds()
    origin = lo.astype(np.float64)
    w = max(1, int(np.ceil((hi[0] - lo[0]) / cell)))
    h = max(1, int(np.ceil((hi[1] - lo[1]) / cell)))
    zrange = float(hi[2] - lo[2])
    tris = scene.vertices[scene.triangles].astype(np.float64)
    walkable = triangle_walkable(scene, nm.agent_max_slope_deg)
    col, smin, smax, area, ztop = hf.rasterise(tris, walkable, origin, cell, ch, w, h, zrange)
    order = np.lexsort((smin, col))
    start, smin, smax, area, ztop = hf.merge_spans(col[order], smin[order], smax[order], area[order], ztop[order],
                                                   h * w, climb)
    if nm.filter_low_hanging_obstacles:
        hf.filter_low_hanging(start, smax, area, climb)
    if nm.filter_ledge_spans:
        hf.filter_ledges(start, smin, smax, area, w, h, walk_height, climb)
    if nm.filter_walkable_low_height_spans:
        hf.filter_low_height(start, smin, smax, area, walk_height)
    con = hf.connections(start, smin, smax, area, w, h, walk_height, climb)
    surface = hf.components(con, area)
    return {"shape": (h, w), "origin": origin, "start": start, "smin": smin, "smax": smax, "area": area,
            "ztop": ztop, "con": con, "surface": surface, "climb": climb}


def _ground(field: dict) -> tuple[np.ndarray, np.ndarray, dict]:
    """((H, W) int64 span index of each column's ground span or -1, (H, W) bool cells whose
    ground does not link to a 4-neighbour's ground (a step the agent cannot take: treated as
    an obstacle edge, as Recast's erosion treats unlinked spans), surface figures)."""
    h, w = field["shape"]
    start, smax, surface, con = field["start"], field["smax"], field["surface"], field["con"]
    walk = np.flatnonzero(surface >= 0)
    ground = np.full(h * w, -1, np.int64)
    info = {"surfaces": 0, "ground_surfaces": 0}
    if len(walk) == 0:
        return ground.reshape(h, w), np.zeros((h, w), bool), info
    labels = surface[walk]
    sizes = np.bincount(labels)
    heights = np.array([np.median(smax[walk[labels == k]]) for k in range(len(sizes))])
    main = int(np.argmax(sizes))
    storey = np.abs(heights - heights[main]) <= field["climb"]
    info.update(surfaces=int(len(sizes)), ground_surfaces=int(storey.sum()))
    keep = walk[storey[labels]]
    cols = np.searchsorted(start, keep, side="right") - 1   # the column of each span
    # the lowest storey span of a column wins (two would mean a second storey overhead)
    first = np.unique(cols, return_index=True)[1]
    ground[cols[first]] = keep[first]
    grid = ground.reshape(h, w)
    edge = np.zeros((h, w), bool)
    for d, (dr, dc) in enumerate(((0, -1), (1, 0), (0, 1), (-1, 0))):
        nb = np.full((h, w), -1, np.int64)   # the neighbour column's ground span
        nb[max(0, -dr):h - max(0, dr), max(0, -dc):w - max(0, dc)] = grid[max(0, dr):h + min(0, dr),
                                                                          max(0, dc):w + min(0, dc)]
        linked = np.full((h, w), -1, np.int64)
        has = grid >= 0
        linked[has] = con[grid[has], d]
        edge |= has & (nb >= 0) & (linked != nb)
    return grid, edge, info


def build_navmesh(scene: Scene, env_cfg, require_navigable: bool = True) -> NavMesh:
    """The navigable space of ``scene`` for the agent of ``env_cfg`` (``nav_cell_m``,
    ``agent_radius_m``, ``agent_height_m``, ``navmesh``); see the module docstring. Raises
    ValueError naming the scene when nothing is navigable (unless ``require_navigable`` is
    False: a report of what a scene holds)."""
    cell = float(env_cfg.nav_cell_m)
    field = build_heightfield(scene, env_cfg)
    h, w = field["shape"]
    span, edge, surfaces = _ground(field)
    ground = span >= 0
    floor_z = np.full((h, w), np.nan, np.float32)
    floor_z[ground] = field["ztop"][span[ground]]
    free = ground & ~edge
    # erosion: keep cells farther than radius + cell/2 from every non-ground cell centre (pad
    # so that the grid border counts as blocked)
    clearance = ndimage.distance_transform_edt(np.pad(free, 1))[1:-1, 1:-1] * cell
    eroded = clearance > env_cfg.agent_radius_m + cell / 2
    labels, n = ndimage.label(eroded, structure=np.ones((3, 3), dtype=bool))
    sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    min_cells = int(env_cfg.navmesh.region_min_size) ** 2
    kept = np.flatnonzero(sizes >= max(min_cells, 1))
    kept = kept[np.argsort(-sizes[kept], kind="stable")]
    lut = np.full(n + 1, -1, np.int32)
    lut[kept + 1] = np.arange(len(kept), dtype=np.int32)
    islands = lut[labels]
    navigable = islands >= 0
    if require_navigable and not navigable.any():
        raise ValueError(
            f"scene {scene.name!r} has no navigable area for an agent of radius {env_cfg.agent_radius_m} m and "
            f"height {env_cfg.agent_height_m} m: no walkable floor (slope <= {env_cfg.navmesh.agent_max_slope_deg} "
            f"deg, {env_cfg.agent_height_m} m of clearance) leaves an island of at least "
            f"{env_cfg.navmesh.region_min_size}^2 cells after the radius erosion")
    area = cell * cell
    stats = {
        "ground_m2": float(free.sum() * area), "navigable_m2": float(navigable.sum() * area),
        "islands": int(len(kept)), "island_m2": [float(sizes[k] * area) for k in kept],
        "dropped_islands": int(n - len(kept)), "dropped_m2": float((sizes.sum() - sizes[kept].sum()) * area),
        **surfaces,   # walkable surfaces in all, and those that make the storey's ground
    }
    return NavMesh(navigable=navigable, ground=free, floor_z=floor_z, clearance=clearance, islands=islands,
                   eroded=labels.astype(np.int32), origin_xy=field["origin"][:2].copy(), cell_m=cell, stats=stats)
