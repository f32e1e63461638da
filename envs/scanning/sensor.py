"""The scanning sensor: what a consumer RGB-D camera makes of a perfect rendering.

Depth (``noisy_depth``), in this order, each step a documented effect of structured-light /
active-stereo sensors (Kinect v1 class):

1. lateral jitter: each pixel reads the depth of a neighbour displaced by N(0, lateral_jitter_px)
   (the pattern's correlation window smears depth sideways; edges get ragged);
2. axial noise: z + N(0, sigma_z(z)), sigma_z = a + b (z - z0)^2 metres (Nguyen, Izadi & Lovell,
   3DIMPVT 2012: a = 0.0012, b = 0.0019, z0 = 0.4);
3. disparity quantisation: disparity d = B f / z is measured in steps of ``disparity_step_px`` at
   the native focal length f, so depth comes in steps that grow with z^2 (2.6 cm at 3 m);
4. dropout (depth 0): incidence beyond ``grazing_max_deg`` from the surface normal; surfaces
   too dark (absorb the projected pattern) or too bright (saturate) with probability
   ``absorb_dropout``; the far side of occlusion edges (the projector's shadow); random pixels;
5. range: returns outside [min_depth_m, max_depth_m] are invalid.

Colour (``camera_rgb``): per-frame exposure (log2 gain ~ N(0, exposure_std_stops)) and
white-balance gains, motion blur along a random direction, per-pixel noise, so the same
surface has a different colour in every view, as on real sensors; the TSDF averages them.
"""
from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np

from calnav.envs.scanning.config import ScanningConfig

LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)   # ITU-R BT.601 luminance weights


def axial_sigma_m(z: np.ndarray, cfg: ScanningConfig) -> np.ndarray:
    """sigma_z (metres) of the axial depth noise at depth ``z`` (metres)."""
    return cfg.axial_noise_m + cfg.axial_noise_quad * (z - cfg.axial_noise_z0_m) ** 2


def quantise_depth(z: np.ndarray, cfg: ScanningConfig) -> np.ndarray:
    """Depth (metres, > 0) as the sensor reports it after disparity quantisation."""
    if cfg.disparity_step_px <= 0:
        return z
    bf = cfg.baseline_m * cfg.disparity_focal_px
    steps = np.maximum(np.round(bf / z / cfg.disparity_step_px), 1.0)
    return (bf / (steps * cfg.disparity_step_px)).astype(np.float32)


