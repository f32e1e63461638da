"""How scan-like a scanned house is, in the figures one reads off a real labelled scan.

``scan_quality(clean, scanned)`` -> dict:

- ``triangles``, ``triangles_per_m2``: triangle count and count per m^2 of the xy footprint
  (a ScanNet ``_vh_clean_2`` apartment: 153k triangles over 8 x 9 m, ~2,100 per m^2);
- ``floor_missing``, ``wall_missing``, ``ceiling_missing``: fraction of the *observable* clean
  floor / wall / ceiling area with no scanned surface within ``COVER_DISTANCE_M``. Observable: a
  surface sample with at least ``OBSERVABLE_CLEARANCE_M`` of free space in front of it along its
  normal, and something (another wall, the ceiling, the floor) at the end of it: this excludes
  faces buried inside other walls, floor under furniture, wall behind a cabinet, and the outside
  of the house;
- ``void_fraction``, ``void_area_fraction``: unlabelled triangles / surface area;
- ``median_error_mm``, ``p90_error_mm``: distance from scanned surface samples to the clean mesh.

``floor_quality(scene, env_cfg)`` -> dict: what a navmesh makes of the scan's floor
(``envs.scene_check.navmesh_figures``: walkable ground, navigable area, islands, the floor's
height above the reference) and ``label_rule_fraction``, the share of that ground a
label-based rule would call floor (a ray's first hit a ``floor`` triangle within
``LABEL_RULE_TOL_M`` of the reference height): on a real scan about half.
"""
from __future__ import annotations

import numpy as np
import open3d.core as o3c

from calnav.envs.render import build_raycasting_scene
from calnav.envs.scanning.scanner import footprint_m2
from calnav.envs.scene import Scene, sample_surface
from calnav.envs.semantics import CLASS_ID, VOID

COVER_DISTANCE_M = 0.05         # a clean surface point is covered by a scan surface this close, metres
OBSERVABLE_CLEARANCE_M = 0.3    # free space needed in front of a clean surface point to count it, metres
SAMPLE_SPACING_M = 0.05         # surface sample spacing of the figures, metres
SAMPLE_SEED = 0                 # surface samples are random but fixed: the figures are deterministic
LABEL_RULE_TOL_M = 0.03        # the label rule's tolerance around the reference floor height, metres
QUALITY_KEYS = ("triangles", "triangles_per_m2", "floor_missing", "wall_missing", "ceiling_missing", "void_fraction",
                "void_area_fraction", "median_error_mm", "p90_error_mm")


def _tri_normals(tris: np.ndarray) -> np.ndarray:
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def _observable_samples(clean: Scene, rc_clean, class_name: str, rng) -> np.ndarray:
    """(n, 3) samples of the clean ``class_name`` surface that a scanner could have seen."""
    sel = clean.tri_class == CLASS_ID[class_name]
    if not sel.any():
        return np.zeros((0, 3))
    tris = clean.vertices[clean.triangles[sel]].astype(np.float64)
    normals = _tri_normals(tris)
    if class_name == "wall":   # wall tops and bottoms are never seen
        keep = np.abs(normals[:, 2]) < 0.5
        tris, normals = tris[keep], normals[keep]
    if len(tris) == 0:
        return np.zeros((0, 3))
    pts, idx = sample_surface(tris, SAMPLE_SPACING_M, rng, return_index=True)
    n = normals[idx]
    if class_name == "wall":
        top = clean.floor_z + float(clean.meta.get("wall_height_m", np.inf))
        inside = (pts[:, 2] > clean.floor_z + 0.02) & (pts[:, 2] < top - 0.02)
        pts, n = pts[inside], n[inside]
    rays = np.concatenate([pts + 0.01 * n, n], axis=1).astype(np.float32)
    t = rc_clean.cast_rays(o3c.Tensor(rays))["t_hit"].numpy()
    return pts[(t > OBSERVABLE_CLEARANCE_M) & np.isfinite(t)]   # inf: faces the outside of the house


