"""Scanned houses (envs.scanning): the sensor model against hand-computed cases, the
reconstruction of a small room (holes where the trajectory never looked, labels transferred,
determinism), scanned procedural houses through load_scene / NavGrid / episodes, and bad input."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from calnav.envs.config import DatasetConfig, EnvConfig
from calnav.envs.primitives import box_room_scene
from calnav.envs.render import Camera, Renderer, look_at_pose
from calnav.envs.scanning.config import ScanningConfig
from calnav.envs.scanning.quality import scan_quality
from calnav.envs.scanning.scanner import scan_house
from calnav.envs.scanning.sensor import (axial_sigma_m, camera_rgb, incidence_deg, noisy_depth, occlusion_shadow,
                                  quantise_depth)
from calnav.envs.semantics import CLASS_ID, VOID

QUIET = dict(lateral_jitter_px=0.0, axial_noise_m=0.0, axial_noise_quad=0.0, disparity_step_px=0.0,
             random_dropout=0.0, absorb_dropout=0.0, edge_width_px=0, grazing_max_deg=89.9)
# a coarse, fast scanner for the tests (the default one takes ~30 s per house)
# the scanner's core on its own: no lived-in additions, no floor artifacts (test_scan_artifacts.py has those)
BARE = dict(rug_prob=0.0, threshold_prob=0.0, clutter_per_m2=0.0, holes_per_m2=0.0, unlabelled_floor_fraction=0.0,
            floor_warp_m=0.0)
FAST = dict(resolution=(96, 72), voxel_m=0.05, min_weight=1.0, triangles_per_m2=0.0, min_component_triangles=0, **BARE)


def _flat(depth_m: float, shape=(40, 50)):
    """A fronto-parallel wall at ``depth_m``: depth, grey rgb, normals facing the camera, pose, K."""
    h, w = shape
    depth = np.full(shape, depth_m, np.float32)
    rgb = np.full((h, w, 3), 128, np.uint8)
    normals = np.zeros((h, w, 3), np.float32)
    normals[..., 2] = -1.0   # world = camera frame (identity pose): the wall faces the camera
    k = Camera(w, h, 60.0).intrinsics
    return depth, rgb, normals, np.eye(4), k


# ------------------------------------------------------------------ sensor model (hand-computed)
def test_axial_sigma_is_nguyen_2012():
    cfg = ScanningConfig()
    # sigma_z(2 m) = 0.0012 + 0.0019 (2 - 0.4)^2 = 0.0012 + 0.004864
    assert axial_sigma_m(np.array(2.0), cfg) == pytest.approx(0.006064, abs=1e-9)
    assert axial_sigma_m(np.array(0.4), cfg) == pytest.approx(0.0012, abs=1e-12)


def test_disparity_quantisation_hand_case():
    cfg = ScanningConfig()   # B f = 0.075 * 580 = 43.5 px m; step 1/8 px
    # z = 3 m: d = 14.5 px = 116 steps exactly -> 3 m; z = 3.01: d = 14.4518 -> 115.61 -> 116 steps -> 3 m
    assert quantise_depth(np.array([3.0, 3.01]), cfg) == pytest.approx([3.0, 3.0], abs=1e-6)
    # z = 3.02: d = 14.404 px = 115.23 steps -> 115 -> 43.5 / 14.375 = 3.02609 m
    assert quantise_depth(np.array([3.02]), cfg)[0] == pytest.approx(43.5 / 14.375, abs=1e-5)
    # the step grows with z^2: dz = z^2 step / (B f)
    z = np.linspace(1.0, 4.0, 4000)
    steps = np.unique(quantise_depth(z, cfg))
    gap_at_1, gap_at_4 = np.diff(steps)[0], np.diff(steps)[-1]
    assert gap_at_1 == pytest.approx(1.0 ** 2 * 0.125 / 43.5, rel=0.05)
    assert gap_at_4 == pytest.approx(4.0 ** 2 * 0.125 / 43.5, rel=0.05)


def test_axial_noise_has_the_model_std():
    depth, rgb, normals, pose, k = _flat(2.0, (200, 200))
    cfg = ScanningConfig(**{**QUIET, "axial_noise_m": 0.0012, "axial_noise_quad": 0.0019})
    z = noisy_depth(depth, rgb, normals, pose, k, cfg, np.random.default_rng(0))
    assert (z > 0).all()
    assert z.mean() == pytest.approx(2.0, abs=5e-4)
    assert z.std() == pytest.approx(0.006064, rel=0.03)


def test_quiet_sensor_is_exact_and_range_applies():
    depth, rgb, normals, pose, k = _flat(2.0)
    cfg = ScanningConfig(**QUIET)
    np.testing.assert_array_equal(noisy_depth(depth, rgb, normals, pose, k, cfg, np.random.default_rng(0)), depth)
    far = noisy_depth(depth * 3, rgb, normals, pose, k, cfg, np.random.default_rng(0))   # 6 m > max 4 m
    assert not far.any()
    depth[5, 5] = 0.0   # a miss stays a miss
    assert noisy_depth(depth, rgb, normals, pose, k, cfg, np.random.default_rng(0))[5, 5] == 0


def test_grazing_incidence_drops_out():
    depth, rgb, normals, pose, k = _flat(2.0)
    tilt = math.radians(85.0)   # the surface seen at 85 degrees from its normal at the centre
    normals[:] = (math.sin(tilt), 0.0, -math.cos(tilt))
    angle = incidence_deg(normals, pose, k)
    h, w = depth.shape
    assert angle[h // 2, w // 2] == pytest.approx(85.0, abs=1.0)
    z = noisy_depth(depth, rgb, normals, pose, k, ScanningConfig(**{**QUIET, "grazing_max_deg": 78.0}),
                    np.random.default_rng(0))
    assert z[h // 2, w // 2] == 0
    assert (z[angle < 78.0] > 0).all() and not z[angle > 78.0].any()


def test_dark_and_saturated_surfaces_drop_out():
    depth, rgb, normals, pose, k = _flat(2.0)
    rgb[:10] = 5      # dark
    rgb[10:20] = 255  # saturated
    cfg = ScanningConfig(**{**QUIET, "absorb_dropout": 1.0})
    z = noisy_depth(depth, rgb, normals, pose, k, cfg, np.random.default_rng(0))
    assert not z[:20].any() and (z[20:] > 0).all()


def test_occlusion_shadow_is_on_the_far_side():
    z = np.full((5, 8), 3.0, np.float32)
    z[:, :4] = 1.0   # a near object on the left, a far wall on the right
    shadow = occlusion_shadow(z, 0.1, 1)
    assert shadow[:, 4].all() and shadow.sum() == 5          # one pixel wide, far side only
    assert occlusion_shadow(z, 0.1, 2)[:, 4:6].all() and occlusion_shadow(z, 0.1, 2).sum() == 10
    assert not occlusion_shadow(z, 5.0, 1).any()             # a jump under the threshold is no edge


def test_colour_changes_between_frames_but_keeps_the_image():
    rgb = np.random.default_rng(1).integers(30, 220, (40, 50, 3)).astype(np.uint8)
    cfg = ScanningConfig()
    a = camera_rgb(rgb, cfg, np.random.default_rng(1))
    b = camera_rgb(rgb, cfg, np.random.default_rng(2))
    assert a.dtype == np.uint8 and a.shape == rgb.shape
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 3         # exposure / white balance differ
    flat = ScanningConfig(exposure_std_stops=0, white_balance_std=0, blur_max_px=0, rgb_noise_std=0)
    np.testing.assert_array_equal(camera_rgb(rgb, flat, np.random.default_rng(0)), rgb)


# ------------------------------------------------------------------ reconstruction of a small room
@pytest.fixture(scope="module")
def room():
    return box_room_scene()   # 6 x 4 m, chair at (1.5, 1), sofa at (-1.8, -1.2), table at (0.5, -0.5)


def _half_room_poses(n: int = 24) -> np.ndarray:
    """A scan that only ever looks at the room's +x half (from x = 1 m, sweeping across +x)."""
    poses = []
    for i in range(n):
        yaw = math.radians(-60 + 120 * i / (n - 1))
        target = np.array([1.0 + 2.0 * math.cos(yaw), 2.0 * math.sin(yaw), 0.0])
        poses.append(look_at_pose((1.0, 0.0, 1.3), target))
    return np.stack(poses)


