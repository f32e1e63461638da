"""The 2D map's grid geometry: ground-plane projection of 3D points and fused voxels, cell
indices, discs and dilation (numpy / OpenCV, and compiled loops where a frame's per-point
numpy passes cost more than the work: ``backproject``, ``cell_of``, ``free_rays``; no state).

Conventions: "world" below is the agent's map frame -- the episode-start frame of
``agent.sensors`` (the simulator's world frame is never seen) -- z-up, metres, floor at z = 0.
A 2D map of ``n`` x ``n`` cells of edge ``cell_m`` has its corner (cell (0, 0)'s lower-left) at
world ``origin`` (2,) metres; arrays are indexed ``[row, col]`` = ``[y, x]``; flat cell index =
row * n + col.
"""
from __future__ import annotations

import functools

import cv2
import numpy as np

from calnav.common.jit import compiled


def backproject(depth: np.ndarray, intrinsics: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points of the valid (depth > 0) pixels of a depth image.

    depth (H, W) float metres (0 = invalid); intrinsics (3, 3) (pixel (u, v)'s centre at
    (u, v)); pose (4, 4) world-from-camera, OpenCV axes. Returns points (N, 3) float32 world
    metres and pix (N,) int64 flat pixel indices (row-major) of the valid pixels.
    """
    h, w = depth.shape
    k, pose = np.asarray(intrinsics, np.float64), np.ascontiguousarray(pose, np.float64)
    points, pix = np.empty((h * w, 3), np.float32), np.empty(h * w, np.int64)
    m = _backproject(np.ascontiguousarray(depth).reshape(-1), w, k[0, 0], k[1, 1], k[0, 2], k[1, 2], pose, points, pix)
    return points[:m], pix[:m]


@compiled
def _backproject(depth, w, fx, fy, cx, cy, pose, points, pix):
    """``backproject`` into points (H * W, 3) / pix (H * W,); returns the number of valid pixels.
    In float64, rounded to float32 at the end."""
    m = 0
    for i in range(depth.shape[0]):
        if not depth[i] > 0:
            continue
        z = np.float64(depth[i])
        x = (i % w - cx) * z / fx
        y = (i // w - cy) * z / fy
        for r in range(3):
            points[m, r] = np.float32(pose[r, 0] * x + pose[r, 1] * y + pose[r, 2] * z + pose[r, 3])
        pix[m] = i
        m += 1
    return m


def lattice_aligned_origin(centre_xy: np.ndarray, size_m: float, lattice_m: float | None) -> np.ndarray:
    """Corner (2,) metres of a ``size_m`` square map centred on ``centre_xy`` (2,) metres,
    moved by less than ``lattice_m`` so that cell edges fall half-way between the points of
    the lattice ``lattice_m * Z^2`` (the voxel centres; None = no alignment, the exact centre).

    Why: the fused map projects voxel centres (multiples of the voxel size) into cells. With a
    corner on the lattice (an agent starting at the frame origin, as in Habitat's start frame)
    every centre sits exactly on a cell edge and floating-point rounding sends whole voxel
    columns to the neighbouring cell: one cell in ~3 stays empty and goal components break up.
    Half a lattice step away from every edge (cell_m a multiple of lattice_m), no rounding can
    move a centre across one.
    """
    corner = np.asarray(centre_xy, np.float64) - size_m / 2
    if not lattice_m:
        return corner
    return (np.floor(corner / lattice_m) + 0.5) * lattice_m


def cell_of(xy: np.ndarray, origin: np.ndarray, cell_m: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat cell index (N,) int64 of world points xy (N, 2) metres (or more columns: the first two
    are x, y), and an inside mask (N,) bool (points outside the n x n map get index 0 and inside
    False)."""
    xy = np.ascontiguousarray(np.asarray(xy)[:, :2], dtype=np.float64)   # (exact; one compiled signature)
    flat, inside = np.empty(len(xy), np.int64), np.empty(len(xy), bool)
    _cell_of(xy, np.asarray(origin, np.float64), float(cell_m), int(n), flat, inside)
    return flat, inside


@compiled
def _cell_of(xy, origin, cell_m, n, flat, inside):
    for i in range(xy.shape[0]):   # floor((x - origin) / cell_m)
        x = np.int64(np.floor((xy[i, 0] - origin[0]) / cell_m))
        y = np.int64(np.floor((xy[i, 1] - origin[1]) / cell_m))
        inside[i] = 0 <= x < n and 0 <= y < n
        flat[i] = y * n + x if inside[i] else 0


def class_confidence_sums(cells: np.ndarray, classes: np.ndarray, conf: np.ndarray, num_cells: int,
                          num_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """Per (class, cell) sum of confidences and point count (dense; the reference that
    ``project_voxels`` and the tests use -- the agent updates sparsely, ``sparse_bin_sums``).

    cells (N,) flat cell index, classes (N,) int class of each point (its arg-max), conf (N,)
    that class's confidence. Returns sums (K, num_cells) float64 and counts (K, num_cells)
    int64; mean = sums / counts where counts > 0.
    """
    bins = np.asarray(classes, np.int64) * num_cells + np.asarray(cells, np.int64)
    size = num_classes * num_cells
    sums = np.bincount(bins, weights=np.asarray(conf, np.float64), minlength=size)
    counts = np.bincount(bins, minlength=size)
    return sums.reshape(num_classes, num_cells), counts.reshape(num_classes, num_cells)


def sparse_bin_sums(bins: np.ndarray, weights: np.ndarray, counts: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sums over equal bins without a dense array: bins (N,) int64, weights (N,) float, counts
    (N,) int per-entry count (default 1). Returns (unique bins (M,), weight sums (M,) float64,
    count sums (M,) int64)."""
    u, inv = np.unique(bins, return_inverse=True)
    sums = np.bincount(inv, weights=np.asarray(weights, np.float64), minlength=len(u))
    cnt = np.ones(len(bins), np.int64) if counts is None else np.asarray(counts, np.int64)
    return u, sums, np.bincount(inv, weights=cnt, minlength=len(u)).astype(np.int64)


def project_voxels(coords: np.ndarray, probs: np.ndarray, origin: np.ndarray, cell_m: float,
                   n: int) -> np.ndarray:
    """Ground-plane semantic confidence map of fused voxels: the non-incremental reference
    that the tests check ``FusedMapBuilder``'s incremental projection against.

    coords (N, 3) world metres, probs (N, K) fused probabilities. Each voxel votes for its
    arg-max class l with confidence probs[l]; the confidence that class l is at a cell is the
    mean of the votes for l in that cell (0 where none). Returns (K, n, n) float32.
    """
    k = probs.shape[1]
    cells, inside = cell_of(coords[:, :2], origin, cell_m, n)
    cls = probs.argmax(axis=1)
    conf = probs[np.arange(len(probs)), cls]
    sums, counts = class_confidence_sums(cells[inside], cls[inside], conf[inside], n * n, k)
    mean = np.divide(sums, counts, out=np.zeros_like(sums), where=counts > 0)
    return mean.astype(np.float32).reshape(k, n, n)


def floor_holes(depth: np.ndarray, intrinsics: np.ndarray, pose: np.ndarray, near_m: float,
                far_m: float, floor_pixels: np.ndarray | None = None) -> np.ndarray:
    """World points (M, 2) metres on the floor plane (z = 0) where the floor should have
    returned depth but did not: pixels with no valid depth whose ray meets the floor at a
    z-depth in (near_m, far_m). Through a hole in a reconstructed floor the depth sensor sees
    nothing (Habitat renders 0 there), and the simulator's navigation mesh has no floor.

    depth (H, W) float metres (0 = invalid); intrinsics (3, 3); pose (4, 4) world-from-camera.
    floor_pixels (H, W) bool, optional: pixels that saw the floor; then only invalid pixels with
    floor seen below them in their image column count (a hole is framed by floor in front of
    it; an object closer than the sensor's minimum range also returns nothing, but nothing
    below it in the image is floor seen past it).
    """
    h, w = depth.shape
    invalid = depth <= 0
    if floor_pixels is not None:
        below = np.zeros_like(invalid)   # some pixel lower in the column saw the floor
        below[:-1] = np.flip(np.logical_or.accumulate(np.flip(floor_pixels, 0), axis=0), 0)[1:]
        invalid &= below
    pix = np.flatnonzero(invalid.reshape(-1))
    if len(pix) == 0:
        return np.zeros((0, 2), np.float32)
    v, u = np.divmod(pix, w)
    r = pose[:3, :3]
    x = (u - intrinsics[0, 2]) / intrinsics[0, 0]
    y = (v - intrinsics[1, 2]) / intrinsics[1, 1]
    dz = r[2, 0] * x + r[2, 1] * y + r[2, 2]          # world z of the ray direction (camera z = 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -pose[2, 3] / dz                          # z-depth at which the ray meets z = 0
    keep = (dz < 0) & (t > near_m) & (t < far_m)
    t, x, y = t[keep], x[keep], y[keep]
    px = pose[0, 3] + t * (r[0, 0] * x + r[0, 1] * y + r[0, 2])
    py = pose[1, 3] + t * (r[1, 0] * x + r[1, 1] * y + r[1, 2])
    return np.stack([px, py], axis=1).astype(np.float32)


def obstacle_points(points: np.ndarray, min_height_m: float, max_height_m: float) -> np.ndarray:
    """Bool mask (N,) of points (N, 3) whose height above the floor (z) is in
    [min_height_m, max_height_m] metres."""
    z = points[:, 2]
    return (z >= min_height_m) & (z <= max_height_m)


def free_rays(camera_xy: np.ndarray, points: np.ndarray, pix: np.ndarray, width: int, obstacle: np.ndarray,
              samples: int) -> np.ndarray:
    """Ground points (M, 2) world metres seen as free along each image column (a laser scan).

    points (N, 3) world metres of the valid pixels, pix (N,) their flat pixel indices (row-major,
    increasing, as ``backproject`` returns them) in an image ``width`` pixels wide, obstacle (N,)
    bool. Per column the view is free from the camera up to the nearest obstacle point's
    horizontal range (or the farthest point's range if the column holds no obstacle), along
    the direction of that point; ``samples`` points are placed evenly on each such segment.
    """
    if len(points) == 0:
        return np.zeros((0, 2), np.float32)
    if len(pix) != len(points) or len(obstacle) != len(points) or pix[0] < 0:   # (the kernel does not check)
        raise ValueError(f"free_rays: points ({len(points)}), pix ({len(pix)}, from 0) and obstacle ({len(obstacle)}) "
                         "disagree")
    out = np.empty((width * samples, 2), np.float32)
    m = _free_rays(np.asarray(camera_xy, np.float64), points, np.ascontiguousarray(pix, np.int64), int(width),
                   np.ascontiguousarray(obstacle, bool), np.linspace(0.0, 1.0, samples), out)
    return out[:m]


@compiled
def _free_rays(camera_xy, points, pix, width, obstacle, t, out):
    """``free_rays`` into out (width * samples, 2); returns the number of rows written. Per column
    the smallest rank key -- obstacles by range, then free points by 1e6 - range (farthest
    first) -- the lowest row among equal keys."""
    best = np.full(width, np.inf)
    point = np.full(width, -1, np.int64)
    for i in range(pix.shape[0]):
        dx = np.float64(points[i, 0]) - camera_xy[0]
        dy = np.float64(points[i, 1]) - camera_xy[1]
        rng = np.hypot(dx, dy)
        key = rng if obstacle[i] else -rng + 1e6
        c = pix[i] % width
        if key < best[c]:   # pixels come row by row: strict < keeps the lowest row
            best[c], point[c] = key, i
    m = 0
    for c in range(width):
        if point[c] < 0:
            continue
        ex = np.float64(points[point[c], 0]) - camera_xy[0]
        ey = np.float64(points[point[c], 1]) - camera_xy[1]
        for j in range(t.shape[0]):
            out[m, 0] = np.float32(camera_xy[0] + ex * t[j])
            out[m, 1] = np.float32(camera_xy[1] + ey * t[j])
            m += 1
    return m


@functools.lru_cache(maxsize=32)
def disc_offsets(radius_cells: float) -> np.ndarray:
    """(M, 2) int (drow, dcol) offsets of the cells within ``radius_cells`` of a cell (read-only:
    one array per radius, as the agent asks for its footprint every step)."""
    r = int(np.ceil(radius_cells))
    dr, dc = np.mgrid[-r:r + 1, -r:r + 1]
    keep = dr ** 2 + dc ** 2 <= radius_cells ** 2
    out = np.stack([dr[keep], dc[keep]], axis=1)
    out.flags.writeable = False
    return out


def dilate(mask: np.ndarray, radius_cells: float) -> np.ndarray:
    """Bool mask dilated by a disc of ``radius_cells``."""
    if int(np.ceil(radius_cells)) <= 0:
        return mask.copy()
    # a 0/1 byte view in and out (no copies; cv2 keeps 0/1 values 0/1)
    return cv2.dilate(np.ascontiguousarray(mask, dtype=bool).view(np.uint8), _disc_kernel(float(radius_cells))).view(bool)


@functools.lru_cache(maxsize=32)
def _disc_kernel(radius_cells: float) -> np.ndarray:
    """(2r + 1, 2r + 1) uint8 structuring element of ``disc_offsets(radius_cells)`` (the agent
    dilates with a few fixed radii every step)."""
    r = int(np.ceil(radius_cells))
    kernel = np.zeros((2 * r + 1, 2 * r + 1), np.uint8)
    kernel[tuple((disc_offsets(radius_cells) + r).T)] = 1
    return kernel
