"""Image textures in the renderer: the texel under each textured hit (``envs.render`` calls it).

A hit's texture coordinates are its triangle's corner coordinates weighted by ``cast_rays``'
barycentric ``primitive_uvs`` (u weighs corner 1, v corner 2, 1 - u - v corner 0); its texel is
the nearest one under glTF's wrap modes (``envs.gltf.wrap_texels``), gathered once per pixel from
every texture packed in one array of RGBX texels (one uint32 each: numpy's gather has a fast
path for 4-byte items); the colour is texel x the triangle's albedo (its base colour factor; a
scene whose textured triangles all have albedo 255 writes the texel as it is). All steps are
whole-array numpy passes over the textured pixels of a row band.
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
        # (F, 8) float32 u0 v0 u1 v1 u2 v2 0 0: 32-byte rows, which numpy's gather copies on its fast path
        self.tri_uv = np.zeros((f, 8), np.float32)
        self.tri_uv[:, :6] = scene.tri_uv.reshape(f, 6)
        sizes = np.array([t.shape[0] * t.shape[1] for t in scene.textures], np.int64)
        self.texel_start = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)    # (T,)
        self.width = np.array([t.shape[1] for t in scene.textures], np.int64)               # (T,)
        self.height = np.array([t.shape[0] for t in scene.textures], np.int64)              # (T,)
        self.wrap = scene.texture_wrap                                                      # (T, 2)
        # an axis whose textures all wrap alike gets that one rule (not three, selected per pixel)
        self.wrap_s = self.wrap[0, 0] if (self.wrap[:, 0] == self.wrap[0, 0]).all() else None
        self.wrap_t = self.wrap[0, 1] if (self.wrap[:, 1] == self.wrap[0, 1]).all() else None
        rgbx = np.zeros((int(sizes.sum()), 4), np.uint8)
        rgbx[:, :3] = np.concatenate([t.reshape(-1, 3) for t in scene.textures])
        self.texels = rgbx.view(np.uint32).ravel()                                          # (sum h w,) RGBX
        textured = scene.tri_material >= 0
        self.untinted = bool((scene.tri_albedo[textured] == 255).all())

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
        wrap_s = self.wrap[m, 0] if self.wrap_s is None else self.wrap_s
        wrap_t = self.wrap[m, 1] if self.wrap_t is None else self.wrap_t
        texel = self.texel_start[m] + wrap_texels(v, self.height[m], wrap_t) * w
        texel += wrap_texels(u, w, wrap_s)
        colour = self.texels.take(texel)
        packed = rgba.view(np.uint32).reshape(-1)   # the frame's RGBA8 albedo, one uint32 per pixel
        if not self.untinted:
            tinted = colour.view(np.uint8).reshape(-1, 4).astype(np.uint16)
            tinted *= packed.take(sel).view(np.uint8).reshape(-1, 4)
            tinted += 127      # rounds texel x albedo / 255 to nearest: albedo 255 keeps the texel exactly
            tinted //= 255
            colour = tinted.astype(np.uint8).view(np.uint32).ravel()
        packed[sel] = colour
