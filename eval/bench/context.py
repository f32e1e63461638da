"""The shared inputs of every ``calnav bench`` section: one procedural house, one real
trajectory through it, frames rendered once per resolution; and the timing helper."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


@dataclass
class BenchContext:
    """Shared inputs of all bench sections.

    scene_seed: procedural house seed. n_poses: length of the trajectory. quick: smaller runs
    (for tests) -- the numbers are then only indicative.
    """

    scene_seed: int = 7
    n_poses: int = 60
    quick: bool = False
    _frames: dict = field(default_factory=dict)

    @cached_property
    def scene(self):
        from calnav.envs.scenes import load_scene, procedural_scene_id

        return load_scene(procedural_scene_id("val", self.scene_seed))

    @cached_property
    def env_config(self):
        from calnav.envs.config import EnvConfig

        return EnvConfig()

    @cached_property
    def navgrid(self):
        from calnav.envs.navigation import NavGrid

        return NavGrid.build(self.scene, self.env_config)

    @cached_property
    def poses(self) -> list[np.ndarray]:
        """(4, 4) world-from-camera poses along a shortest path between two far-apart points,
        turning in place every few steps to look around (as an exploring agent does)."""
        from calnav.envs.oracle import scan_trajectory

        return scan_trajectory(self.navgrid, self.env_config, n_poses=self.n_poses, seed=self.scene_seed)

    def renderer(self, width: int, height: int):
        from calnav.envs.render import Camera, Renderer

        cfg = self.env_config
        cam = Camera(width=width, height=height, hfov_deg=cfg.hfov_deg)
        return Renderer(self.scene, cam, min_depth_m=cfg.min_depth_m, max_depth_m=cfg.max_depth_m)

    def frames(self, width: int, height: int) -> list:
        """``envs.render.RenderedView`` for every pose, cached per resolution."""
        key = (width, height)
        if key not in self._frames:
            r = self.renderer(width, height)
            self._frames[key] = [r.render(p) for p in self.poses]
        return self._frames[key]


def timeit_ms(fn, repeats: int, warmup: int = 1) -> float:
    """Median wall time of ``fn()`` in milliseconds."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))
