"""Bench section ``env``: renderer, navigation grid and geodesic speed on the bench scene.

Figures (all measured in this run, on ``ctx.scene``, along ``ctx.poses``):
- env.render_ms_640x480 / env.render_ms_160x120: median ``Renderer.render`` wall time, ms.
- env.raycast_ms_640x480: median bare ``RaycastingScene.cast_rays`` for the very same rays
  and thread count, measured interleaved with the renders (so machine load hits both alike).
- env.render_ratio_640x480 = render_ms / raycast_ms: the cost of everything beyond the cast.
- env.steps_per_s_*: agent steps per second, a step = MOVE_FORWARD (or a turn when blocked,
  and every few steps to look around) on the NavGrid + one render at the new pose.
- env.navgrid_build_ms: ``NavGrid.build`` (the navmesh: rasterising the mesh into the
  heightfield, its filters, the erosion, the islands) plus its geodesic graph.
  env.geodesic_field_ms: one uncached single-goal field. env.episode_check_ms: median
  ``oracle_solves`` (the discrete-action check every generated episode passes) from random
  starts to that goal.
- env.scene_triangles: triangle count of the scene.
- env.house_gen_ms: median ``generate_house`` of a procedural house (default spec; seeds 500,
  501, 502, only 500 with --quick), ms: episode generation builds houses, a cost users pay.
"""
from __future__ import annotations

import itertools
import time

import numpy as np

from calnav.eval.bench.context import BenchContext, timeit_ms

RESOLUTIONS: tuple[tuple[int, int], ...] = ((640, 480), (160, 120))
TURN_EVERY = 4  # the stepping agent turns every this many steps (as an exploring agent does)


def _render_vs_cast(renderer, poses: list[np.ndarray], n: int) -> tuple[float, float]:
    """Median (render ms, bare cast ms) over n poses, each render followed by a bare cast of
    the same rays."""
    render_ms, cast_ms = [], []
    rc = renderer.raycasting_scene
    renderer.render(poses[0])  # warm-up: first-touch allocations
    for i in range(n):
        pose = poses[i % len(poses)]
        t0 = time.perf_counter()
        renderer.render(pose)
        render_ms.append((time.perf_counter() - t0) * 1e3)
        rays = renderer.rays(pose)
        t0 = time.perf_counter()
        rc.cast_rays(rays, nthreads=renderer.nthreads)
        cast_ms.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(render_ms)), float(np.median(cast_ms))


def _step_ms(ctx: BenchContext, renderer, repeats: int) -> float:
    """Median ms of one agent step (move/turn on the NavGrid + render)."""
    from calnav.envs.render import camera_pose

    cfg, grid = ctx.env_config, ctx.navgrid
    rng = np.random.default_rng(ctx.scene_seed)
    state = {"xy": grid.sample_navigable(rng, 1)[0], "yaw": 0.0, "k": 0}
    turn = np.deg2rad(cfg.turn_angle_deg)
    height = grid.floor_z + cfg.camera_height_m

    def step() -> None:
        state["k"] += 1
        moved = False
        if state["k"] % TURN_EVERY:
            state["xy"], moved = grid.move_forward(state["xy"], state["yaw"], cfg.forward_step_m)
        if not moved:
            state["yaw"] += turn
        renderer.render(camera_pose(state["xy"], state["yaw"], height))

    return timeit_ms(step, repeats=repeats, warmup=2)


def run(ctx: BenchContext) -> dict[str, float]:
    from calnav.envs.navigation import NavGrid

    scene, cfg, poses = ctx.scene, ctx.env_config, ctx.poses
    n = 12 if ctx.quick else 60
    out: dict[str, float] = {"env.scene_triangles": float(len(scene.triangles))}
    for w, h in RESOLUTIONS:
        r = ctx.renderer(w, h)
        render_ms, cast_ms = _render_vs_cast(r, poses, n)
        out[f"env.render_ms_{w}x{h}"] = render_ms
        if (w, h) == (640, 480):
            out["env.raycast_ms_640x480"] = cast_ms
            out["env.render_ratio_640x480"] = render_ms / cast_ms
        out[f"env.steps_per_s_{w}x{h}"] = 1e3 / _step_ms(ctx, r, n)

    from calnav.envs.house import generate_house

    seeds = itertools.count(500)   # a new house per repeat
    out["env.house_gen_ms"] = timeit_ms(lambda: generate_house(next(seeds)), repeats=1 if ctx.quick else 3, warmup=0)
    out["env.navgrid_build_ms"] = timeit_ms(lambda: NavGrid.build(scene, cfg).graph,
                                            repeats=1 if ctx.quick else 3, warmup=0)
    grid = ctx.navgrid
    grid.graph  # built once per grid; the field timing is the per-goal cost
    rng = np.random.default_rng(ctx.scene_seed + 1)
    goal = np.zeros(grid.shape, dtype=bool)
    goal[grid.to_cell(grid.sample_navigable(rng, 1)[0])] = True
    out["env.geodesic_field_ms"] = timeit_ms(lambda: grid.geodesic_field(goal, use_cache=False),
                                             repeats=3 if ctx.quick else 10)
    from calnav.envs.oracle import oracle_solves

    field = grid.geodesic_field(goal)
    starts = iter(grid.sample_navigable(rng, 40))
    out["env.episode_check_ms"] = timeit_ms(lambda: oracle_solves(grid, cfg, next(starts), 0.0, field),
                                            repeats=3 if ctx.quick else 10)
    return out
