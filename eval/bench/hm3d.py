"""Bench section ``hm3d``: the simulator on a scene of HM3D's size, beside the bench house.

HM3D's scenes hold ~0.5-2 M triangles and baked colour textures; calnav's houses ~2 k faces
and flat colours. The bench house is subdivided (every triangle into four, ``SUBDIVISIONS``
times: 1968 -> ~2 M faces, the same surfaces), written in HM3D v0.2's layout with its baked
texture atlas (``envs.hm3d_write``) and read back as any HM3D scene is
(``envs.scene_files.load_scene_file``), then stepped as ``env`` steps the house, in the same
run, so the ratios hold on any machine.

Figures:
- hm3d.scene_triangles: faces of the HM3D-size scene.
- hm3d.load_s / hm3d.cached_load_s: reading it the first time (GLB parse, textures decoded,
  semantic faces matched) / from calnav's conversion cache, seconds.
- hm3d.navgrid_build_ms: its navmesh (``NavGrid.build``), ms.
- hm3d.steps_per_s_640x480: env steps per second (move + textured render) on it, and
  hm3d.step_ratio_vs_house = its step time / the bench house's step time (1 = no slower).
The agent's own cost per step does not depend on the scene (it sees images of a fixed size):
``agent.*`` holds it.
"""
from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

SUBDIVISIONS = 5         # 4^5 = 1024 faces per house face: ~2 M faces, HM3D's large scenes
QUICK_SUBDIVISIONS = 2   # --quick: ~30 k faces


def subdivide(scene, times: int):
    """``scene`` with every triangle split into four at its edge midpoints, ``times`` times:
    the same surfaces, classes, instances and colours, 4^times as many faces (untextured)."""
    tris = scene.vertices[scene.triangles].astype(np.float32)          # (F, 3, 3) corners
    owner = np.arange(len(tris))
    for _ in range(times):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        tris = np.concatenate([np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
        owner = np.tile(owner, 4)
    faces = np.arange(3 * len(tris), dtype=np.int32).reshape(-1, 3)
    return replace(scene, vertices=tris.reshape(-1, 3), triangles=faces, tri_class=scene.tri_class[owner],
                   tri_instance=scene.tri_instance[owner], tri_albedo=scene.tri_albedo[owner],
                   tri_texture=scene.tri_texture[owner], tri_uv=None, tri_material=None, textures=[],
                   texture_wrap=None, name=f"{scene.name}_x{4 ** times}")


def run(ctx) -> dict[str, float]:
    from calnav.envs.hm3d_write import write_hm3d_scene, write_scene_dataset_config
    from calnav.envs.navigation import NavGrid
    from calnav.envs.scene_files import load_scene_file
    from calnav.eval.bench.env import _step_ms

    big = subdivide(ctx.scene, QUICK_SUBDIVISIONS if ctx.quick else SUBDIVISIONS)
    n = 12 if ctx.quick else 60
    with tempfile.TemporaryDirectory(prefix="calnav-bench-hm3d-") as tmp:
        root = Path(tmp) / "hm3d"
        files = write_hm3d_scene(big, root / "val" / "00000-bench", "bench")
        write_scene_dataset_config(root, name="hm3d")
        t0 = time.perf_counter()
        scene = load_scene_file(files["glb"], root=root)
        load_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        load_scene_file(files["glb"], root=root)
        cached_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    grid = NavGrid.build(scene, ctx.env_config)
    grid_ms = (time.perf_counter() - t0) * 1e3
    house_ms = _step_ms(ctx, ctx.renderer(640, 480), n)
    big_ctx = _SceneContext(ctx, scene, grid)
    big_ms = _step_ms(big_ctx, big_ctx.renderer(640, 480), n)
    return {"hm3d.scene_triangles": float(len(scene.triangles)), "hm3d.load_s": load_s, "hm3d.cached_load_s": cached_s,
            "hm3d.navgrid_build_ms": grid_ms, "hm3d.steps_per_s_640x480": 1e3 / big_ms,
            "hm3d.step_ratio_vs_house": big_ms / house_ms}


class _SceneContext:
    """The bench context's settings on another scene (what ``env._step_ms`` reads)."""

    def __init__(self, ctx, scene, navgrid):
        self.scene_seed, self.env_config, self.navgrid, self._scene = ctx.scene_seed, ctx.env_config, navgrid, scene

    def renderer(self, width: int, height: int):
        from calnav.envs.render import Camera, Renderer

        cfg = self.env_config
        return Renderer(self._scene, Camera(width=width, height=height, hfov_deg=cfg.hfov_deg),
                        min_depth_m=cfg.min_depth_m, max_depth_m=cfg.max_depth_m)
