"""Per-frame camera geometry for the voxel map: input validation, rigid-pose inversion,
candidate-pixel grids and depth-image surface normals / incidence angles.

Conventions: pinhole intrinsics (3, 3) in pixels; poses (4, 4) world-from-camera with OpenCV
camera axes (x right, y down, z forward); depth (H, W) float32 z-depth in metres, 0 = invalid.
"""
from __future__ import annotations


import math

import numpy as np

# Rotation tolerances of a pose, on max |R^T R - I| and |det R - 1|. Recorded poses are only
# nearly rigid: 7-Scenes' KinectFusion poses, written with 8 digits, are off by 1.5e-4. Up to
# NEAR_RIGID_TOL a pose is accepted and its rotation replaced by the nearest rotation (SVD:
# U V^T); beyond it the matrix is not a camera pose (a scaled or sheared transform) and is
# rejected. Below RIGID_EXACT_TOL (float64 round-off) the pose is used unchanged.
NEAR_RIGID_TOL = 1e-2
RIGID_EXACT_TOL = 1e-9
LAST_ROW_TOL = 1e-6   # |pose[3] - (0, 0, 0, 1)| tolerance
# Depth-normal differences: both one-sided differences are "smooth" (use the central difference)
# when they differ by at most this fraction of the larger one; else the smaller jump wins.
SMOOTH_JUMP_RATIO = 0.5
# Plausible pinhole fields of view, degrees: a focal length of a few pixels or less (e.g. 1e-3, a
# near-180-degree view) sends back-projected points kilometres away and sizes the per-frame
# block table in tebibytes; one that sees under a degree is a unit mix-up (metres vs pixels).
MIN_FOV_DEG, MAX_FOV_DEG = 1.0, 179.0
# How far the principal point may sit from the image centre, as a fraction of the image size on
# each axis: real cameras put it within a few percent of the centre (crops rarely past 15%), while
# a K calibrated for twice or half the resolution puts it at a full or a quarter width off -- a
# map fused through it is skewed with no other sign.
MAX_PRINCIPAL_OFFSET = 0.2


def _describe(a) -> str:
    return f"{a.shape} {a.dtype}" if isinstance(a, np.ndarray) else type(a).__name__


def field_of_view_deg(focal_px: float, centre_px: float, size_px: int) -> float:
    """Angle in degrees that ``size_px`` pixels span through a pinhole of focal length
    ``focal_px`` (pixels) with principal point ``centre_px`` (pixels; the image spans
    [-0.5, size - 0.5], OpenCV pixel centres)."""
    return math.degrees(math.atan2(centre_px + 0.5, focal_px) + math.atan2(size_px - 0.5 - centre_px, focal_px))


def check_intrinsics(intrinsics, width: int | None = None, height: int | None = None) -> np.ndarray:
    """(3, 3) float64 pinhole matrix with fx, fy > 0 and last row (0, 0, 1). With the image
    size (pixels), the horizontal and vertical fields of view must also be plausible, within
    (MIN_FOV_DEG, MAX_FOV_DEG), and the principal point near the centre (MAX_PRINCIPAL_OFFSET)."""
    k = np.asarray(intrinsics, dtype=np.float64)
    if k.shape != (3, 3):
        raise ValueError(f"intrinsics must be a finite (3, 3) matrix, got {_describe(np.asarray(intrinsics))}")
    if not np.isfinite(k).all():
        raise ValueError(f"intrinsics hold NaN or inf: {k.tolist()}")
    if k[0, 0] <= 0 or k[1, 1] <= 0 or not np.allclose(k[2], (0, 0, 1)) or k[1, 0] != 0:
        raise ValueError(f"intrinsics must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {k.tolist()}")
    if width is not None and height is not None:
        for axis, f, c, size in (("horizontal", k[0, 0], k[0, 2], width), ("vertical", k[1, 1], k[1, 2], height)):
            fov = field_of_view_deg(f, c, size)
            if not MIN_FOV_DEG < fov < MAX_FOV_DEG:
                raise ValueError(f"intrinsics give a {axis} field of view of {fov:.4g} deg for a {width}x{height} "
                                 f"image, outside ({MIN_FOV_DEG:g}, {MAX_FOV_DEG:g}) deg: focal lengths are in "
                                 f"pixels (fx = fy = {width / 2 / math.tan(math.radians(79 / 2)):.1f} for a "
                                 f"79-degree view), got fx = {k[0, 0]:g}, fy = {k[1, 1]:g}")
        offset = max(abs(k[0, 2] - width / 2) / width, abs(k[1, 2] - height / 2) / height)
        if offset > MAX_PRINCIPAL_OFFSET:
            raise ValueError(f"intrinsics put the principal point at ({k[0, 2]:g}, {k[1, 2]:g}), {offset:.0%} of the "
                             f"image's size off the centre of a {width}x{height} image (at most {MAX_PRINCIPAL_OFFSET:.0%}): "
                             f"they look like a {2 * k[0, 2]:.0f}x{2 * k[1, 2]:.0f} image's intrinsics; scale fx, fy, "
                             f"cx, cy to this image's size")
    return k


