"""Floor artifacts of a real reconstruction, applied to a scanned mesh after labelling
(``envs.scanning.scanner``). Each is what a ScanNet / HM3D mesh shows and the clean house
does not:

- holes: floor-level surface missing where the scanner never looked, in front of and beside
  furniture (``hole_near_furniture``) and elsewhere; ``holes_per_m2`` of room floor, ellipses
  with semi-axes in ``hole_radius_m``;
- unlabelled floor: patches of floor triangles left void (annotators skip them), until
  ``unlabelled_floor_fraction`` of the floor area is void;
- warp: the whole mesh bent by a smooth, low-frequency height field of 0 to ``floor_warp_m``
  (per house a fraction of it), wavelengths in ``floor_warp_wavelength_m`` (tracking drift: a
  real scan's floor is centimetres off one plane).

Pure functions of their inputs and the generator; the mesh arrays follow ``envs.scanning.reconstruct``.
"""
from __future__ import annotations

import numpy as np

from calnav.envs.scanning.config import ScanningConfig
from calnav.envs.scanning.lived_in import _furniture_rects
from calnav.envs.scene import Scene
from calnav.envs.semantics import CLASS_ID, VOID

FLOOR_LEVEL_M = 0.06          # up-facing triangles below floor_z + this are floor-level (rugs too), metres
UP_NORMAL_Z = 0.8             # |normal z| above this is up-facing
WARP_WAVES = 3                # plane waves summed into the warp field
WARP_GRID_M = 0.1             # the warp is normalised to [0, 1] on a grid of this spacing, metres
PATCH_RADIUS_M = (0.4, 1.2)   # radii of the unlabelled floor patches, metres
MAX_PATCHES = 500             # a bound on the patch loop (a floor smaller than the target patch)


def _normals_z(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    tri = vertices[triangles]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n[:, 2] / np.maximum(np.linalg.norm(n, axis=1), 1e-12)


def _areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    tri = vertices[triangles]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def hole_centres(scene: Scene, cfg: ScanningConfig, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) world xy of the holes' centres: beside a floor-standing object (the edge of its
    box pushed out by 5-45 cm) with probability ``hole_near_furniture``, else anywhere on a
    room's floor."""
    rooms = scene.rooms
    floor_m2 = sum(r.area for r in rooms)
    rects = _furniture_rects(scene)
    out = []
    for _ in range(int(rng.poisson(cfg.holes_per_m2 * floor_m2))):
        if len(rects) and rng.random() < cfg.hole_near_furniture:
            x0, y0, x1, y1 = rects[rng.integers(len(rects))] + rng.uniform(0.05, 0.45) * np.array([-1, -1, 1, 1])
            side, t = rng.integers(4), rng.random()   # a point on the pushed-out box's edge
            out.append(((x0 + t * (x1 - x0), (y0, y1)[side]) if side < 2
                        else ((x0, x1)[side - 2], y0 + t * (y1 - y0))))
        elif rooms:
            room = rooms[rng.integers(len(rooms))]
            out.append((rng.uniform(room.xmin, room.xmax), rng.uniform(room.ymin, room.ymax)))
    return np.array(out, np.float64).reshape(-1, 2)


def cut_holes(vertices: np.ndarray, triangles: np.ndarray, floor_z: float, centres: np.ndarray,
              cfg: ScanningConfig, rng: np.random.Generator) -> np.ndarray:
    """(F,) bool: triangles to keep -- floor-level, up-facing triangles whose centroid lies in an
    elliptic hole around one of ``centres`` are dropped."""
    keep = np.ones(len(triangles), bool)
    if len(centres) == 0:
        return keep
    cen = vertices[triangles].mean(axis=1)
    floor_level = (np.abs(_normals_z(vertices, triangles)) > UP_NORMAL_Z) & (cen[:, 2] < floor_z + FLOOR_LEVEL_M)
    for c in centres:
        a, b = rng.uniform(*cfg.hole_radius_m, 2)
        th = rng.uniform(0, np.pi)
        d = cen[:, :2] - c
        u = d[:, 0] * np.cos(th) + d[:, 1] * np.sin(th)
        v = -d[:, 0] * np.sin(th) + d[:, 1] * np.cos(th)
        keep &= ~(floor_level & ((u / a) ** 2 + (v / b) ** 2 <= 1.0))
    return keep


