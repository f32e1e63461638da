"""Read-outs of a ``SemanticVoxelMap`` (mixed into it): surface voxels with their fused
probabilities, point queries, TSDF-gradient normals, a semantic point cloud and semantic
images rendered from any camera."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import open3d as o3d
import open3d.core as o3c
import torch

from mapping import frame_geometry as fg

TRILINEAR_CORNERS = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], np.int32)


class PointCloud(NamedTuple):
    """Surface points with semantics: points (P, 3) float32 m, colors (P, 3) uint8,
    normals (P, 3) float32 unit, probs (P, K) float32."""

    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    probs: np.ndarray


class MapReadouts:
    """Read-out methods; the host class provides cfg, vbg, num_classes, frames_integrated,
    _view, _counts, _readout, _lookup and _o3d_weight_threshold."""

    def _surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(coords (N, 3) float32 m, flat (N,) int64) of surface voxels with semantics."""
        cfg = self.cfg
        active = self.vbg.hashmap().active_buf_indices()
        if active.shape[0] == 0:
            return np.zeros((0, 3), np.float32), np.zeros(0, np.int64)
        coords, flat = self.vbg.voxel_coordinates_and_flattened_indices(active)
        coords, flat = coords.numpy(), flat.numpy().ravel()
        n = self._counts(flat)
        keep = np.flatnonzero(n > 0)
        flat, coords = flat[keep], coords[keep]
        tsdf, wgt = self._view("tsdf")[flat, 0], self._view("weight")[flat, 0]
        band = cfg.surface_band_voxels / cfg.trunc_voxels
        keep = np.flatnonzero((np.abs(tsdf) < band) & (wgt >= cfg.min_tsdf_weight))
        return coords[keep], flat[keep]

    def voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """Surface voxels with semantic observations: coords (N, 3) float32 world metres (voxel
        centres), probs (N, K) float32 fused probabilities."""
        coords, flat = self._surface()
        return coords, self._readout(flat) if len(flat) else np.zeros((0, self.num_classes), np.float32)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fused probs (n, K) of the voxels nearest to ``points`` (n, 3) world metres, and a bool
        (n,) mask of those that have semantic observations (others read uniform)."""
        keys = np.rint(np.asarray(points, dtype=np.float64).reshape(-1, 3) / self.cfg.voxel_size_m)
        flat = self._lookup(keys.astype(np.int32))
        observed = flat >= 0
        observed[observed] = self._counts(flat[observed]) > 0
        probs = np.full((len(flat), self.num_classes), 1.0 / self.num_classes, np.float32)
        if observed.any():
            probs[observed] = self._readout(flat[observed])
        return probs, observed

    def voxel_normals(self, coords: np.ndarray) -> np.ndarray:
        """(N, 3) float32 unit surface normals at voxel centres ``coords`` (N, 3) m from the TSDF
        gradient (central differences, one-sided where a neighbour is unallocated; 0 if none)."""
        keys = np.rint(np.asarray(coords, dtype=np.float64).reshape(-1, 3) / self.cfg.voxel_size_m).astype(np.int32)
        tsdf, wgt = self._view("tsdf")[:, 0], self._view("weight")[:, 0]

        def sample(kk):
            f = self._lookup(kk)
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

    def point_cloud(self) -> PointCloud:
        """Iso-surface points (``extract_point_cloud``) that have semantics, with colour, normal
        and the fused probs of the voxel nearest each point."""
        pcd = self.vbg.extract_point_cloud(self._o3d_weight_threshold) if self.vbg.hashmap().size() else None
        if pcd is None or pcd.is_empty():
            z = np.zeros((0, 3), np.float32)
            return PointCloud(z, np.zeros((0, 3), np.uint8), z, np.zeros((0, self.num_classes), np.float32))
        pts = pcd.point.positions.numpy()
        probs, observed = self.query(pts)
        colors = np.clip(pcd.point.colors.numpy() * 255.0 + 0.5, 0, 255).astype(np.uint8) if "colors" in pcd.point \
            else np.zeros((len(pts), 3), np.uint8)
        normals = pcd.point.normals.numpy() if "normals" in pcd.point else np.zeros_like(pts)
        return PointCloud(pts[observed], colors[observed], normals[observed], probs[observed])

    def _surface_scene(self):
        """Open3D RaycastingScene of the TSDF iso-surface mesh, cached until the next integrate."""
        if self._scene_cache is None or self._scene_cache[0] != self.frames_integrated:
            scene = None
            mesh = self.vbg.extract_triangle_mesh(self._o3d_weight_threshold) if self.vbg.hashmap().size() else None
            if mesh is not None and mesh.triangle.indices.shape[0] > 0:
                scene = o3d.t.geometry.RaycastingScene()
                scene.add_triangles(mesh.vertex.positions, mesh.triangle.indices.to(o3c.uint32))
            self._scene_cache = (self.frames_integrated, scene)
        return self._scene_cache[1]

    def render_semantics(self, intrinsics: np.ndarray, pose: np.ndarray, width: int,
                         height: int) -> tuple[np.ndarray, np.ndarray]:
        """Semantics seen by a camera: probs (H, W, K) float32 and valid (H, W) bool (the ray hit a
        surface with semantics within [depth_min, depth_max]).

        Rays are cast against the TSDF iso-surface mesh (marching cubes, cached per map state);
        each hit blends the fused probs of the observed voxels among the 8 around the hit point
        with trilinear weights. (``VoxelBlockGrid.ray_cast`` is not used: its first call after
        the map grows under-sizes a range buffer and silently misses most rays.)
        """
        cfg, kk = self.cfg, self.num_classes
        k, pose = fg.check_intrinsics(intrinsics, width, height), fg.check_pose(pose)
        probs = np.zeros((height * width, kk), np.float32)
        valid = np.zeros(height * width, bool)
        scene = self._surface_scene()
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
            flat = self._lookup((base.astype(np.int32)[:, None, :] + corners).reshape(-1, 3)).reshape(-1, 8)
            wts = np.prod(np.where(corners.astype(bool), frac[:, None, :], 1.0 - frac[:, None, :]), axis=2)
            ok = flat >= 0
            ok[ok] = self._counts(flat[ok]) > 0
            wts = np.where(ok, wts, 0.0).astype(np.float32)
            total = wts.sum(1)
            row, corner = np.nonzero(ok)
            uniq, inv = np.unique(flat[row, corner], return_inverse=True)
            if len(uniq):
                blend = np.zeros((len(hit), kk), np.float32)
                contrib = torch.from_numpy(self._readout(uniq))[torch.from_numpy(inv.ravel())]
                contrib *= torch.from_numpy(wts[row, corner])[:, None]
                torch.from_numpy(blend).index_add_(0, torch.from_numpy(row), contrib)
                good = total > 0
                probs[hit[good]] = blend[good] / total[good, None]
                valid[hit[good]] = True
        return probs.reshape(height, width, kk), valid.reshape(height, width)