@pytest.fixture(scope="module")
def half_scan(room):
    return scan_house(room, ScanningConfig(**FAST), seed=5, poses=_half_room_poses())


def _floor_hit(scene, xy) -> bool:
    import open3d as o3d

    rc = Renderer(scene, Camera(8, 8, 60.0)).raycasting_scene
    rays = np.array([[xy[0], xy[1], 1.0, 0, 0, -1]], np.float32)
    hit = rc.cast_rays(o3d.core.Tensor(rays))
    prim = int(hit["primitive_ids"].numpy()[0])
    return prim < len(scene.tri_class) and scene.tri_class[prim] == CLASS_ID["floor"] \
        and abs(1.0 - float(hit["t_hit"].numpy()[0])) < 0.05


def test_holes_where_the_trajectory_never_looked(half_scan):
    assert _floor_hit(half_scan, (2.2, -1.0)) and _floor_hit(half_scan, (2.6, 0.3))   # looked at
    assert not _floor_hit(half_scan, (-2.5, 0.0)) and not _floor_hit(half_scan, (-1.0, 1.5))   # never seen
    assert half_scan.vertices[:, 0].min() > -1.0


def test_labels_transfer_from_the_clean_room(room, half_scan):
    present = half_scan.classes_present()
    assert {CLASS_ID["floor"], CLASS_ID["wall"], CLASS_ID["chair"]} <= present
    assert CLASS_ID["sofa"] not in present            # behind the scanner the whole time
    chair = half_scan.tri_class == CLASS_ID["chair"]
    centre = half_scan.vertices[half_scan.triangles[chair]].mean(axis=(0, 1))
    assert centre[:2] == pytest.approx((1.5, 1.0), abs=0.2)
    # every instance keeps one class, and it is its clean instance's class
    for inst in half_scan.instance_ids():
        assert half_scan.instance_class(inst) == room.instance_class(inst)
    assert half_scan.meta["lighting"] == "baked" and half_scan.meta["closed_solids"] is False


