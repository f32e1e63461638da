"""Hand-held scanning trajectories (envs.trajectories)."""
from __future__ import annotations

import numpy as np
import pytest

from calnav.envs.config import EnvConfig
from calnav.envs.navigation import NavGrid
from calnav.envs.scenes import load_scene
from calnav.envs.trajectories import ScanConfig, scan_poses


@pytest.fixture(scope="module")
def house():
    env = EnvConfig()
    scene = load_scene("house_calib_0000")
    return scene, NavGrid.build(scene, env), env


def test_scan_visits_every_room_walks_only_free_floor_and_is_seeded(house):
    scene, grid, env = house
    cfg = ScanConfig(frames=1500)
    poses = scan_poses(scene, grid, env, cfg, seed=3)
    assert poses.shape == (1500, 4, 4)
    xy = poses[:, :2, 3]
    # pauses jitter a few millimetres off the free cells, so test at the walked positions
    assert grid.is_navigable(xy).mean() > 0.97
    visited = [any(r.contains(x, y) for x, y in xy) for r in scene.rooms]
    assert all(visited), f"rooms never entered: {[r.kind for r, v in zip(scene.rooms, visited) if not v]}"
    np.testing.assert_allclose(poses[:, 2, 3], scene.floor_z + env.camera_height_m)
    np.testing.assert_array_equal(poses, scan_poses(scene, grid, env, cfg, seed=3))
    assert not np.array_equal(poses[:200], scan_poses(scene, grid, env, ScanConfig(frames=200), seed=4))


def test_scan_dwell_is_uneven_with_pauses(house):
    scene, grid, env = house
    poses = scan_poses(scene, grid, env, ScanConfig(frames=800, pause_prob=0.1), seed=0)
    step = np.linalg.norm(np.diff(poses[:, :2, 3], axis=0), axis=1)
    heading = np.arctan2(poses[:, 1, 2], poses[:, 0, 2])
    turn = np.abs(np.angle(np.exp(1j * np.diff(heading))))
    paused = (step < 0.03) & (turn < np.deg2rad(3))      # near-identical consecutive frames
    assert paused.mean() > 0.1
    assert step.max() <= ScanConfig().step_m + 0.05 and turn.max() <= np.deg2rad(12 + 3)


def _look_up_runs(poses: np.ndarray) -> list[int]:
    """Lengths of the runs of consecutive frames pitched more than 10 degrees up."""
    up = np.degrees(np.arcsin(np.clip(poses[:, 2, 2], -1, 1))) > 10
    edges = np.flatnonzero(np.diff(np.r_[0, up.astype(int), 0]))
    return list(edges[1::2] - edges[::2])


def test_scan_looks_up_at_the_chosen_share_of_stops(house):
    scene, grid, env = house
    steady = dict(frames=5000, tours=1, pause_prob=0.0, pitch_std_deg=0.0, pitch_deg=-25.0, max_turn_deg=30.0,
                  stop_spacing_m=1.5)
    down = scan_poses(scene, grid, env, ScanConfig(**steady), seed=2)
    assert _look_up_runs(down) == []          # the default never looks up: no ceiling in the scan
    every = scan_poses(scene, grid, env, ScanConfig(**steady, up_turn_prob=1.0, up_pitch_deg=30.0), seed=2)
    runs = _look_up_runs(every)
    assert runs and set(runs) == {12}         # one full turn (12 x 30 degrees) per stop, at +30 degrees
    pitch = np.degrees(np.arcsin(every[:, 2, 2]))
    np.testing.assert_allclose(np.sort(np.unique(pitch.round(6))), [-25.0, 30.0])
    half = _look_up_runs(scan_poses(scene, grid, env, ScanConfig(**steady, up_turn_prob=0.5), seed=2))
    assert 0.2 * len(runs) <= len(half) <= 0.8 * len(runs)


def test_scan_config_rejects_bad_values():
    with pytest.raises(ValueError, match="scan.frames"):
        ScanConfig(frames=0)
    with pytest.raises(ValueError, match="pause_prob"):
        ScanConfig(pause_prob=1.0)
    with pytest.raises(ValueError, match="up_turn_prob"):
        ScanConfig(up_turn_prob=float("nan"))
    with pytest.raises(ValueError, match="up_pitch_deg"):
        ScanConfig(up_pitch_deg=95.0)


def test_plane_length_rounds_as_the_fused_dot_by_hand():
    """(-1, 0.4): 0.16 fused onto 1 (rounded once) is one ulp below the plain sum's rounding, and
    its square root keeps the difference; 3-4-5 is exact either way."""
    import math

    from calnav.envs.trajectories import plane_length

    assert plane_length(np.array([-1.0, 0.4])) == 1.0770329614269007
    assert math.sqrt(1.0 * 1.0 + 0.4 * 0.4) == 1.077032961426901   # the unfused rounding, one ulp above
    assert plane_length(np.array([3.0, 4.0])) == 5.0 and plane_length(np.zeros(2)) == 0.0


KERNEL_PROBE = """
import hashlib
from calnav.envs.config import EnvConfig
from calnav.envs.navigation import NavGrid
from calnav.envs.scenes import load_scene
from calnav.envs.trajectories import ScanConfig, scan_poses
env = EnvConfig()
scene = load_scene("house_calib_0000")
print(hashlib.sha256(scan_poses(scene, NavGrid.build(scene, env), env, ScanConfig(frames=1500), seed=3).tobytes()).hexdigest())
"""


def test_a_scan_walks_the_same_poses_under_every_blas_kernel(house):
    """OpenBLAS picks its kernels by CPU (OPENBLAS_CORETYPE forces one): on an AVX-512 CPU its
    default kernel and Haswell's round a 2-vector's dot product differently, which once gave a
    walk segment one pose more or less and so another scan per kind of CPU. Every kernel walks
    the same poses, to the bit (Prescott's runs on any x86-64 CPU)."""
    import os
    import subprocess
    import sys

    digests = {}
    for core in ("", "Haswell", "Prescott"):
        env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"} | ({"OPENBLAS_CORETYPE": core} if core else {})
        run = subprocess.run([sys.executable, "-c", KERNEL_PROBE], env=env, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr[-2000:]
        digests[core or "default"] = run.stdout.split()[-1]
    assert len(set(digests.values())) == 1, digests