def scan_quality(clean: Scene, scanned: Scene) -> dict[str, float]:
    """The figures of the module docstring for ``scanned``, a scan of ``clean``."""
    rng = np.random.default_rng(SAMPLE_SEED)
    rc_clean, rc_scan = build_raycasting_scene(clean), build_raycasting_scene(scanned)
    footprint = footprint_m2(clean)
    out: dict[str, float] = {"triangles": float(len(scanned.triangles)),
                             "triangles_per_m2": len(scanned.triangles) / footprint}
    for name in ("floor", "wall", "ceiling"):
        pts = _observable_samples(clean, rc_clean, name, rng)
        if len(pts) == 0:
            out[f"{name}_missing"] = float("nan")
            continue
        d = rc_scan.compute_distance(o3c.Tensor(pts.astype(np.float32))).numpy()
        out[f"{name}_missing"] = float(np.mean(d > COVER_DISTANCE_M))
    tris = scanned.vertices[scanned.triangles].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    void = scanned.tri_class == VOID
    out["void_fraction"] = float(void.mean())
    out["void_area_fraction"] = float(area[void].sum() / max(area.sum(), 1e-12))
    samples = sample_surface(tris, SAMPLE_SPACING_M, rng)
    err = rc_clean.compute_distance(o3c.Tensor(samples.astype(np.float32))).numpy()
    out["median_error_mm"] = float(np.median(err) * 1000.0)
    out["p90_error_mm"] = float(np.percentile(err, 90) * 1000.0)
    return out


def label_rule_floor(scene: Scene, ground: np.ndarray, origin_xy: np.ndarray, cell_m: float,
                     ray_start_m: float) -> np.ndarray:
    """(H, W) bool: ground cells whose centre's down ray (from ``ray_start_m`` above the
    reference floor) first hits a ``floor``-labelled triangle within LABEL_RULE_TOL_M of it."""
    rows, cols = np.nonzero(ground)
    xy = origin_xy + (np.stack([cols, rows], axis=1) + 0.5) * cell_m
    z0 = scene.floor_z + ray_start_m
    rays = np.zeros((len(xy), 6), np.float32)
    rays[:, :2], rays[:, 2], rays[:, 5] = xy, z0, -1.0
    hit = build_raycasting_scene(scene).cast_rays(o3c.Tensor(rays))
    t = hit["t_hit"].numpy()
    prim = np.minimum(hit["primitive_ids"].numpy(), len(scene.triangles)).astype(np.int64)
    cls = np.append(scene.tri_class, np.int16(VOID))[prim]
    ok = (cls == CLASS_ID["floor"]) & (np.abs(z0 - t - scene.floor_z) < LABEL_RULE_TOL_M)
    out = np.zeros(ground.shape, bool)
    out[rows[ok], cols[ok]] = True
    return out


def floor_quality(scene: Scene, env_cfg) -> dict[str, float]:
    """The navmesh's figures of ``scene`` and the label rule's share of its ground (module docstring)."""
    from calnav.envs.navmesh import build_navmesh
    from calnav.envs.scene_check import navmesh_figures

    mesh = build_navmesh(scene, env_cfg, require_navigable=False)   # a failed scan is a figure too
    fig = navmesh_figures(mesh, scene.floor_z)
    label = label_rule_floor(scene, mesh.ground, mesh.origin_xy, mesh.cell_m, env_cfg.agent_height_m)
    return {"ground_m2": fig["ground_m2"], "navigable_m2": fig["navigable_m2"],
            "navigable_fraction": fig["navigable_fraction"], "islands": float(fig["islands"]),
            "label_rule_fraction": float(label.sum() / max(mesh.ground.sum(), 1)),
            "floor_above_median_m": fig["floor_above_median_m"], "floor_above_p95_m": fig["floor_above_p95_m"]}