def test_label_distance_makes_far_vertices_void(room):
    scan = scan_house(room, ScanningConfig(**{**FAST, "label_distance_m": 1e-4}), seed=5, poses=_half_room_poses(6))
    assert (scan.tri_class == VOID).mean() > 0.5   # noisy surfaces lie farther than 0.1 mm from the clean one


def test_scan_is_deterministic_per_seed(room, half_scan):
    again = scan_house(room, ScanningConfig(**FAST), seed=5, poses=_half_room_poses())
    np.testing.assert_array_equal(again.vertices, half_scan.vertices)
    np.testing.assert_array_equal(again.tri_class, half_scan.tri_class)
    np.testing.assert_array_equal(again.tri_albedo, half_scan.tri_albedo)
    other = scan_house(room, ScanningConfig(**FAST), seed=6, poses=_half_room_poses())
    assert other.vertices.shape != again.vertices.shape or not np.array_equal(other.vertices, again.vertices)


def test_quality_figures(room, half_scan):
    q = scan_quality(room, half_scan)
    assert 0.3 < q["floor_missing"] < 0.8       # about half the floor was never looked at
    assert 0 < q["wall_missing"] < 1
    assert q["ceiling_missing"] > 0.9           # the poses look down at the floor: no ceiling
    assert q["median_error_mm"] < 30            # 5 cm voxels: errors of a centimetre or so
    assert q["triangles"] == len(half_scan.triangles)
    clean_q = scan_quality(room, room)
    assert clean_q["floor_missing"] == 0 and clean_q["wall_missing"] == 0 and clean_q["ceiling_missing"] == 0
    assert clean_q["median_error_mm"] < 1e-3


def test_decimation_reaches_the_density(room):
    cfg = ScanningConfig(**{**FAST, "voxel_m": 0.03, "triangles_per_m2": 300.0})
    scan = scan_house(room, cfg, seed=1, poses=_half_room_poses(8))
    assert len(scan.triangles) <= 300 * 6.2 * 4.2 * 1.01   # footprint of the room with its walls


def test_baked_lighting_is_not_shaded_again(room):
    cam = Camera(32, 24, 60.0)
    pose = look_at_pose((0.0, 0.0, 1.3), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))   # straight down at the floor
    plain = dataclasses.replace(room, tri_texture=np.zeros_like(room.tri_texture))
    baked = dataclasses.replace(plain, meta={**room.meta, "lighting": "baked"})
    floor_albedo = room.tri_albedo[room.tri_class == CLASS_ID["floor"]][0]
    lit = Renderer(plain, cam).render(pose).rgb[12, 16]
    raw = Renderer(baked, cam).render(pose).rgb[12, 16]
    np.testing.assert_array_equal(raw, floor_albedo)
    assert (lit <= raw).all() and (lit < raw).any()