class IntrinsicsCache:
    """``check_intrinsics`` of the cameras a map sees, remembered: a map sees one or two, and the
    check (~0.2 ms) ran on every frame. At most ``MAX_CAMERAS`` are kept, then all forgotten (a
    camera whose K changes every frame is checked every time)."""

    MAX_CAMERAS = 16

    def __init__(self) -> None:
        self._checked: dict = {}

    def __call__(self, intrinsics, width: int, height: int) -> np.ndarray:
        a = np.asarray(intrinsics)
        key = (a.dtype.str, a.shape, a.tobytes(), width, height)
        if key not in self._checked:
            if len(self._checked) >= self.MAX_CAMERAS:
                self._checked.clear()
            self._checked[key] = check_intrinsics(a, width, height)
        return self._checked[key].copy()


def o3d_ray_intrinsics(k: np.ndarray) -> np.ndarray:
    """K for ``RaycastingScene.create_rays_pinhole``, which puts pixel centres at (u + 0.5,
    v + 0.5): shifting the principal point by half a pixel gives the OpenCV-convention rays."""
    out = np.array(k, dtype=np.float64)
    out[0, 2] += 0.5
    out[1, 2] += 0.5
    return out


def check_pose(pose) -> np.ndarray:
    """(4, 4) float64 rigid transform (R^T R = I, det R = 1, last row 0 0 0 1) or ValueError.

    A nearly rigid rotation (max |R^T R - I| and |det R - 1| <= ``NEAR_RIGID_TOL``) is
    re-orthonormalised to the nearest rotation (the orthogonal polar factor U V^T of its SVD);
    a returned pose is always rigid to float64 round-off.
    """
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (4, 4) or not np.isfinite(p).all():
        raise ValueError(f"pose must be a finite (4, 4) world-from-camera matrix, got {_describe(np.asarray(pose))}")
    if np.abs(p[3] - (0, 0, 0, 1)).max() > LAST_ROW_TOL:
        raise ValueError(f"pose is not a rigid transform: last row must be (0, 0, 0, 1), got {p[3].tolist()}")
    r = p[:3, :3]
    ortho_err = float(np.abs(r.T @ r - np.eye(3)).max())
    det = float(np.linalg.det(r))
    if ortho_err > NEAR_RIGID_TOL:
        raise ValueError(f"pose is not a rigid transform: its rotation is not orthonormal (max |R^T R - I| = "
                         f"{ortho_err:.3g} > {NEAR_RIGID_TOL:g})")
    if abs(det - 1.0) > NEAR_RIGID_TOL:
        raise ValueError(f"pose is not a rigid transform: det(R) = {det:.4f}, expected 1 (a reflection?)")
    if ortho_err > RIGID_EXACT_TOL or abs(det - 1.0) > RIGID_EXACT_TOL:
        u, _, vt = np.linalg.svd(r)
        p = p.copy()
        p[:3, :3] = u @ vt   # det(U V^T) = +1 here: det(R) is within NEAR_RIGID_TOL of 1
        p[3] = (0, 0, 0, 1)
    return p


