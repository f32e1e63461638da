"""Appearance changes of a segmenter's frames that are not camera augmentation: the
render-level recolouring of training instances (``data.recolour_fraction``) and the fixed
camera shift of evaluation frames (``data.eval_appearance: camera``).

Recolouring: calnav's houses draw each part's colour from a small per-class palette
(``envs.furniture_parts``), which a network learns in place of shape. A ``recolour_fraction``
share of a training house's instances gets every part (its triangles of one albedo) a new
colour, hue uniform, saturation U(0, 0.8), value U(0.15, 0.95), and a procedural pattern drawn
uniformly from ``envs.scene.Texture`` (an image texture the part had is dropped).

The camera shift stands in for a real camera and is deliberately *not* the training levers'
distribution (``eval.segmenter.photometric``): it decodes the sRGB frame to linear light,
applies a fixed warm colour cast (gains 1.12 / 1.0 / 0.85 +- 3 % per frame), a disc-shaped
defocus (radius 1.2 pixels; training blurs are Gaussian or linear), read + shot sensor noise
in linear light, a logistic camera response curve (training's tone curve is a power law), and
JPEG at a quality drawn from [40, 60]. Each frame's draws are seeded by (seed, frame index), so a
record is reproducible and independent of the batch size.
"""
from __future__ import annotations

import colorsys

import numpy as np

from calnav.envs.scene import Scene, Texture

CAST_GAINS = (1.12, 1.0, 0.85)    # camera shift: the warm cast, linear-light gains R, G, B
CAST_JITTER = 0.03                # camera shift: per-frame relative jitter of each gain
DEFOCUS_RADIUS_PX = 1.2           # camera shift: disc kernel radius, pixels
READ_NOISE = 0.004                # camera shift: read-noise std, linear light [0, 1]
SHOT_NOISE = 0.015                # camera shift: shot-noise std at white (std ~ sqrt(signal)), linear light
RESPONSE_SLOPE = 6.0              # camera shift: slope of the logistic response curve at mid-grey
JPEG_QUALITY = (40, 60)           # camera shift: JPEG quality range (cv2), inclusive


def recolour_scene(scene: Scene, fraction: float, rng: np.random.Generator) -> Scene:
    """A copy of ``scene`` whose instances, each with probability ``fraction``, have every part
    (triangles of one instance and one albedo) recoloured and repatterned (module docstring).
    The scene itself (perhaps shared by the in-memory scene cache) is not changed."""
    import dataclasses

    instances = np.unique(scene.tri_instance[scene.tri_instance >= 0])
    chosen = instances[rng.random(len(instances)) < fraction]
    hit = np.isin(scene.tri_instance, chosen)
    albedo, texture = scene.tri_albedo.copy(), scene.tri_texture.copy()
    if hit.any():
        parts = np.column_stack([scene.tri_instance[hit], scene.tri_albedo[hit].astype(np.int32)])
        _, part_of = np.unique(parts, axis=0, return_inverse=True)
        n = int(part_of.max()) + 1
        hsv = np.column_stack([rng.random(n), rng.uniform(0.0, 0.8, n), rng.uniform(0.15, 0.95, n)])
        colours = np.array([colorsys.hsv_to_rgb(*c) for c in hsv]) * 255.0
        patterns = rng.integers(0, len(Texture), n)
        albedo[hit] = np.round(colours[part_of.ravel()]).astype(np.uint8)
        texture[hit] = patterns[part_of.ravel()]
    material = None
    if scene.tri_material is not None:
        material = scene.tri_material.copy()
        material[hit] = -1   # the redrawn albedo shows, not the part's image texture
    return dataclasses.replace(scene, tri_albedo=albedo, tri_texture=texture, tri_material=material)


def _disc_kernel(radius: float) -> np.ndarray:
    r = int(np.ceil(radius))
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    # coverage of each pixel by the disc, 4x4 supersampled: a smooth kernel for a sub-pixel radius
    sub = (np.arange(4) + 0.5) / 4 - 0.5
    cover = np.zeros(x.shape)
    for dy in sub:
        for dx in sub:
            cover += (x + dx) ** 2 + (y + dy) ** 2 <= radius ** 2
    return (cover / cover.sum()).astype(np.float32)


def _response(linear: np.ndarray) -> np.ndarray:
    """The logistic camera response on sRGB-encoded values, rescaled to map 0 -> 0 and 1 -> 1."""
    enc = np.clip(linear, 0.0, 1.0) ** (1 / 2.2)
    lo, hi = (1 / (1 + np.exp(RESPONSE_SLOPE * 0.5)), 1 / (1 + np.exp(-RESPONSE_SLOPE * 0.5)))
    return (1 / (1 + np.exp(-RESPONSE_SLOPE * (enc - 0.5))) - lo) / (hi - lo)


def camera_shift(rgb: np.ndarray, seed: int) -> np.ndarray:
    """(N, H, W, 3) uint8 frames through the fixed camera pipeline of the module docstring,
    frame i seeded by (``seed``, i); returns new (N, H, W, 3) uint8 frames."""
    import cv2

    kernel = _disc_kernel(DEFOCUS_RADIUS_PX)
    out = np.empty_like(rgb)
    for i, frame in enumerate(rgb):
        rng = np.random.default_rng([seed, i])
        linear = (frame.astype(np.float32) / 255.0) ** 2.2
        gains = np.asarray(CAST_GAINS, np.float32) * (1 + rng.uniform(-CAST_JITTER, CAST_JITTER, 3)).astype(np.float32)
        linear = cv2.filter2D(linear * gains, -1, kernel, borderType=cv2.BORDER_REPLICATE)
        std = np.sqrt(READ_NOISE ** 2 + SHOT_NOISE ** 2 * np.clip(linear, 0.0, None))
        linear = linear + rng.standard_normal(linear.shape).astype(np.float32) * std
        img = np.round(_response(linear) * 255.0).astype(np.uint8)
        quality = int(rng.integers(JPEG_QUALITY[0], JPEG_QUALITY[1] + 1))
        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, quality])
        if not ok:
            raise RuntimeError(f"cv2.imencode failed to encode a {img.shape} frame as JPEG")
        out[i] = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1]
    return out