# ------------------------------------------------------------------ procedural houses, scanned
def _fast_dataset(**scanning) -> DatasetConfig:
    return DatasetConfig(val_scenes=1, episodes_per_scene=3, style="scanned",
                         scanning=ScanningConfig(**{**FAST, "frames": 600, "stop_spacing_m": 3.0, **scanning}))


@pytest.fixture(scope="module")
def scanned_house():
    from calnav.envs.scenes import clear_scene_lru, load_scene

    clear_scene_lru()
    return load_scene("house_val_0000", _fast_dataset())


def test_load_scene_scanned_is_cached_and_a_normal_scene(scanned_house):
    from calnav.envs.scenes import clear_scene_lru, load_scene, scanned_cache_path

    ds = _fast_dataset()
    assert scanned_house.meta["style"] == "scanned" and scanned_house.name == "house_val_0000"
    from calnav.envs.scene_plausible import check_plausible

    assert check_plausible(scanned_house.vertices, scanned_house.triangles, scanned_house.tri_class) is None
    assert scanned_cache_path("house_val_0000", ds).exists()
    clear_scene_lru()
    again = load_scene("house_val_0000", ds)
    np.testing.assert_array_equal(again.vertices, scanned_house.vertices)
    clean = load_scene("house_val_0000", ds, style="clean")
    assert len(clean.triangles) < len(scanned_house.triangles) and "style" not in clean.meta
    other = _fast_dataset(axial_noise_m=0.002)
    assert scanned_cache_path("house_val_0000", other) != scanned_cache_path("house_val_0000", ds)


def test_scan_and_clean_caches_hold_their_own_style(tmp_path, monkeypatch):
    """Scanning a house first generates its clean twin: each lands at its own cache path (a
    clean house written at the scan's path would be read back as the scan by a concurrent worker)."""
    from calnav.envs.scene import Scene
    from calnav.envs.scenes import clear_scene_lru, load_scene, scanned_cache_path, scene_cache_path

    monkeypatch.setenv("CALNAV_CACHE", str(tmp_path))
    clear_scene_lru()
    ds = _fast_dataset(frames=40)
    load_scene("house_val_0000", ds)
    assert Scene.load(scanned_cache_path("house_val_0000", ds)).meta["style"] == "scanned"
    assert "style" not in Scene.load(scene_cache_path("house_val_0000", ds)).meta
    clear_scene_lru()


def test_scanned_house_navigates_and_makes_habitat_episodes(scanned_house):
    from calnav.envs.episodes import generate_scene_episodes
    from calnav.envs.navigation import NavGrid

    env = EnvConfig(resolution=(64, 48), dataset=_fast_dataset())
    renderer = Renderer(scanned_house, Camera.from_config(env))
    grid = NavGrid.build(scanned_house, env, renderer.raycasting_scene)
    from calnav.envs.scenes import load_scene

    clean = NavGrid.build(load_scene("house_val_0000", env.dataset, style="clean"), env)
    assert grid.navigable.sum() > 0.4 * clean.navigable.sum()   # a coarse, short scan: most of the floor
    episodes = generate_scene_episodes("house_val_0000", scanned_house, grid, renderer.raycasting_scene, env, 3, 0)
    assert len(episodes) == 3
    for ep in episodes:
        assert grid.is_navigable(ep.start_position)               # starts on the scan's navigable floor
        for goal in ep.goals:
            assert len(goal.view_points) and grid.is_navigable(goal.view_points).all()