def unlabel_floor(vertices: np.ndarray, triangles: np.ndarray, tri_class: np.ndarray, tri_instance: np.ndarray,
                  cfg: ScanningConfig, rng: np.random.Generator) -> float:
    """Void round patches of floor triangles (in place) until ``unlabelled_floor_fraction`` of
    the floor area is void; returns the void fraction reached."""
    floor = tri_class == CLASS_ID["floor"]
    area = _areas(vertices, triangles)
    total = area[floor].sum()
    if total <= 0 or cfg.unlabelled_floor_fraction <= 0:
        return 0.0
    cen = vertices[triangles].mean(axis=1)[:, :2]
    voided = np.zeros(len(triangles), bool)
    for _ in range(MAX_PATCHES):
        if area[voided].sum() >= cfg.unlabelled_floor_fraction * total:
            break
        candidates = np.flatnonzero(floor & ~voided)
        if len(candidates) == 0:
            break
        c = cen[candidates[rng.integers(len(candidates))]]
        voided |= floor & (np.hypot(*(cen - c).T) <= rng.uniform(*PATCH_RADIUS_M))
    tri_class[voided] = VOID
    tri_instance[voided] = -1
    return float(area[voided].sum() / total)


def warp_field(lo: np.ndarray, hi: np.ndarray, amplitude_m: float, cfg: ScanningConfig,
               rng: np.random.Generator):
    """A smooth height field over the xy box [lo, hi]: ``f(xy (N, 2)) -> (N,)`` metres, spanning
    [0, amplitude_m] over the box (a sum of WARP_WAVES plane waves)."""
    k = 2 * np.pi / rng.uniform(*cfg.floor_warp_wavelength_m, WARP_WAVES)
    ang = rng.uniform(0, 2 * np.pi, WARP_WAVES)
    phase = rng.uniform(0, 2 * np.pi, WARP_WAVES)
    dirs = np.stack([np.cos(ang), np.sin(ang)], axis=1) * k[:, None]

    def raw(xy):
        return np.cos(xy @ dirs.T + phase).sum(axis=1)

    gx, gy = (np.arange(lo[i], hi[i] + WARP_GRID_M, WARP_GRID_M) for i in range(2))
    grid = raw(np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2))
    f0, f1 = grid.min(), grid.max()
    return lambda xy: amplitude_m * np.clip((raw(xy) - f0) / max(f1 - f0, 1e-12), 0.0, 1.0)


def apply_floor_artifacts(scene: Scene, vertices: np.ndarray, triangles: np.ndarray, tri_class: np.ndarray,
                          tri_instance: np.ndarray, cfg: ScanningConfig, rng: np.random.Generator):
    """Holes, unlabelled floor and the warp on a labelled scan of ``scene`` (the lived-in house:
    its rooms and objects place the holes). Returns (vertices, triangles, tri_class,
    tri_instance, counts dict)."""
    keep = cut_holes(vertices, triangles, scene.floor_z, hole_centres(scene, cfg, rng), cfg, rng)
    removed_m2 = float(_areas(vertices, triangles)[~keep].sum())
    triangles, tri_class, tri_instance = triangles[keep], tri_class[keep].copy(), tri_instance[keep].copy()
    void_fraction = unlabel_floor(vertices, triangles, tri_class, tri_instance, cfg, rng)
    amplitude = float(rng.uniform(0.75, 1.0) * cfg.floor_warp_m)
    vertices = vertices.copy()
    if amplitude > 0:
        lo, hi = vertices[:, :2].min(axis=0), vertices[:, :2].max(axis=0)
        vertices[:, 2] += warp_field(lo, hi, amplitude, cfg, rng)(vertices[:, :2])
    counts = {"holes_m2": removed_m2, "unlabelled_floor_fraction": void_fraction, "warp_m": amplitude}
    return vertices, triangles, tri_class, tri_instance, counts
