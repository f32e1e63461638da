"""The storeys of a scanned scene, found from its geometry (HM3D and MP3D houses have stairs).

calnav's own houses know their storeys (``meta["storey_z"]``, ``envs.house``); a scan does not.
Its storeys are the heights at which it holds large walkable floors under a ceiling:

    walkable  = upward faces within the navmesh's slope (``envs.navmesh.triangle_walkable``:
                the file's winding, as Recast judges it)
    floors    = the walkable area per ``BIN_M`` of height; a storey is a height holding at
                least ``MIN_STOREY_AREA_M2`` and ``MIN_SHARE`` of the largest floor, at least
                ``MIN_STOREY_GAP_M`` above or below every larger one (a sunken living room, a
                bed, a stage are one storey with the floor beside them)
    ceiling   = at least ``MIN_COVERED`` of the floor's area has geometry within
                ``CEILING_REACH_M`` above it (a roof or a terrace has none: not a storey)

The result feeds ``envs.navmesh_layers`` through ``meta["storey_z"]`` and
``meta["storey_height_m"]`` (the smallest gap between storeys); one storey leaves the scene as it
was (``envs.navmesh`` builds its grid).
"""
from __future__ import annotations

import numpy as np

from calnav.envs.scene import Scene

BIN_M = 0.1                 # height bins of the floor histogram, metres
MIN_STOREY_AREA_M2 = 8.0    # a storey holds at least this much walkable floor (a landing does not), m^2
MIN_SHARE = 0.15            # ... and this share of the largest floor
MIN_STOREY_GAP_M = 2.0      # storeys lie at least this far apart (a person stands under the one above), metres
CEILING_REACH_M = 4.0       # a storey's ceiling lies within this above its floor, metres
MIN_COVERED = 0.5           # share of a storey's floor with a ceiling above it
CEILING_SAMPLES = 400       # points per candidate floor tested for a ceiling (area-weighted draw)


def detect_storeys(scene: Scene, max_slope_deg: float = 45.0, seed: int = 0) -> list[float]:
    """The floor heights (metres, ascending) of the scene's storeys (module docstring); one
    height for a single storey, [] for a scene without walkable faces."""
    from calnav.envs.navmesh import triangle_walkable

    walk = triangle_walkable(scene, max_slope_deg)
    tris = scene.vertices[scene.triangles[walk]].astype(np.float64)
    if len(tris) == 0:
        return []
    area = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1) / 2
    z = tris[:, :, 2].mean(axis=1)
    bins = np.floor((z - z.min()) / BIN_M).astype(np.int64)
    per_bin = np.bincount(bins, weights=area)
    # a floor spans two bins when it lies on a boundary: its area is that of the bin and its neighbours
    smooth = per_bin + np.concatenate([[0], per_bin[:-1]]) + np.concatenate([per_bin[1:], [0]])
    largest = float(smooth.max())
    chosen: list[tuple[float, float]] = []   # (height, area) of accepted floors, largest first
    for b in np.argsort(-smooth, kind="stable"):
        a = float(smooth[b])
        if a < max(MIN_STOREY_AREA_M2, MIN_SHARE * largest):
            break
        near = np.abs(bins - b) <= 1
        height = float(np.average(z[near], weights=area[near]))
        if all(abs(height - h) >= MIN_STOREY_GAP_M for h, _ in chosen):
            chosen.append((height, a))
    if not chosen:   # no floor as large as a storey (a closet, a scan fragment): one storey, its largest floor
        near = np.abs(bins - int(np.argmax(smooth))) <= 1
        return [float(np.average(z[near], weights=area[near]))]
    rng = np.random.default_rng(seed)
    storeys = [h for h, _ in chosen if len(chosen) == 1 or _covered(scene, tris, area, z, h, rng) >= MIN_COVERED]
    return sorted(storeys) or [chosen[0][0]]


def _covered(scene: Scene, tris: np.ndarray, area: np.ndarray, z: np.ndarray, height: float,
             rng: np.random.Generator) -> float:
    """Share of the floor at ``height`` (its faces within a bin) with geometry above it within
    ``CEILING_REACH_M``: rays cast straight up from area-weighted points on it."""
    import open3d as o3d

    on = np.flatnonzero(np.abs(z - height) <= BIN_M)
    pick = rng.choice(on, size=min(CEILING_SAMPLES, len(on)), p=area[on] / area[on].sum())
    w = rng.dirichlet(np.ones(3), size=len(pick))
    points = np.einsum("nk,nkd->nd", w, tris[pick]) + [0.0, 0.0, 0.02]   # just above the floor
    rays = np.hstack([points, np.tile([0.0, 0.0, 1.0], (len(points), 1))]).astype(np.float32)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                     o3d.core.Tensor(scene.triangles.astype(np.uint32)))
    hit = rc.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return float(np.mean(hit <= CEILING_REACH_M))


def storey_meta(scene: Scene, max_slope_deg: float = 45.0) -> dict:
    """``{"storey_z": [...], "storey_height_m": gap}`` when the scene has more than one storey
    (``detect_storeys``), else {}."""
    storeys = detect_storeys(scene, max_slope_deg)
    if len(storeys) < 2:
        return {}
    return {"storey_z": [round(h, 4) for h in storeys], "storey_height_m": round(float(np.diff(storeys).min()), 4)}