def invert_rigid(pose: np.ndarray) -> np.ndarray:
    """camera-from-world (4, 4) of a rigid world-from-camera pose."""
    out = np.eye(4)
    out[:3, :3] = pose[:3, :3].T
    out[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return out


def check_frame(depth, logits, rgb, weights, num_classes: int) -> tuple:
    """Validate one frame's images; returns (depth, logits, rgb, weights) as C-contiguous numpy.

    depth (H, W) float32 metres; logits (H, W, K) float32 (numpy or CPU torch) or None;
    rgb (H, W, 3) uint8 or None; weights (H, W) float32 >= 0 or None.
    """
    if not isinstance(depth, np.ndarray) or depth.ndim != 2 or depth.dtype != np.float32:
        raise ValueError(f"depth must be a (H, W) float32 array of metres, got {_describe(depth)}")
    h, w = depth.shape
    if logits is not None:
        if hasattr(logits, "detach"):  # a torch tensor
            logits = logits.detach().cpu().numpy()
        if not isinstance(logits, np.ndarray) or logits.dtype != np.float32 or logits.ndim != 3:
            raise ValueError(f"logits must be a (H, W, K) float32 array, got {_describe(logits)}")
        if logits.shape[:2] != (h, w):
            raise ValueError(f"logits are {logits.shape[1]}x{logits.shape[0]} pixels but depth is {w}x{h}")
        if logits.shape[2] != num_classes:
            raise ValueError(f"logits have K = {logits.shape[2]} classes, the map has {num_classes}")
        logits = np.ascontiguousarray(logits)
    if rgb is not None:
        if not isinstance(rgb, np.ndarray) or rgb.dtype != np.uint8 or rgb.shape != (h, w, 3):
            raise ValueError(f"rgb must be a ({h}, {w}, 3) uint8 array, got {_describe(rgb)}")
        rgb = np.ascontiguousarray(rgb)
    if weights is not None:
        if not isinstance(weights, np.ndarray) or weights.dtype != np.float32 or weights.shape != (h, w):
            raise ValueError(f"weights must be a ({h}, {w}) float32 array, got {_describe(weights)}")
        if not np.isfinite(weights).all() or (weights < 0).any():
            raise ValueError("weights must be finite and >= 0")
    return np.ascontiguousarray(depth), logits, rgb, weights


def clean_depth(depth: np.ndarray, depth_min: float, depth_max: float) -> np.ndarray:
    """Depth with invalid entries (NaN, inf, 0, outside [depth_min, depth_max]) set to 0."""
    from calnav.mapping.semantic_kernels import clean_depth as kernel   # (see incidence_angles)

    # NaN compares False: bad; the bounds compare as float32 (as numpy's with python floats)
    return kernel(depth.ravel(), np.float32(depth_min), np.float32(depth_max)).reshape(depth.shape)


class BlockTable:
    """A frame's touched blocks as a dense table over their bounding box, padded by one block
    on every side: ``low`` (3,) int the padded corner (block coordinates), ``dims`` (3,) its
    size, ``in_frame`` (prod(dims),) bool the frame's blocks, ``cells`` (B,) their entries."""

    def __init__(self, block_coords: np.ndarray):
        self.low = block_coords.min(0) - 1
        self.dims = block_coords.max(0) - self.low + 2
        rel = block_coords - self.low
        self.cells = rel[:, 0] + self.dims[0] * (rel[:, 1] + self.dims[1] * rel[:, 2])
        self.in_frame = np.zeros(int(np.prod(self.dims)), bool)
        self.in_frame[self.cells] = True

    def cells_of(self, ids: np.ndarray, res3: int) -> np.ndarray:
        """(B',) int64 sorted table cells of the blocks holding table ids (n,)."""
        mark = np.zeros(self.in_frame.size, bool)
        mark[ids // res3] = True
        return np.flatnonzero(mark)

    def block_coords(self, cells: np.ndarray) -> np.ndarray:
        """(B', 3) int32 block coordinates of table cells (B',)."""
        d0, d1 = int(self.dims[0]), int(self.dims[1])
        rel = np.stack([cells % d0, (cells // d0) % d1, cells // (d0 * d1)], axis=1)
        return (rel + self.low).astype(np.int32)

    def flat_indices(self, ids: np.ndarray, buffer_index: np.ndarray, res3: int,
                     cells: np.ndarray | None = None) -> np.ndarray:
        """Flat voxel-buffer index (n,) int64 of table ids (n,) (cell * res3 + voxel in block),
        given the buffer index (B,) of each block of ``cells`` (default: the frame's blocks; -1:
        not allocated, giving -1)."""
        table = np.full(self.in_frame.size, -1, np.int64)
        table[self.cells if cells is None else cells] = buffer_index
        block = table[ids // res3]
        return np.where(block >= 0, block * res3 + ids % res3, -1)


class PixelGrid:
    """Candidate pixels of one (intrinsics, image size, stride) with preallocated scratch.

    pix: (n,) int64 flat pixel index; rays: (3, n) float32 camera-frame rays with z = 1 (a
    point at depth d is d * ray). The scratch arrays are reused by every frame (fresh large
    numpy arrays page-fault on every allocation, which costs more than the arithmetic).
    """

    def __init__(self, k: np.ndarray, height: int, width: int, stride: int):
        off = stride // 2
        v, u = np.mgrid[off:height:stride, off:width:stride]
        u, v = u.ravel(), v.ravel()
        y = (v - k[1, 2]) / k[1, 1]
        self.stride = stride
        self.pix = (v * width + u).astype(np.int64)
        self.rays = np.ascontiguousarray(np.stack([(u - k[0, 2] - k[0, 1] * y) / k[0, 0], y, np.ones(len(u))]),
                                         dtype=np.float32)
        n = len(u)
        self.depth = np.empty(n, np.float32)
        self.pts = np.empty((3, n), np.float32)
        self.g = np.empty((3, n), np.int32)
        self.slot = np.empty(n, np.int64)
        self.ids = np.empty(n, np.int64)
        self.keys = np.empty((n, 3), np.int32)


def auto_stride(k: np.ndarray, voxel_size_m: float, depth_max_m: float, spacing_voxels: float) -> int:
    """Largest pixel stride whose candidate spacing at depth_max is <= spacing_voxels voxels."""
    f = min(k[0, 0], k[1, 1])
    return max(1, int(spacing_voxels * voxel_size_m * f / depth_max_m))


def incidence_angles(depth: np.ndarray, k: np.ndarray, pix: np.ndarray, offset: int) -> np.ndarray:
    """(n,) float32 incidence angle in degrees [0, 90] between the viewing ray of flat pixel
    ``pix`` (n,) and the depth-image surface normal there.

    With z(u, v) the depth image and z_u, z_v its derivatives (pixels), the back-projected
    surface has normal n ~ (-fx z_u, -fy z_v, (u - cx) z_u + (v - cy) z_v + z) and n . r = z
    for the ray r = ((u - cx) / fx, (v - cy) / fy, 1), so cos = z / (|n| |r|) (skew ignored).
    Each derivative is the central difference over +-``offset`` pixels where the surface is
    smooth there, else the one-sided difference on the side with the smaller depth jump (so a
    depth discontinuity does not bend the normal); an axis with no valid neighbour counts as
    flat.
    """
    # imported here: envs.config reads this module and need not load numba
    from calnav.mapping.semantic_kernels import incidence_cosines

    h, w = depth.shape
    pix = np.ascontiguousarray(pix, dtype=np.int64)
    if len(pix) and (pix.min() < 0 or pix.max() >= h * w) or not 1 <= offset:
        raise ValueError(f"pixels must lie in the {w}x{h} image and offset be >= 1, got offset {offset}")
    cos = np.empty(len(pix), np.float32)
    incidence_cosines(np.ascontiguousarray(depth, dtype=np.float32).ravel(), w, h, float(k[0, 0]), float(k[1, 1]),
                      float(k[0, 2]), float(k[1, 2]), pix, int(offset), SMOOTH_JUMP_RATIO, cos)
    return np.degrees(np.arccos(np.minimum(cos, np.float32(1)))).astype(np.float32)
