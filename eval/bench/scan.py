"""Bench section ``scan``: the cost of scanned houses (``env.dataset.style: scanned``).

- scan.build_s: ``scan_house`` of the bench house (trajectory, render, sensor model, TSDF,
  marching cubes, decimation, labels), seconds. With --quick a coarse scan (QUICK_SCAN):
  indicative only. scan.frames: its frames; scan.triangles, scan.triangles_per_m2: its mesh.
- scan.render_ms_160x120 / scan.clean_render_ms_160x120: median render of the scanned / clean
  bench house along the same poses, interleaved (so machine load hits both alike), ms;
  scan.render_ratio_160x120 = scanned / clean (target <= 2).
- scan.agent_hz_160x120: the agent section's explore-only loop (``gt`` segmenter) on a scanned
  ``val`` house, steps per second (target >= 15); scan.agent_steps: its steps.
"""
from __future__ import annotations

import time

import numpy as np

from calnav.eval.bench.context import BenchContext

# --quick: a coarse scan that still covers the house (~4 s; the agent loop needs its goals in view)
QUICK_SCAN = dict(frames=600, resolution=(96, 72), voxel_m=0.05, min_weight=1.0, stop_spacing_m=3.0,
                  triangles_per_m2=0.0, min_component_triangles=0)


def run(ctx: BenchContext) -> dict[str, float]:
    from calnav.envs.render import Camera, Renderer
    from calnav.envs.scanning.config import ScanningConfig
    from calnav.envs.scanning.scanner import footprint_m2, scan_house
    from calnav.envs.scenes import procedural_scene_id
    from calnav.envs.scenes import scene_seed as house_seed
    from calnav.eval.bench.agent import agent_loop

    scene_id = procedural_scene_id("val", ctx.scene_seed)
    cfg = ScanningConfig(**QUICK_SCAN) if ctx.quick else ScanningConfig()
    t0 = time.perf_counter()
    scanned = scan_house(ctx.scene, cfg, seed=house_seed(scene_id))
    out = {"scan.build_s": time.perf_counter() - t0, "scan.frames": float(scanned.meta["scan_frames"]),
           "scan.triangles": float(len(scanned.triangles)),
           "scan.triangles_per_m2": len(scanned.triangles) / footprint_m2(ctx.scene)}
    cam = Camera(160, 120, ctx.env_config.hfov_deg)
    clean_r, scan_r = (Renderer(s, cam, ctx.env_config.min_depth_m, ctx.env_config.max_depth_m)
                       for s in (ctx.scene, scanned))
    clean_ms, scan_ms = [], []
    for r in (clean_r, scan_r):
        r.render(ctx.poses[0])   # warm-up: first-touch allocations
    for i in range(12 if ctx.quick else 60):
        pose = ctx.poses[i % len(ctx.poses)]
        for r, acc in ((clean_r, clean_ms), (scan_r, scan_ms)):
            t = time.perf_counter()
            r.render(pose)
            acc.append((time.perf_counter() - t) * 1e3)
    out["scan.render_ms_160x120"] = float(np.median(scan_ms))
    out["scan.clean_render_ms_160x120"] = float(np.median(clean_ms))
    out["scan.render_ratio_160x120"] = out["scan.render_ms_160x120"] / out["scan.clean_render_ms_160x120"]
    # the agent loop on a scanned val house (the scene cache keeps it: made once per setting)
    scan_keys = [f"env.dataset.scanning.{k}={v if not isinstance(v, tuple) else 'x'.join(map(str, v))}"
                 for k, v in (QUICK_SCAN.items() if ctx.quick else ())]
    hz, _, _, steps = agent_loop(ctx, ("env.dataset.style=scanned", "env.dataset.val_scenes=1", *scan_keys))
    out["scan.agent_hz_160x120"], out["scan.agent_steps"] = hz, float(steps)
    return out
