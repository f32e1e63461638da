"""Ground truth from a labelled triangle mesh, for evaluating maps (raw arrays: ``mapping``
does not import ``envs``).

- ``voxel_labels``: class of each voxel centre = class of the nearest surface triangle, or void
  (-1) when the nearest surface is farther than ``max_dist_m`` (free space / unlabelled).
- ``LabelledMesh.render``: ground-truth z-depth and class image of a pinhole camera (a light
  stand-in for the simulator's renderer in tests and benchmarks).
"""
from __future__ import annotations

import numpy as np

VOID = -1
QUERY_CHUNK = 1 << 20  # points per compute_closest_points call (bounds peak memory)


class LabelledMesh:
    """A triangle mesh with a class per triangle, wrapped in an Open3D ``RaycastingScene``.

    vertices: (V, 3) metres. triangles: (F, 3) vertex indices. tri_class: (F,) class id per
    triangle (-1 = void).
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, tri_class: np.ndarray):
        import open3d as o3d
        import open3d.core as o3c

        vertices = np.asarray(vertices, dtype=np.float32)
        triangles = np.asarray(triangles)
        self.tri_class = np.asarray(tri_class).astype(np.int64).reshape(-1)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or triangles.ndim != 2 or triangles.shape[1] != 3:
            raise ValueError(f"need vertices (V, 3) and triangles (F, 3), got {vertices.shape} and {triangles.shape}")
        if len(self.tri_class) != len(triangles):
            raise ValueError(f"tri_class has {len(self.tri_class)} entries for {len(triangles)} triangles")
        if len(triangles) == 0:
            raise ValueError("the mesh has no triangles")
        self._o3c = o3c
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3c.Tensor(vertices), o3c.Tensor(triangles.astype(np.uint32)))

    def voxel_labels(self, coords: np.ndarray, max_dist_m: float) -> np.ndarray:
        """(N,) int64 class of the nearest triangle to each point of ``coords`` (N, 3) metres,
        -1 where it is farther than ``max_dist_m``."""
        coords = np.asarray(coords, dtype=np.float32).reshape(-1, 3)
        labels = np.full(len(coords), VOID, dtype=np.int64)
        for start in range(0, len(coords), QUERY_CHUNK):
            q = np.ascontiguousarray(coords[start:start + QUERY_CHUNK])
            ans = self.scene.compute_closest_points(self._o3c.Tensor(q))
            prim = ans["primitive_ids"].numpy().astype(np.int64)
            near = np.linalg.norm(ans["points"].numpy() - q, axis=1) <= max_dist_m
            labels[start:start + QUERY_CHUNK][near] = self.tri_class[prim[near]]
        return labels

    def render(self, intrinsics: np.ndarray, pose: np.ndarray, width: int, height: int,
               depth_max_m: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth seen by a camera: depth (H, W) float32 z-depth metres (0 = no hit or
        beyond depth_max_m) and labels (H, W) int64 (-1 = void / no hit).

        intrinsics: (3, 3) pinhole, OpenCV pixel-centre convention (pixel (u, v) is centred at
        image coordinate (u, v), as ``envs.render``); pose: (4, 4) world-from-camera, OpenCV axes.
        """
        from calnav.mapping.frame_geometry import o3d_ray_intrinsics

        o3c = self._o3c
        extrinsic = np.linalg.inv(np.asarray(pose, dtype=np.float64))
        rays = self.scene.create_rays_pinhole(o3c.Tensor(o3d_ray_intrinsics(intrinsics)), o3c.Tensor(extrinsic),
                                              width, height)
        ans = self.scene.cast_rays(rays)
        depth = ans["t_hit"].numpy().astype(np.float32)  # rays are not normalised: t is z-depth
        hit = np.isfinite(depth) & (depth <= depth_max_m)
        labels = np.full(depth.shape, VOID, dtype=np.int64)
        labels[hit] = self.tri_class[ans["primitive_ids"].numpy()[hit].astype(np.int64)]
        depth[~hit] = 0.0
        return depth, labels


def voxel_labels(coords: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, tri_class: np.ndarray,
                 max_dist_m: float | None = None, voxel_size_m: float = 0.05) -> np.ndarray:
    """(N,) int64 class per voxel centre ``coords`` (N, 3) world metres: the class of the
    nearest triangle of the mesh (vertices (V, 3) m, triangles (F, 3), tri_class (F,)), -1
    (void) beyond ``max_dist_m`` -- default one voxel diagonal, sqrt(3) * voxel_size_m."""
    if max_dist_m is None:
        max_dist_m = float(np.sqrt(3.0) * voxel_size_m)
    coords = np.asarray(coords, dtype=np.float32).reshape(-1, 3)
    mesh = LabelledMesh(vertices, triangles, tri_class)
    return mesh.voxel_labels(coords, max_dist_m) if len(coords) else np.zeros(0, np.int64)


def nearest_vertex_labels(coords: np.ndarray, vertices: np.ndarray, vertex_labels: np.ndarray,
                          max_dist_m: float) -> np.ndarray:
    """(N,) int64 class per point of ``coords`` (N, 3) metres: the label of the nearest vertex of
    a labelled mesh (vertices (V, 3) m, vertex_labels (V,) int, -1 = void), or -1 when that
    vertex is farther than ``max_dist_m``. Void vertices are left out of the search, so a
    voxel next to an unannotated patch takes the nearest *labelled* vertex in range (ScanNet
    meshes are dense: ~1-2 cm between vertices)."""
    from scipy.spatial import cKDTree

    coords = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(vertex_labels).astype(np.int64).ravel()
    keep = labels != VOID
    out = np.full(len(coords), VOID, dtype=np.int64)
    if not keep.any() or not len(coords):
        return out
    tree = cKDTree(np.asarray(vertices, dtype=np.float64)[keep])
    dist, idx = tree.query(coords, k=1, distance_upper_bound=max_dist_m)
    hit = np.isfinite(dist)
    out[hit] = labels[keep][idx[hit]]
    return out
