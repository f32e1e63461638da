"""The memory a config implies (``eval.memory``): each part's estimate against what its owner
really allocates, and the preflight's refusal, in one line naming the keys and the estimate,
of a config whose one worker would not fit, before anything is written."""
from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest

import calnav.eval.memory as memory
from calnav.eval.cli import main
from calnav.eval.config import load_config
from calnav.eval.preflight import CHECKS

GIB = 1 << 30
SMALL = ["env.resolution=32x24", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]


def test_map_state_estimate_is_its_arrays():
    from calnav.agent.config import AgentConfig
    from calnav.agent.semantic_map import MapState

    cfg = AgentConfig(map_size_m=6.0, cell_m=0.05)
    state = MapState.empty(np.zeros(2), cfg, 5)
    held = state.channels.nbytes + state.semantic.nbytes + state.sums.nbytes + state.counts.nbytes
    assert MapState.estimate_bytes(cfg, 5) == held


@pytest.mark.parametrize("voxel", [0.05, 0.02])
@pytest.mark.parametrize("tsdf", [False, True])
def test_voxel_map_estimate_covers_its_allocation_and_a_frames_table(voxel, tsdf):
    from calnav.envs.task import camera_pose, pinhole_intrinsics
    from calnav.mapping.config import MappingConfig
    from calnav.mapping.memory import voxel_map_bytes
    from calnav.mapping.voxel_map import SemanticVoxelMap

    w, h, hfov, k = 160, 120, 79.0, 4
    vfov = math.degrees(2 * math.atan(math.tan(math.radians(hfov) / 2) * h / w))
    cfg = MappingConfig(voxel_size_m=voxel, initial_alloc_mb=16)
    allocation = voxel_map_bytes(k, cfg, tsdf=tsdf)
    vm = SemanticVoxelMap(k, cfg, tsdf=tsdf)
    assert vm.memory_bytes(allocated=True) == allocation
    # a frame seeing as far as the map integrates, at several yaws: its table's stamp is the
    # part that grows as 1 / voxel^3
    depth = np.full((h, w), cfg.depth_max_m * 0.999, np.float32)
    depth[h // 2:] = np.linspace(0.5, cfg.depth_max_m * 0.999, h - h // 2, dtype=np.float32)[:, None]
    table = 0
    for yaw in np.radians([0, 20, 45, 70]):
        vm.reset()
        vm._stamp = np.empty(0, np.int32)
        vm.integrate(depth, pinhole_intrinsics(w, h, hfov), camera_pose((0.3, -0.2), yaw, 0.88),
                     logits=np.zeros((h, w, k), np.float32))
        table = max(table, vm._stamp.nbytes)
    extent = memory.frustum_extent_m(hfov, vfov, cfg.depth_max_m)
    estimate = voxel_map_bytes(k, cfg, tsdf=tsdf, frame_extent_m=extent) - allocation
    assert table <= estimate <= 2.5 * table


def test_nav_estimate_covers_the_measured_peak():
    from calnav.envs.config import EnvConfig
    from calnav.envs.navigation import NavGrid, estimate_bytes
    from tests.envs.worlds import warped_floor_house

    scene = warped_floor_house()
    NavGrid.build(scene, EnvConfig())   # compiles the kernels outside the measurement
    cfg = EnvConfig(nav_cell_m=0.02)
    tracemalloc.start()
    try:
        grid = NavGrid.build(scene, cfg)
        grid.geodesic_field(grid.navigable & (grid.islands == 0))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    lo, hi = scene.bounds()
    estimate = estimate_bytes((float(hi[0] - lo[0]), float(hi[1] - lo[1])), cfg.nav_cell_m)
    assert peak <= estimate <= 2 * peak


def test_render_estimate_covers_the_renderers_buffers():
    from calnav.envs.config import EnvConfig
    from calnav.envs.render import Camera, Renderer, estimate_bytes
    from calnav.envs.task import camera_pose
    from tests.envs.worlds import warped_floor_house

    cfg = EnvConfig(resolution=(96, 64), rgb_noise_std=2.0)
    r = Renderer(warped_floor_house(), Camera.from_config(cfg))
    pose = camera_pose((1.0, 1.0), 0.3, 0.88)
    frame = r.render(pose)
    hit = r.raycasting_scene.cast_rays(r.rays(pose))
    held = (sum(a.nbytes for a in r._scratch.values()) + r._rays.nbytes + sum(t.numpy().nbytes for t in hit.values())
            + sum(a.nbytes for a in (frame.rgb, frame.depth, frame.semantic, frame.instance))
            + 3 * frame.depth.nbytes)   # the rgb noise: 3 float32 per pixel
    assert estimate_bytes(96, 64) == held


def test_largest_house_extent_bounds_the_generated_houses():
    from calnav.envs.house import HouseSpec
    from calnav.envs.scenes import load_scene

    long_side, short_side = HouseSpec().max_extent_m()
    for sid in ("house_val_0000", "house_val_0001"):
        lo, hi = load_scene(sid).bounds()
        sides = sorted((float(hi[0] - lo[0]), float(hi[1] - lo[1])), reverse=True)
        assert sides[0] * sides[1] <= long_side * short_side + 1e-6 and sides[0] <= long_side + 1e-6


def test_available_memory_is_the_lower_of_meminfo_and_the_cgroup(tmp_path, monkeypatch):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:  8000000 kB\nMemFree:   1000 kB\nMemAvailable:   4194304 kB\n")
    limit, usage = tmp_path / "memory.max", tmp_path / "memory.current"
    monkeypatch.setattr(memory, "MEMINFO", meminfo)
    monkeypatch.setattr(memory, "CGROUP_FILES", ((limit, usage),))
    assert memory.available_bytes() == 4 * GIB   # no cgroup files
    limit.write_text("max\n")
    usage.write_text(str(GIB))
    assert memory.available_bytes() == 4 * GIB   # no limit
    limit.write_text(str(3 * GIB))
    assert memory.available_bytes() == 2 * GIB
    # inactive file cache counts in the cgroup's usage but is reclaimed on demand
    (tmp_path / "memory.stat").write_text(f"anon 1000\ninactive_file {GIB // 2}\nactive_file 10\n")
    assert memory.available_bytes() == 2 * GIB + GIB // 2


@pytest.mark.parametrize("overrides,keys,estimate", [
    (["agent.cell_m=0.01", "agent.map_size_m=200"],
     "the agent's 2D map of 20000x20000 cells (agent.cell_m=0.01, agent.map_size_m=200) takes 83.1 GiB", "83."),
    (["env.nav_cell_m=0.005"], "the navigation grid of the largest house (20 x 12 m: 3975x2347 cells) "
                               "(env.nav_cell_m=0.005) takes 3.5 GiB", "3."),
    (["mapping.voxel_size_m=0.005"], "the voxel map (its first allocation and a frame's block table) "
                                     "(mapping.voxel_size_m=0.005, mapping.block_resolution=8, "
                                     "mapping.initial_alloc_mb=192) takes 9.7 GiB", "9.9"),
    (["env.resolution=4096x4096", "agent.map_resolution=160x120"],
     "the renderer's buffers at 4096x4096 pixels (env.resolution=4096x4096) takes 1.9 GiB", "2."),
])
def test_a_config_beyond_the_memory_is_refused_naming_its_keys(overrides, keys, estimate):
    cfg = load_config(None, overrides)
    with pytest.raises(ValueError) as err:
        memory.check_memory(cfg, CHECKS, available=GIB)
    text = str(err.value)
    assert text.startswith(f"this config needs about {estimate}") and "of memory per worker process, but " \
        "1.0 GiB is available: " in text and keys in text and "\n" not in text
    memory.check_memory(load_config(None, []), CHECKS, available=GIB)   # the defaults fit in 1 GiB


def test_only_what_the_command_runs_is_counted():
    cfg = load_config(None, ["agent.cell_m=0.01", "agent.map_size_m=200"])
    memory.check_memory(cfg, ("run",), available=GIB)   # scan-houses / check-scene run no agent
    oracle = load_config(None, ["agent.cell_m=0.01", "agent.map_size_m=200", "run.agent=oracle"])
    memory.check_memory(oracle, CHECKS, available=GIB)  # the oracle keeps no map


@pytest.mark.e2e
def test_the_cli_refuses_before_writing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(memory, "available_bytes", lambda: 8 * GIB)
    out = tmp_path / "run"
    assert main(["objectnav", "--episodes", "0:1", "--output", str(out), *SMALL, "agent.cell_m=0.01",
                 "agent.map_size_m=200"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("calnav objectnav: error: this config needs about 83.") \
        and "8.0 GiB is available" in err[0] and "agent.cell_m=0.01, agent.map_size_m=200" in err[0]
    assert not out.exists()
