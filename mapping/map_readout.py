"""Read-outs of a ``SemanticVoxelMap``: surface voxels with their fused probabilities, point
queries, TSDF-gradient normals, a semantic point cloud and semantic images rendered from any
camera.

The seam: these functions use only the map's storage interface (``VoxelStorage``), never its
fusion internals; the map's read-out methods (``SemanticVoxelMap.voxels`` ...) call them."""
from __future__ import annotations

import weakref
from typing import Any, NamedTuple, Protocol

import numpy as np
import open3d as o3d
import open3d.core as o3c
import torch

from calnav.mapping import frame_geometry as fg
from calnav.mapping.config import MappingConfig

TRILINEAR_CORNERS = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], np.int32)


class PointCloud(NamedTuple):
    """Surface points with semantics: points (P, 3) float32 m, colors (P, 3) uint8,
    normals (P, 3) float32 unit, probs (P, K) float32."""

    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    probs: np.ndarray


class VoxelStorage(Protocol):
    """The seam: what a read-out may use of a map (``SemanticVoxelMap`` provides it). flat: a
    voxel's row in the attribute buffers."""

    cfg: MappingConfig
    vbg: Any                        # open3d.t.geometry.VoxelBlockGrid
    num_classes: int
    has_geometry: bool              # False: semantics fused without the TSDF (no surface to read)
    frames_integrated: int

    @property
    def o3d_weight_threshold(self) -> float: ...

    def attribute(self, name: str) -> np.ndarray:
        """(rows, C) float32 view of a grid attribute (tsdf, weight, color, semantic)."""

    def observation_counts(self, flat: np.ndarray) -> np.ndarray:
        """(n,) float32 semantic observations of voxels ``flat``."""

    def fused_probs(self, flat: np.ndarray) -> np.ndarray:
        """(n, K) float32 fused probabilities of voxels ``flat``."""

    def flat_indices(self, keys: np.ndarray) -> np.ndarray:
        """(n,) int64 rows of integer voxel keys (n, 3), -1 where not allocated."""


# map -> (frames_integrated, RaycastingScene of its iso-surface or None): rebuilt after integrate
_SURFACE_SCENES: "weakref.WeakKeyDictionary[VoxelStorage, tuple]" = weakref.WeakKeyDictionary()

def require_geometry(vmap: VoxelStorage) -> None:
    """ValueError unless the map kept its TSDF (a semantics-only map has no surface: its
    read-outs would be empty, not an error)."""
    if not vmap.has_geometry:
        raise ValueError("this voxel map fused semantics without the TSDF (tsdf=False): it has no surface to read; "
                         "build it with tsdf=True, or read observed_voxels()")

def observed(vmap: VoxelStorage) -> tuple[np.ndarray, np.ndarray]:
    """(coords (N, 3) float32 m, flat (N,) int64) of every voxel with a semantic observation
    (each contains a depth point back-projected from a frame that saw it, so they lie on the
    measured surface; no TSDF read)."""
    active = vmap.vbg.hashmap().active_buf_indices()
    if active.shape[0] == 0:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.int64)
    coords, flat = vmap.vbg.voxel_coordinates_and_flattened_indices(active)
    coords, flat = coords.numpy(), flat.numpy().ravel()
    keep = np.flatnonzero(vmap.observation_counts(flat) > 0)
    return coords[keep], flat[keep]

def observed_voxels(vmap: VoxelStorage) -> tuple[np.ndarray, np.ndarray]:
    """``voxels`` without the TSDF band: every voxel with a semantic observation, coords (N, 3)
    float32 m and probs (N, K) float32 (what a semantics-only map, ``tsdf=False``, can show)."""
    coords, flat = observed(vmap)
    return coords, vmap.fused_probs(flat) if len(flat) else np.zeros((0, vmap.num_classes), np.float32)

