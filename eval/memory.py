"""The memory a config's run needs, estimated before anything is written or any worker starts
(``eval.preflight`` calls ``check_memory`` for every config a command runs).

A size key within its declared range can still ask for more memory than the machine has: a
1 cm agent map cell over a 200 m map is 4e8 cells. Each estimate comes from the module that
allocates the memory, for what one worker process holds at once:

- the agent's 2D map (``agent.semantic_map.MapState.estimate_bytes``): (map_size_m / cell_m)^2
  cells of 7 + 12 K bytes (peanut agent);
- the voxel map (``mapping.memory.voxel_map_bytes``): Open3D's hashmap as
  allocated up front (``mapping.block_count`` / ``initial_alloc_mb``; it then grows with the
  mapped volume, which no config bounds) and one frame's dense block table over the view
  frustum up to the depth range, which grows as 1 / voxel^3 (the agent's map with ``map_type:
  fused``; ``calnav map`` and the calibration study, without the frame table when the config has
  no camera);
- the navigation grid of the largest procedural house (``envs.house.HouseSpec.max_extent_m``,
  ``envs.navigation.estimate_bytes``): (extent / nav_cell_m)^2 cells; user scenes
  (``env.dataset.scene_dir``) are not opened here, so their grids are not estimated;
- the renderer's buffers at ``env.resolution`` (``envs.render.estimate_bytes``).

Their sum is compared with the memory available now (``MemAvailable`` of ``/proc/meminfo``, or
a cgroup's limit less its usage when that is lower; ``psutil`` where there is no
``/proc``). A run whose one worker would not fit is refused in one line naming the largest
part, the keys that size it and the estimate. Parallel workers each hold their own copy; the
check is per worker, so a run it passes may still need fewer workers (``run.workers``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

GIB = float(1 << 30)
MIB = float(1 << 20)
YAW_SAMPLES = 91   # yaws in [0, 90] degrees tried for the worst axis-aligned extent of a view
MEMINFO = Path("/proc/meminfo")
# cgroup v2, then v1: (limit file, usage file); a limit of "max" or beyond the machine is none
CGROUP_FILES = ((Path("/sys/fs/cgroup/memory.max"), Path("/sys/fs/cgroup/memory.current")),
                (Path("/sys/fs/cgroup/memory/memory.limit_in_bytes"),
                 Path("/sys/fs/cgroup/memory/memory.usage_in_bytes")))


@dataclass(frozen=True)
class Need:
    """One part of a run's memory: what it is, the config keys that size it (``key=value``),
    its estimate in bytes and how to make it smaller."""

    what: str
    keys: tuple[str, ...]
    bytes: int
    advice: str


def size_text(nbytes: float) -> str:
    """``nbytes`` in GiB (or MiB below one GiB), one decimal."""
    return f"{nbytes / GIB:.1f} GiB" if nbytes >= GIB else f"{nbytes / MIB:.1f} MiB"


def frustum_extent_m(hfov_deg: float, vfov_deg: float, depth_m: float) -> tuple[float, float, float]:
    """The largest axis-aligned (x, y, z) extent, metres, of a level camera's view up to z-depth
    ``depth_m``, over every yaw: the bounding box of the camera centre and the far plane's
    corners, turned to the yaw whose horizontal box is largest."""
    half_w = depth_m * math.tan(math.radians(hfov_deg) / 2)
    corners = ((0.0, 0.0), (depth_m, half_w), (depth_m, -half_w))
    best = (0.0, 0.0)
    for i in range(YAW_SAMPLES):
        yaw = math.radians(90.0 * i / (YAW_SAMPLES - 1))
        c, s = math.cos(yaw), math.sin(yaw)
        xs = [c * x - s * y for x, y in corners]
        ys = [s * x + c * y for x, y in corners]
        box = (max(xs) - min(xs), max(ys) - min(ys))
        if box[0] * box[1] > best[0] * best[1]:
            best = box
    return best[0], best[1], 2 * depth_m * math.tan(math.radians(vfov_deg) / 2)


def _camera_extent(env: Any, depth_max_m: float) -> tuple[float, float, float]:
    """``frustum_extent_m`` of the env's camera up to the nearer of its and the map's depth limit."""
    w, h = env.resolution
    hfov = env.hfov_deg
    vfov = math.degrees(2 * math.atan(math.tan(math.radians(hfov) / 2) * h / w))
    return frustum_extent_m(hfov, vfov, min(env.max_depth_m, depth_max_m))


def _voxel_need(mapping: Any, num_classes: int, tsdf: bool, env: Any) -> Need:
    from calnav.mapping.memory import voxel_map_bytes

    extent = _camera_extent(env, mapping.depth_max_m) if env is not None else None
    budget = f"mapping.block_count={mapping.block_count}" if mapping.block_count else \
        f"mapping.initial_alloc_mb={mapping.initial_alloc_mb:g}"
    keys = (f"mapping.voxel_size_m={mapping.voxel_size_m:g}", f"mapping.block_resolution={mapping.block_resolution}",
            budget)
    allocation = voxel_map_bytes(num_classes, mapping, tsdf=tsdf)
    total = voxel_map_bytes(num_classes, mapping, tsdf=tsdf, frame_extent_m=extent)
    advice = (f"use a smaller {budget.split('=')[0]} or mapping.block_resolution" if allocation >= total - allocation
              else "use a larger mapping.voxel_size_m or a shorter depth range (mapping.depth_max_m)")
    return Need("the voxel map (its first allocation" + (" and a frame's block table)" if extent else ")"), keys,
                total, advice)


def config_needs(cfg: Any, checks: tuple[str, ...], num_classes: int | None = None) -> list[Need]:
    """The parts of one worker's memory that ``cfg`` sizes, for the preflight ``checks`` of its
    command (the agent's maps only where the command runs the agent). ``num_classes``: the
    segmenter's K (default: calnav's classes)."""
    from calnav.envs.semantics import NUM_CLASSES

    k = num_classes or NUM_CLASSES
    needs: list[Need] = []
    env = getattr(cfg, "env", None)
    if env is not None:
        from calnav.envs import navigation, render
        from calnav.envs.house import HouseSpec

        w, h = env.resolution
        needs.append(Need(f"the renderer's buffers at {w}x{h} pixels", (f"env.resolution={w}x{h}",),
                          render.estimate_bytes(w, h), "use a smaller env.resolution"))
        if not env.dataset.scene_dir:
            extent = HouseSpec().max_extent_m()
            cells = "x".join(str(math.ceil(side / env.nav_cell_m)) for side in extent)
            needs.append(Need(f"the navigation grid of the largest house ({extent[0]:.0f} x {extent[1]:.0f} m: "
                              f"{cells} cells)", (f"env.nav_cell_m={env.nav_cell_m:g}",),
                              navigation.estimate_bytes(extent, env.nav_cell_m), "use a larger env.nav_cell_m"))
    agent, mapping, run = getattr(cfg, "agent", None), getattr(cfg, "mapping", None), getattr(cfg, "run", None)
    runs_map_agent = agent is not None and "agent" in checks and getattr(run, "agent", "peanut") == "peanut"
    if runs_map_agent:
        from calnav.agent.semantic_map import MapState

        n = agent.map_cells
        needs.append(Need(f"the agent's 2D map of {n}x{n} cells",
                          (f"agent.cell_m={agent.cell_m:g}", f"agent.map_size_m={agent.map_size_m:g}"),
                          MapState.estimate_bytes(agent, k), "use a larger agent.cell_m or a smaller agent.map_size_m"))
        if mapping is not None and agent.map_type == "fused":
            needs.append(_voxel_need(mapping, k, False, env))   # the agent fuses semantics only
    elif mapping is not None and "mapping" in checks and agent is None:   # calnav map, the calibration study
        needs.append(_voxel_need(mapping, k, True, env))
    return needs


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def available_bytes() -> int | None:
    """Memory a new allocation can have now, bytes: ``MemAvailable`` (``psutil`` without
    ``/proc/meminfo``), lowered to a cgroup's limit less its usage; None when unknown."""
    available = None
    try:
        for line in MEMINFO.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                available = int(line.split()[1]) * 1024   # kB
                break
    except (OSError, ValueError, IndexError):
        try:
            import psutil

            available = int(psutil.virtual_memory().available)
        except ImportError:
            available = None
    for limit_file, usage_file in CGROUP_FILES:
        limit, usage = _read_int(limit_file), _read_int(usage_file)
        if usage is not None:   # reclaimable page cache counts in a cgroup's usage, not in what it can give
            usage = max(0, usage - _inactive_file(usage_file.parent))
        if limit is not None and usage is not None and (available is None or limit - usage < available):
            available = max(0, limit - usage)
    return available


def _inactive_file(cgroup_dir: Path) -> int:
    """Bytes of inactive file cache in the cgroup (``memory.stat``'s ``inactive_file``, v1
    ``total_inactive_file``), which the kernel reclaims on demand; 0 when unknown."""
    try:
        for line in (cgroup_dir / "memory.stat").read_text().splitlines():
            key, _, value = line.partition(" ")
            if key in ("inactive_file", "total_inactive_file"):
                return int(value)
    except (OSError, ValueError):
        pass
    return 0


def check_memory(cfg: Any, checks: tuple[str, ...], num_classes: int | None = None,
                 available: int | None = None) -> None:
    """ValueError (one line) when one worker of ``cfg``'s run would need more memory than is
    available (``available`` bytes; default ``available_bytes()``; unknown: no check)."""
    needs = config_needs(cfg, checks, num_classes)
    available = available_bytes() if available is None else available
    total = sum(n.bytes for n in needs)
    if available is None or total <= available:
        return
    top = max(needs, key=lambda n: n.bytes)
    raise ValueError(f"this config needs about {size_text(total)} of memory per worker process, but "
                     f"{size_text(available)} is available: {top.what} ({', '.join(top.keys)}) takes "
                     f"{size_text(top.bytes)}; {top.advice}")
