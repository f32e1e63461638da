"""Appearance changes of a segmenter's frames that are not camera augmentation: the
render-level recolouring of training instances (``data.recolour_fraction``) and the fixed
camera shift of evaluation frames (``data.eval_appearance: camera``).

Recolouring: calnav's houses draw each part's colour from a small per-class palette
(``envs.furniture_parts``), which a network learns in place of shape. A ``recolour_fraction``
share of a training house's instances gets every part (its triangles of one albedo) a new
colour, hue uniform, saturation U(0, 0.8), value U(0.15, 0.95), and a procedural pattern drawn
uniformly from ``envs.scene.Texture`` (an image texture the part had is dropped).

A scan's colours are baked per triangle (lighting, blur and the pattern included), so its parts
are not its distinct colours: each scan triangle takes the part of the nearest triangle of the
clean house it was scanned from, and keeps its own shading, the ratio of its luminance to that
part's clean albedo (clipped to [0, ``MAX_SHADING``]), times the part's new colour. The scan
keeps its baked pattern (it cannot be re-patterned without scanning again).

``data.eval_appearance: recolour`` scores a segmenter on held-out houses whose every instance is
recoloured that way (from the evaluation seed's own stream): the same rooms and shapes in colours
the training palette never drew, the content shift a real house is to calnav's houses.

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
MAX_SHADING = 2.0                 # recolouring a scan: largest kept ratio of baked to clean luminance
MIN_LUMA = 8.0                    # recolouring a scan: clean luminance floor (uint8 levels), avoids /0
LUMA = np.array([0.299, 0.587, 0.114])   # Rec. 601 luma weights of R, G, B


def _new_looks(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` parts' new colours, (n, 3) float64 in [0, 255], and patterns, (n,) Texture ids."""
    hsv = np.column_stack([rng.random(n), rng.uniform(0.0, 0.8, n), rng.uniform(0.15, 0.95, n)])
    colours = np.array([colorsys.hsv_to_rgb(*c) for c in hsv]).reshape(n, 3) * 255.0
    return colours, rng.integers(0, len(Texture), n)


def _nearest_source_albedo(scene: Scene, source: Scene, tris: np.ndarray) -> np.ndarray:
    """(len(tris), 3) uint8 albedo of the ``source`` triangle nearest each of ``scene``'s
    triangles ``tris`` (their centroids)."""
    import open3d as o3d

    from calnav.envs.render import build_raycasting_scene

    centroids = scene.vertices[scene.triangles[tris]].mean(axis=1).astype(np.float32)
    prim = build_raycasting_scene(source).compute_closest_points(o3d.core.Tensor(centroids))["primitive_ids"]
    return source.tri_albedo[prim.numpy().astype(np.int64)]


def is_baked(scene: Scene) -> bool:
    """Whether ``scene``'s colours carry their lighting (a scan: ``meta["lighting"] == "baked"``)."""
    from calnav.envs.scanning.scanner import BAKED

    return scene.meta.get("lighting") == BAKED


def recolour_scene(scene: Scene, fraction: float, rng: np.random.Generator, source: Scene | None = None) -> Scene:
    """A copy of ``scene`` whose instances, each with probability ``fraction``, have every part
    (triangles of one instance and one albedo) recoloured and repatterned (module docstring).
    ``source``: the clean house a baked scan (``meta["lighting"] == "baked"``) was made from; a
    scan's parts and shading come from it. The scene itself (perhaps shared by the in-memory
    scene cache) is not changed."""
    import dataclasses

    baked = is_baked(scene)
    if baked and (source is None or is_baked(source)):   # a scene file's scan has no clean house behind it
        raise ValueError(f"recolouring the scan {scene.name!r} needs the clean house it was scanned from (source); "
                         "scans loaded from scene files have none")
    instances = np.unique(scene.tri_instance[scene.tri_instance >= 0])
    chosen = instances[rng.random(len(instances)) < fraction]
    hit = np.flatnonzero(np.isin(scene.tri_instance, chosen))
    albedo, texture = scene.tri_albedo.copy(), scene.tri_texture.copy()
    if len(hit):
        part_albedo = _nearest_source_albedo(scene, source, hit) if baked else scene.tri_albedo[hit]
        parts = np.column_stack([scene.tri_instance[hit], part_albedo.astype(np.int32)])
        _, part_of = np.unique(parts, axis=0, return_inverse=True)
        part_of = part_of.ravel()
        colours, patterns = _new_looks(int(part_of.max()) + 1, rng)
        if baked:   # the triangle's own shading times its part's new colour; the baked pattern stays
            shading = (scene.tri_albedo[hit] @ LUMA) / np.maximum(part_albedo @ LUMA, MIN_LUMA)
            new = colours[part_of] * np.clip(shading, 0.0, MAX_SHADING)[:, None]
            albedo[hit] = np.round(np.clip(new, 0.0, 255.0)).astype(albedo.dtype)
        else:
            albedo[hit] = np.round(colours[part_of]).astype(albedo.dtype)
            texture[hit] = patterns[part_of]
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
