"""Image textures in the renderer: the texel under each textured hit (``envs.render`` calls it).

A hit's texture coordinates are its triangle's corner coordinates weighted by ``cast_rays``'
barycentric ``primitive_uvs`` (u weighs corner 1, v corner 2, 1 - u - v corner 0); its texel is
the nearest one under glTF's wrap modes (``envs.gltf.wrap_texels``), gathered once per pixel from
every texture packed in one (sum h w, 3) uint8 array; the colour is texel x the triangle's albedo
(its base colour factor, 255 = the texel unchanged). All steps are whole-array numpy passes over
the textured pixels of a row band.
"""
from __future__ import annotations

import numpy as np

from calnav.envs.gltf import wrap_texels
from calnav.envs.scene import Scene


class TextureSampler:
    """Per-scene texture tables: each triangle's texture (-1 none; one extra row for misses) and
    corner coordinates, each texture's first texel, size and wrap modes, and the packed texels."""

    def __init__(self, scene: Scene):
        f = len(scene.triangles)
        self.tri_material = np.append(scene.tri_material, np.int16(-1)).astype(np.int16)   # (F + 1,)
        self.tri_uv = scene.tri_uv.reshape(f, 6)                                           # (F, 6) u0 v0 u1 v1 u2 v2
        sizes = np.array([t.shape[0] * t.shape[1] for t in scene.textures], np.int64)
        self.texel_start = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)    # (T,)
        self.width = np.array([t.shape[1] for t in scene.textures], np.int64)               # (T,)
        self.height = np.array([t.shape[0] for t in scene.textures], np.int64)              # (T,)
        self.wrap = scene.texture_wrap                                                      # (T, 2)
        self.texels = np.concatenate([t.reshape(-1, 3) for t in scene.textures])            # (sum h w, 3) uint8

    def apply(self, rgba: np.ndarray, idx: np.ndarray, bary: np.ndarray) -> None:
        """Replace the colour of textured hits in ``rgba`` ((h, w, 4) uint8 albedo, in place) by
        texel x albedo / 255. idx: (h, w) triangle index (misses: F); bary: (h, w, 2) float32."""
        mat = self.tri_material.take(idx)
        sel = np.flatnonzero(mat >= 0)
        if not len(sel):
            return
        m = mat.ravel()[sel].astype(np.int64)
        corners = self.tri_uv.take(idx.ravel()[sel], axis=0)
        b1, b2 = bary[..., 0].ravel()[sel], bary[..., 1].ravel()[sel]
        b0 = 1.0 - b1 - b2
        u = b0 * corners[:, 0] + b1 * corners[:, 2] + b2 * corners[:, 4]
        v = b0 * corners[:, 1] + b1 * corners[:, 3] + b2 * corners[:, 5]
        w = self.width[m]
        texel = self.texel_start[m] + wrap_texels(v, self.height[m], self.wrap[m, 1]) * w
        texel += wrap_texels(u, w, self.wrap[m, 0])
        flat = rgba.reshape(-1, 4)
        colour = self.texels.take(texel, axis=0).astype(np.uint16)
        colour *= flat[sel, :3]
        colour += 127          # rounds texel x albedo / 255 to nearest: albedo 255 keeps the texel exactly
        colour //= 255
        flat[sel, :3] = colour