def surface(vmap: VoxelStorage) -> tuple[np.ndarray, np.ndarray]:
    """(coords (N, 3) float32 m, flat (N,) int64) of surface voxels with semantics."""
    require_geometry(vmap)
    cfg = vmap.cfg
    coords, flat = observed(vmap)
    if len(flat) == 0:
        return coords, flat
    tsdf, wgt = vmap.attribute("tsdf")[flat, 0], vmap.attribute("weight")[flat, 0]
    band = cfg.surface_band_voxels / cfg.trunc_voxels
    keep = np.flatnonzero((np.abs(tsdf) < band) & (wgt >= cfg.min_tsdf_weight))
    return coords[keep], flat[keep]

def voxels(vmap: VoxelStorage) -> tuple[np.ndarray, np.ndarray]:
    """Surface voxels with semantic observations: coords (N, 3) float32 world metres (voxel
    centres), probs (N, K) float32 fused probabilities."""
    coords, flat = surface(vmap)
    return coords, vmap.fused_probs(flat) if len(flat) else np.zeros((0, vmap.num_classes), np.float32)

def query(vmap: VoxelStorage, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fused probs (n, K) of the voxels nearest to ``points`` (n, 3) world metres, and a bool
    (n,) mask of those that have semantic observations (others read uniform)."""
    keys = np.rint(np.asarray(points, dtype=np.float64).reshape(-1, 3) / vmap.cfg.voxel_size_m)
    return query_keys(vmap, keys.astype(np.int32))

def query_keys(vmap: VoxelStorage, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``query`` by integer voxel keys (n, 3) (a voxel's centre is key * voxel size)."""
    flat = vmap.flat_indices(keys)
    observed = flat >= 0
    observed[observed] = vmap.observation_counts(flat[observed]) > 0
    probs = np.full((len(flat), vmap.num_classes), 1.0 / vmap.num_classes, np.float32)
    if observed.any():
        probs[observed] = vmap.fused_probs(flat[observed])
    return probs, observed

def voxel_normals(vmap: VoxelStorage, coords: np.ndarray) -> np.ndarray:
    """(N, 3) float32 unit surface normals at voxel centres ``coords`` (N, 3) m from the TSDF
    gradient (central differences, one-sided where a neighbour is unallocated; 0 if none)."""
    require_geometry(vmap)
    keys = np.rint(np.asarray(coords, dtype=np.float64).reshape(-1, 3) / vmap.cfg.voxel_size_m).astype(np.int32)
    tsdf, wgt = vmap.attribute("tsdf")[:, 0], vmap.attribute("weight")[:, 0]

    def sample(kk):
        f = vmap.flat_indices(kk)
        ok = f >= 0
        ok[ok] = wgt[f[ok]] > 0
        return np.where(ok, tsdf[np.where(ok, f, 0)], 0.0), ok

    c, c_ok = sample(keys)
    grad = np.zeros((len(keys), 3), np.float32)
    for axis in range(3):
        e = np.zeros(3, np.int32)
        e[axis] = 1
        (p, p_ok), (m, m_ok) = sample(keys + e), sample(keys - e)
        hi, lo = np.where(p_ok, p, c), np.where(m_ok, m, c)
        span = p_ok.astype(np.float32) + m_ok
        grad[:, axis] = np.where(span > 0, (hi - lo) / np.maximum(span, 1), 0.0)
    grad[~c_ok] = 0.0
    norm = np.linalg.norm(grad, axis=1, keepdims=True)
    return np.where(norm > 0, grad / np.maximum(norm, np.finfo(np.float32).tiny), 0.0).astype(np.float32)

def point_cloud(vmap: VoxelStorage) -> PointCloud:
    """Iso-surface points (``extract_point_cloud``) that have semantics, with colour, normal
    and the fused probs of the voxel nearest each point."""
    require_geometry(vmap)
    pcd = vmap.vbg.extract_point_cloud(vmap.o3d_weight_threshold) if vmap.vbg.hashmap().size() else None
    if pcd is None or pcd.is_empty():
        z = np.zeros((0, 3), np.float32)
        return PointCloud(z, np.zeros((0, 3), np.uint8), z, np.zeros((0, vmap.num_classes), np.float32))
    pts = pcd.point.positions.numpy()
    probs, observed = query(vmap, pts)
    colors = np.clip(pcd.point.colors.numpy() * 255.0 + 0.5, 0, 255).astype(np.uint8) if "colors" in pcd.point \
        else np.zeros((len(pts), 3), np.uint8)
    normals = pcd.point.normals.numpy() if "normals" in pcd.point else np.zeros_like(pts)
    return PointCloud(pts[observed], colors[observed], normals[observed], probs[observed])

def _surface_scene(vmap: VoxelStorage):
    """Open3D RaycastingScene of the TSDF iso-surface mesh, cached until the next integrate."""
    require_geometry(vmap)
    cached = _SURFACE_SCENES.get(vmap)
    if cached is None or cached[0] != vmap.frames_integrated:
        scene = None
        mesh = vmap.vbg.extract_triangle_mesh(vmap.o3d_weight_threshold) if vmap.vbg.hashmap().size() else None
        if mesh is not None and mesh.triangle.indices.shape[0] > 0:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(mesh.vertex.positions, mesh.triangle.indices.to(o3c.uint32))
        cached = _SURFACE_SCENES[vmap] = (vmap.frames_integrated, scene)
    return cached[1]

def render_semantics(vmap: VoxelStorage, intrinsics: np.ndarray, pose: np.ndarray, width: int,
                     height: int) -> tuple[np.ndarray, np.ndarray]:
    """Semantics seen by a camera: probs (H, W, K) float32 and valid (H, W) bool (the ray hit a
    surface with semantics within [depth_min, depth_max]).

    Rays are cast against the TSDF iso-surface mesh (marching cubes, cached per map state);
    each hit blends the fused probs of the observed voxels among the 8 around the hit point
    with trilinear weights. (``VoxelBlockGrid.ray_cast`` is not used: its first call after
    the map grows under-sizes a range buffer and silently misses most rays.)
    """
    cfg, kk = vmap.cfg, vmap.num_classes
    k, pose = fg.check_intrinsics(intrinsics, width, height), fg.check_pose(pose)
    probs = np.zeros((height * width, kk), np.float32)
    valid = np.zeros(height * width, bool)
    scene = _surface_scene(vmap)
    if scene is not None:
        rays = scene.create_rays_pinhole(o3c.Tensor(fg.o3d_ray_intrinsics(k)), o3c.Tensor(fg.invert_rigid(pose)),
                                         width, height)
        t_hit = scene.cast_rays(rays)["t_hit"].numpy().ravel()  # z-depth: the rays are not normalised
        hit = np.flatnonzero(np.isfinite(t_hit) & (t_hit >= cfg.depth_min_m) & (t_hit <= cfg.depth_max_m))
        r = rays.numpy().reshape(-1, 6)[hit]
        q = (r[:, :3] + t_hit[hit, None] * r[:, 3:]) / cfg.voxel_size_m
        base = np.floor(q)
        frac = (q - base).astype(np.float32)
        corners = TRILINEAR_CORNERS
        flat = vmap.flat_indices((base.astype(np.int32)[:, None, :] + corners).reshape(-1, 3)).reshape(-1, 8)
        wts = np.prod(np.where(corners.astype(bool), frac[:, None, :], 1.0 - frac[:, None, :]), axis=2)
        ok = flat >= 0
        ok[ok] = vmap.observation_counts(flat[ok]) > 0
        wts = np.where(ok, wts, 0.0).astype(np.float32)
        total = wts.sum(1)
        row, corner = np.nonzero(ok)
        uniq, inv = np.unique(flat[row, corner], return_inverse=True)
        if len(uniq):
            blend = np.zeros((len(hit), kk), np.float32)
            contrib = torch.from_numpy(vmap.fused_probs(uniq))[torch.from_numpy(inv.ravel())]
            contrib *= torch.from_numpy(wts[row, corner])[:, None]
            torch.from_numpy(blend).index_add_(0, torch.from_numpy(row), contrib)
            good = total > 0
            probs[hit[good]] = blend[good] / total[good, None]
            valid[hit[good]] = True
    return probs.reshape(height, width, kk), valid.reshape(height, width)