@lru_cache(maxsize=4)
def _unit_rays(h: int, w: int, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(H, W, 3) float32 camera-frame unit ray directions of a pinhole camera."""
    x = (np.arange(w, dtype=np.float32) - cx) / fx
    y = (np.arange(h, dtype=np.float32) - cy) / fy
    rays = np.stack(np.broadcast_arrays(x[None, :], y[:, None], np.float32(1.0)), axis=-1)
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


@lru_cache(maxsize=4)
def _pixel_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 column and row coordinates."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return u, v


def incidence_cos(normals: np.ndarray, pose: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """(H, W) float32 |cos| of the angle between each pixel's ray and the hit surface's normal
    (1 = head-on, 0 = grazing or a miss). normals: (H, W, 3) world-frame unit normals (zeros on
    a miss). Component-wise (no per-pixel matrix products: those are slow for 3-vectors)."""
    h, w = normals.shape[:2]
    k = np.asarray(intrinsics, dtype=np.float64)
    rays = _unit_rays(h, w, float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]))
    r = np.asarray(pose, dtype=np.float64)[:3, :3].astype(np.float32)
    nx, ny, nz = normals[..., 0], normals[..., 1], normals[..., 2]
    cos = np.zeros((h, w), np.float32)
    for c in range(3):   # camera-frame normal component c = (R^T n)_c, dotted with the ray
        cos += rays[..., c] * (r[0, c] * nx + r[1, c] * ny + r[2, c] * nz)
    return np.abs(cos, out=cos)


def incidence_deg(normals: np.ndarray, pose: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """(H, W) angle between each pixel's ray and the hit surface's normal, degrees (0 = head-on,
    90 on a miss)."""
    return np.degrees(np.arccos(np.clip(incidence_cos(normals, pose, intrinsics), 0.0, 1.0)))


def occlusion_shadow(z: np.ndarray, jump_m: float, width_px: int) -> np.ndarray:
    """(H, W) bool: pixels on the far side of a depth jump: more than ``jump_m`` (metres) behind
    the nearest pixel within ``width_px`` pixels (square window), so a band ``width_px`` wide.
    z: (H, W) metres, 0 invalid."""
    if width_px <= 0:
        return np.zeros(z.shape, dtype=bool)
    far = np.where(z > 0, z, np.inf).astype(np.float32)
    size = 2 * int(width_px) + 1
    near = cv2.erode(far, np.ones((size, size), np.uint8), borderType=cv2.BORDER_REPLICATE)   # window minimum
    with np.errstate(invalid="ignore"):   # inf - inf where both are invalid: NaN compares False
        return np.isfinite(far) & (far - near > jump_m)


def noisy_depth(depth: np.ndarray, rgb: np.ndarray, normals: np.ndarray, pose: np.ndarray,
                intrinsics: np.ndarray, cfg: ScanningConfig, rng: np.random.Generator) -> np.ndarray:
    """The scanner's depth image.

    depth: (H, W) float32 true z-depth, metres, 0 on a miss. rgb: (H, W, 3) uint8 true surface
    colour (decides absorption / saturation). normals: (H, W, 3) float32 world normals. pose:
    (4, 4) world-from-camera. intrinsics: (3, 3). Returns (H, W) float32 metres, 0 = no return.
    """
    h, w = depth.shape
    z = depth.astype(np.float32, copy=True)
    invalid = z <= 0
    if cfg.lateral_jitter_px > 0:   # nearest-neighbour reads keep depth edges sharp, never blended
        u, v = _pixel_grid(h, w)
        jitter = rng.standard_normal((2, h, w), dtype=np.float32)
        jitter *= np.float32(cfg.lateral_jitter_px)
        map_u, map_v = np.clip(u + jitter[0], 0, w - 1), np.clip(v + jitter[1], 0, h - 1)
        z = cv2.remap(z, map_u, map_v, cv2.INTER_NEAREST)
        normals = cv2.remap(normals, map_u, map_v, cv2.INTER_NEAREST)
        rgb = cv2.remap(rgb, map_u, map_v, cv2.INTER_NEAREST)
        invalid = z <= 0
    z_safe = np.where(invalid, np.float32(1.0), z)
    z = z_safe + rng.standard_normal((h, w), dtype=np.float32) * axial_sigma_m(z_safe, cfg).astype(np.float32)
    z = quantise_depth(np.maximum(z, np.float32(1e-3)), cfg)
    drop = invalid.copy()
    drop |= incidence_cos(normals, pose, intrinsics) < np.float32(math.cos(math.radians(cfg.grazing_max_deg)))
    rgb_f = rgb.astype(np.float32)
    luma = LUMA[0] * rgb_f[..., 0] + LUMA[1] * rgb_f[..., 1] + LUMA[2] * rgb_f[..., 2]
    extreme = (luma < cfg.dark_level) | (luma > cfg.bright_level)
    drop |= extreme & (rng.random((h, w), dtype=np.float32) < cfg.absorb_dropout)
    drop |= occlusion_shadow(np.where(invalid, 0, depth), cfg.edge_jump_m, cfg.edge_width_px)
    if cfg.random_dropout > 0:
        drop |= rng.random((h, w), dtype=np.float32) < cfg.random_dropout
    drop |= (z < cfg.min_depth_m) | (z > cfg.max_depth_m)
    z[drop] = 0.0
    return z.astype(np.float32)


def motion_blur_kernel(length_px: float, angle_rad: float) -> np.ndarray:
    """(k, k) float32 line kernel of ``length_px`` pixels along ``angle_rad``, summing to 1."""
    k = max(1, int(math.ceil(length_px)) | 1)   # odd size
    kernel = np.zeros((k, k), np.float32)
    c = (k - 1) / 2
    for t in np.linspace(-length_px / 2, length_px / 2, max(2, 4 * k)):
        x, y = c + t * math.cos(angle_rad), c + t * math.sin(angle_rad)
        kernel[int(round(min(max(y, 0), k - 1))), int(round(min(max(x, 0), k - 1)))] += 1.0
    return kernel / kernel.sum()


def camera_rgb(rgb: np.ndarray, cfg: ScanningConfig, rng: np.random.Generator) -> np.ndarray:
    """The colour camera's image of a true-colour render: (H, W, 3) uint8 -> (H, W, 3) uint8."""
    gain = 2.0 ** rng.normal(0.0, cfg.exposure_std_stops)
    balance = np.clip(1.0 + rng.normal(0.0, cfg.white_balance_std, 3), 0.5, 1.5)
    out = rgb.astype(np.float32) * np.float32(gain) * balance.astype(np.float32)
    length = rng.uniform(0.0, cfg.blur_max_px)
    if length >= 1.0:
        out = cv2.filter2D(out, -1, motion_blur_kernel(length, rng.uniform(0, math.pi)),
                           borderType=cv2.BORDER_REFLECT)
    if cfg.rgb_noise_std > 0:   # luminance noise (one draw per pixel, shared by the channels)
        noise = rng.standard_normal(out.shape[:2], dtype=np.float32)
        noise *= np.float32(cfg.rgb_noise_std)
        out += noise[..., None]
    return np.clip(np.round(out), 0, 255).astype(np.uint8)