def test_segmenter_training_frames_mix_in_scans(scanned_house):
    """data.scanned_fraction: that share of a house's training frames comes from its scan (each
    reproduced by rendering the scan at the recorded pose), the clean frames are the ones a
    fraction of 0 draws, and evaluation sets ignore the key (they follow env.dataset.style)."""
    from calnav.envs.scenes import load_scene
    from calnav.eval.segmenter.data import SegDataConfig, cache_path, render_frames

    env = EnvConfig(dataset=dataclasses.replace(_fast_dataset(), style="clean"))
    mixed_cfg = SegDataConfig(resolution=(48, 36), walk_steps=3, keep_sparse_prob=1.0, scanned_fraction=0.5)
    clean_cfg = dataclasses.replace(mixed_cfg, scanned_fraction=0.0)
    mixed = render_frames(env, mixed_cfg, "val", 8, 0, progress=False, rebalance=True)
    clean = render_frames(env, clean_cfg, "val", 8, 0, progress=False, rebalance=True)
    np.testing.assert_array_equal(mixed.rgb[:4], clean.rgb[:4])
    assert not np.array_equal(mixed.rgb[4:], clean.rgb[4:])
    cam = Camera(width=48, height=36, hfov_deg=env.hfov_deg)
    scan = Renderer(scanned_house, cam, min_depth_m=env.min_depth_m, max_depth_m=env.max_depth_m)
    clean_house = Renderer(load_scene("house_val_0000", env.dataset), cam, min_depth_m=env.min_depth_m,
                           max_depth_m=env.max_depth_m)
    for i in range(4, 8):
        frame = scan.render(mixed.poses[i].astype(np.float64))
        assert np.abs(frame.rgb.astype(int) - mixed.rgb[i]).max() <= 1
        assert not np.array_equal(clean_house.render(mixed.poses[i].astype(np.float64)).rgb, mixed.rgb[i])
    assert cache_path(env, mixed_cfg, "val", 8, 0, False, rebalance=True) != \
        cache_path(env, clean_cfg, "val", 8, 0, False, rebalance=True)
    assert cache_path(env, mixed_cfg, "val", 8, 0, False) == cache_path(env, clean_cfg, "val", 8, 0, False)
    with pytest.raises(ValueError, match=r"scanned_fraction must be in \[0, 1\]"):
        SegDataConfig(scanned_fraction=1.5)
    with pytest.raises(ValueError, match="scanned_fraction must be in"):
        SegDataConfig(scanned_fraction=float("nan"))


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("override, message", [
    ("env.dataset.style=photoreal", "valid choices: clean, scanned"),
    ("env.dataset.scanning.axial_noise_m=-0.001", "scanning.axial_noise_m must be in [0, 0.5]"),
    ("env.dataset.scanning.voxel_m=0", "scanning.voxel_m must be in [0.005, 0.2]"),
    ("env.dataset.scanning.voxel_m=.nan", "expected a finite number"),
    ("env.dataset.scanning.max_depth_m=.inf", "expected a finite number"),
    ("env.dataset.scanning.min_depth_m=3 env.dataset.scanning.max_depth_m=2", "min_depth_m < "),
    ("env.dataset.scanning.resolution=8x8", "scanning.resolution must be between"),
    ("env.dataset.scanning.up_turn_prob=1.5", "scanning.up_turn_prob must be in [0, 1]"),
])
def test_bad_scan_settings_are_one_line_errors(override, message):
    from calnav.eval.config import ConfigError, load_config

    with pytest.raises(ConfigError) as err:
        load_config(None, override.split())
    assert message in str(err.value) and "\n" not in str(err.value)


def test_scanned_style_of_a_user_scan_directory_is_refused(tmp_path):
    from calnav.eval.config import ConfigError, load_config
    from calnav.envs.scenes import load_scene

    with pytest.raises(ConfigError, match="already are scans"):
        load_config(None, [f"env.dataset.scene_dir={tmp_path}", "env.dataset.style=scanned"])
    with pytest.raises(ValueError, match="already are scans"):
        load_scene("apartment", DatasetConfig(scene_dir=str(tmp_path)), style="scanned")
    with pytest.raises(ValueError, match="valid styles: clean, scanned"):
        load_scene("house_val_0000", style="mesh")


def test_style_names_match():
    import typing

    from calnav.envs.config import StyleName
    from calnav.envs.scenes import STYLES

    assert typing.get_args(StyleName) == STYLES


@pytest.mark.parametrize("override", ["env.dataset.style=photoreal", "env.dataset.scanning.depth_noise=1",
                                      "env.dataset.scanning.voxel_m=0", "env.dataset.scanning.axial_noise_m=-1"])
def test_objectnav_refuses_bad_scan_settings_before_writing(tmp_path, capsys, override):
    from calnav.eval.cli import main

    out = tmp_path / "run"
    assert main(["objectnav", "--episodes", "1", "--output", str(out), override]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calnav objectnav: error:" in err[0] and not out.exists()


def test_scanned_style_of_a_user_directory_refused_by_the_cli(tmp_path, capsys):
    from calnav.eval.cli import main

    out = tmp_path / "run"
    assert main(["objectnav", "--output", str(out), f"env.dataset.scene_dir={tmp_path}", "env.dataset.style=scanned"]) == 2
    assert "already are scans" in capsys.readouterr().err and not out.exists()
