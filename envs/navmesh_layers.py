"""The navmesh of a house with storeys: one (H, W) layer per storey, joined where stairs cross.

``envs.navmesh`` keeps one storey: the lowest ground span of each column. A house with
``meta["storey_z"]`` (``envs.house``, ``storeys > 1``) has a floor above a floor, so here every
walkable span of the ground surfaces goes to the layer of its height band:

    band k      = [b_(k-1), b_k), b_k = storey_z[k] + LAYER_SPLIT x storey height (b_-1 = -inf,
                  the last band open above): a flight of stairs changes layer once, part-way
                  up, and the half-way landing (at 0.5) lies wholly in the lower layer
    ground      = the largest walkable surface (the floors and stairs join into one) and every
                  other within one climb of a storey's floor height
    layer k     = per column, the lowest ground span in band k
    transitions = 8-neighbour cells of adjacent layers whose floors differ by at most the
                  climb (only stairs: elsewhere the layers lie a storey apart)

The radius erosion treats a cell beyond a transition as ground (``TRANSITION_BAND_M``): the
stairs would otherwise narrow to nothing where they change layer. Islands are connected
across transitions. With one storey nothing here runs: ``envs.navmesh`` builds the grid.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from calnav.envs.navmesh import build_heightfield
from calnav.envs.scene import Scene

LAYER_SPLIT = 0.62            # band boundary above a storey floor, fraction of the storey height (off 0.5: the landing)
TRANSITION_BAND_M = 0.5       # cells of the next layer within this height of the boundary count as ground for the erosion
NEIGHBOURS_8 = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


@dataclass
class LayeredNavMesh:
    """navigable, ground: (L, H, W) bool; floor_z: (L, H, W) float32 metres (NaN off the
    ground); islands: (L, H, W) int32 (-1 off the navigable cells; an island may span layers);
    storey_z: (L,) float64 floor height of each storey; bounds: (L - 1,) band boundaries,
    metres; origin_xy (2,), cell_m, stats as ``envs.navmesh.NavMesh``."""

    navigable: np.ndarray
    ground: np.ndarray
    floor_z: np.ndarray
    islands: np.ndarray
    storey_z: np.ndarray
    bounds: np.ndarray
    origin_xy: np.ndarray
    cell_m: float
    stats: dict


def shifted(a: np.ndarray, dr: int, dc: int, fill) -> np.ndarray:
    """out[..., r, c] = a[..., r + dr, c + dc], ``fill`` outside the grid."""
    h, w = a.shape[-2:]
    out = np.full_like(a, fill)
    out[..., max(0, -dr):h - max(0, dr), max(0, -dc):w - max(0, dc)] = \
        a[..., max(0, dr):h + min(0, dr), max(0, dc):w + min(0, dc)]
    return out


def transitions(navigable: np.ndarray, floor_z: np.ndarray, climb_m: float) -> list[tuple[int, int, int, np.ndarray]]:
    """[(layer, other layer, offset index into NEIGHBOURS_8, (H, W) bool)]: cell (r, c) of
    ``layer`` steps onto (r + dr, c + dc) of ``other`` (a layer above or below), both
    navigable, floors within ``climb_m``. navigable (L, H, W) bool, floor_z (L, H, W)."""
    out = []
    n_layers = navigable.shape[0]
    for a in range(n_layers):
        for b in (a - 1, a + 1):
            if not 0 <= b < n_layers:
                continue
            for k, (dr, dc) in enumerate(NEIGHBOURS_8):
                nb_nav = shifted(navigable[b], dr, dc, False)
                nb_z = shifted(floor_z[b], dr, dc, np.nan)
                with np.errstate(invalid="ignore"):
                    ok = navigable[a] & nb_nav & (np.abs(nb_z - floor_z[a]) <= climb_m)
                # the step goes to the other layer only where this layer does not continue
                ok &= ~shifted(navigable[a], dr, dc, False)
                if ok.any():
                    out.append((a, b, k, ok))
    return out


def _layers(field: dict, storey_z: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, dict]:
    """(L, H, W) int64 ground span per layer and column (-1 none), surface figures."""
    h, w = field["shape"]
    start, smax, surface, ztop = field["start"], field["smax"], field["surface"], field["ztop"]
    n_layers = len(storey_z)
    ground = np.full((n_layers, h * w), -1, np.int64)
    walk = np.flatnonzero(surface >= 0)
    info = {"surfaces": 0, "ground_surfaces": 0}
    if len(walk) == 0:
        return ground.reshape(n_layers, h, w), info
    labels = surface[walk]
    sizes = np.bincount(labels)
    heights = np.array([np.median(ztop[walk[labels == k]]) for k in range(len(sizes))])
    climb_m = field["climb"] * field["ch"]
    near = np.abs(heights[:, None] - storey_z[None, :]).min(axis=1) <= climb_m
    keep_label = near.copy()
    keep_label[int(np.argmax(sizes))] = True
    info.update(surfaces=int(len(sizes)), ground_surfaces=int(keep_label.sum()))
    keep = walk[keep_label[labels]]
    layer = np.searchsorted(bounds, ztop[keep], side="right")
    cols = np.searchsorted(start, keep, side="right") - 1
    for k in range(n_layers):
        sel = layer == k
        c, s = cols[sel], keep[sel]
        first = np.unique(c, return_index=True)[1]   # spans are sorted bottom to top: the lowest
        ground[k, c[first]] = s[first]
    return ground.reshape(n_layers, h, w), info


def _edges(field: dict, span: np.ndarray) -> np.ndarray:
    """(H, W) bool cells of one layer whose ground does not link to a 4-neighbour's ground in
    the same layer (an impassable step: an obstacle edge, as ``envs.navmesh._ground``)."""
    h, w = span.shape
    con = field["con"]
    edge = np.zeros((h, w), bool)
    has = span >= 0
    for d, (dr, dc) in enumerate(((0, -1), (1, 0), (0, 1), (-1, 0))):
        nb = shifted(span, dr, dc, -1)
        linked = np.full((h, w), -1, np.int64)
        linked[has] = con[span[has], d]
        edge |= has & (nb >= 0) & (linked != nb)
    return edge


def build_layered_navmesh(scene: Scene, env_cfg) -> LayeredNavMesh:
    """The layered navigable space of a house with ``scene.meta["storey_z"]`` for the agent of
    ``env_cfg``; see the module docstring. Raises ValueError when nothing is navigable."""
    cell = float(env_cfg.nav_cell_m)
    storey_z = np.asarray(scene.meta["storey_z"], np.float64)
    storey_h = float(scene.meta["storey_height_m"])
    bounds = storey_z[:-1] + LAYER_SPLIT * storey_h
    field = build_heightfield(scene, env_cfg)
    field["ch"] = float(env_cfg.navmesh.cell_height_m)
    span, surfaces = _layers(field, storey_z, bounds)
    n_layers, h, w = span.shape
    ground = span >= 0
    floor_z = np.full(span.shape, np.nan, np.float32)
    floor_z[ground] = field["ztop"][span[ground]]
    free = np.stack([ground[k] & ~_edges(field, span[k]) for k in range(n_layers)])
    radius = env_cfg.agent_radius_m + cell / 2
    eroded = np.zeros_like(free)
    for k in range(n_layers):
        beyond = np.zeros((h, w), bool)   # the next / previous layer's stairs, near the boundary
        for j, b in ((k - 1, k - 1), (k + 1, k)):
            if 0 <= j < n_layers:
                with np.errstate(invalid="ignore"):
                    beyond |= free[j] & (np.abs(floor_z[j] - bounds[b]) <= TRANSITION_BAND_M)
        open_k = free[k] | (beyond & ~ground[k])
        clearance = ndimage.distance_transform_edt(np.pad(open_k, 1))[1:-1, 1:-1] * cell
        eroded[k] = free[k] & (clearance > radius)
    climb_m = float(env_cfg.navmesh.agent_max_climb_m)
    islands = _islands(eroded, floor_z, climb_m, int(env_cfg.navmesh.region_min_size) ** 2)
    navigable = islands >= 0
    if not navigable.any():
        raise ValueError(f"scene {scene.name!r} has no navigable area for an agent of radius "
                         f"{env_cfg.agent_radius_m} m on any of its {n_layers} storeys")
    area = cell * cell
    ids = islands[navigable]
    stats = {"ground_m2": float(free.sum() * area), "navigable_m2": float(navigable.sum() * area),
             "islands": int(ids.max()) + 1, "island_m2": [float(x * area) for x in np.bincount(ids)],
             "storeys": n_layers, "storey_navigable_m2": [float(navigable[k].sum() * area) for k in range(n_layers)],
             **surfaces}
    return LayeredNavMesh(navigable=navigable, ground=free, floor_z=floor_z, islands=islands, storey_z=storey_z,
                          bounds=bounds, origin_xy=field["origin"][:2].copy(), cell_m=cell, stats=stats)


def _islands(eroded: np.ndarray, floor_z: np.ndarray, climb_m: float, min_cells: int) -> np.ndarray:
    """(L, H, W) int32 island ids (0 = the largest, -1 dropped / off the eroded ground): each
    layer's 8-connected pieces, joined across stair transitions, pieces under ``min_cells``
    cells in all dropped."""
    n_layers = eroded.shape[0]
    labels = np.zeros(eroded.shape, np.int64)
    offset = 0
    for k in range(n_layers):
        lab, n = ndimage.label(eroded[k], structure=np.ones((3, 3), bool))
        labels[k] = np.where(lab > 0, lab + offset, 0)
        offset += n
    rows, cols = [], []
    for a, b, k, ok in transitions(eroded, floor_z, climb_m):
        dr, dc = NEIGHBOURS_8[k]
        rows.append(labels[a][ok])
        cols.append(shifted(labels[b], dr, dc, 0)[ok])
    r = np.concatenate(rows + [np.zeros(0, np.int64)])
    c = np.concatenate(cols + [np.zeros(0, np.int64)])
    graph = coo_matrix((np.ones(len(r)), (r, c)), shape=(offset + 1, offset + 1))
    _, comp = connected_components(graph, directed=False)
    piece = np.where(labels > 0, comp[labels], -1)
    sizes = np.bincount(piece[piece >= 0])
    kept = np.flatnonzero(sizes >= max(min_cells, 1))
    kept = kept[np.argsort(-sizes[kept], kind="stable")]
    lut = np.full(len(sizes) + 1, -1, np.int32)
    lut[kept] = np.arange(len(kept), dtype=np.int32)
    return np.where(piece >= 0, lut[np.maximum(piece, 0)], -1).astype(np.int32)
