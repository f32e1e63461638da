"""`calnav bench`: speed and memory figures, measured in one run on one scene.

Each section is a module ``eval.bench_<name>`` with ``run(ctx: BenchContext) -> dict[str, float]``;
this file owns the shared context (one procedural house, one real trajectory through it, frames
rendered once per resolution), the table and the flat JSON output (name -> number).
"""
from __future__ import annotations

import importlib
import json
import time
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

SECTIONS: tuple[str, ...] = ("env", "fusion", "segmenter", "agent")


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
        from envs.scenes import load_scene, procedural_scene_id

        return load_scene(procedural_scene_id("val", self.scene_seed))

    @cached_property
    def env_config(self):
        from envs.config import EnvConfig

        return EnvConfig()

    @cached_property
    def navgrid(self):
        from envs.navigation import NavGrid

        return NavGrid.build(self.scene, self.env_config)

    @cached_property
    def poses(self) -> list[np.ndarray]:
        """(4, 4) world-from-camera poses along a shortest path between two far-apart points,
        turning in place every few steps to look around (as an exploring agent does)."""
        from envs.oracle import scan_trajectory

        return scan_trajectory(self.navgrid, self.env_config, n_poses=self.n_poses, seed=self.scene_seed)

    def renderer(self, width: int, height: int):
        from envs.render import Camera, Renderer

        cfg = self.env_config
        cam = Camera(width=width, height=height, hfov_deg=cfg.hfov_deg)
        return Renderer(self.scene, cam, min_depth_m=cfg.min_depth_m, max_depth_m=cfg.max_depth_m)

    def frames(self, width: int, height: int) -> list:
        """Rendered ``envs.render.Frame`` for every pose, cached per resolution."""
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


def run_bench(output: str | Path | None, sections: tuple[str, ...] = SECTIONS, quick: bool = False,
              scene_seed: int = 7) -> dict[str, float]:
    ctx = BenchContext(scene_seed=scene_seed, quick=quick, n_poses=12 if quick else 60)
    results: dict[str, float] = {}
    for name in sections:
        if name not in SECTIONS:
            raise ValueError(f"unknown bench section {name!r}; valid sections: {', '.join(SECTIONS)}")
        module = importlib.import_module(f"eval.bench_{name}")
        t0 = time.perf_counter()
        part = module.run(ctx)
        print(f"[bench] {name}: {len(part)} figures in {time.perf_counter() - t0:.1f} s", flush=True)
        results.update({k: float(v) for k, v in part.items()})
    print(format_table(results))
    if output:
        Path(output).write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")
        print(f"wrote {output}")
    return results


def format_table(results: dict[str, float]) -> str:
    width = max((len(k) for k in results), default=10)
    lines = [f"{'figure':<{width}}  value", f"{'-' * width}  ---------"]
    lines += [f"{k:<{width}}  {v:.4g}" for k, v in results.items()]
    return "\n".join(lines)


def main_bench(args) -> None:
    """`calnav bench`: ``--only`` names comma-separated sections (default: all)."""
    only = tuple(s for s in args.only.split(",") if s) or SECTIONS
    run_bench(args.output, only, quick=args.quick, scene_seed=args.scene_seed)
