"""Renderer: analytic depth, depth validity, labels, intrinsics, noise, determinism, speed bench."""
from __future__ import annotations

from functools import cached_property

import numpy as np
import pytest

from calnav.envs.config import EnvConfig
from calnav.envs.primitives import box_room_scene
from calnav.envs.render import Camera, Renderer, camera_pose, look_at_pose
from calnav.envs.semantics import class_id

HFOV = 79.0
CAM_H = 0.88
ROOM_X, ROOM_Y, ROOM_Z = 6.0, 4.0, 2.6  # box_room_scene defaults: inner faces at +-3, +-2, 0, 2.6


@pytest.fixture(scope="module")
def empty_room():
    return box_room_scene(objects=())


@pytest.fixture(scope="module")
def room():
    return box_room_scene()


def pixel_rays(cam: Camera, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Independent pinhole model: world origin (3,) and (H, W, 3) directions with camera z = 1,
    from inv(K) [u, v, 1] for integer pixel indices (u column, v row)."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    pix = np.stack([u, v, np.ones_like(u)], axis=-1)
    d_cam = pix @ np.linalg.inv(cam.intrinsics).T
    return pose[:3, 3], d_cam @ pose[:3, :3].T


def project(cam: Camera, pose: np.ndarray, p_world) -> np.ndarray:
    """(u, v) image coordinates (float) of a world point."""
    p_cam = np.linalg.inv(pose) @ np.append(np.asarray(p_world, dtype=np.float64), 1.0)
    uvw = cam.intrinsics @ p_cam[:3]
    return uvw[:2] / uvw[2]


def analytic_box_depth(cam: Camera, pose: np.ndarray) -> np.ndarray:
    """z-depth to the inside of the axis-aligned empty room, from the camera inside it."""
    o, d = pixel_rays(cam, pose)
    lo = np.array([-ROOM_X / 2, -ROOM_Y / 2, 0.0])
    hi = np.array([ROOM_X / 2, ROOM_Y / 2, ROOM_Z])
    with np.errstate(divide="ignore"):
        t_exit = np.where(d > 0, (hi - o) / d, np.where(d < 0, (lo - o) / d, np.inf))
    return t_exit.min(axis=-1)  # leaving a convex box: the nearest plane crossed; d_cam z = 1


# ---------------------------------------------------------------- conventions
def test_camera_pose_axes():
    p = camera_pose((1.0, 2.0), 0.0, CAM_H)
    np.testing.assert_allclose(p[:3, 2], [1, 0, 0], atol=1e-12)   # forward
    np.testing.assert_allclose(p[:3, 0], [0, -1, 0], atol=1e-12)  # right
    np.testing.assert_allclose(p[:3, 1], [0, 0, -1], atol=1e-12)  # down
    np.testing.assert_allclose(p[:3, 3], [1, 2, CAM_H])
    p = camera_pose((0, 0), np.pi / 2, CAM_H, pitch=np.deg2rad(30))
    np.testing.assert_allclose(p[:3, 2], [0, np.cos(np.pi / 6), 0.5], atol=1e-12)
    np.testing.assert_allclose(p[:3, :3] @ p[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(p[:3, :3]) == pytest.approx(1.0)
    q = look_at_pose((0, 0, 1), (2, 0, 1))
    np.testing.assert_allclose(q, camera_pose((0, 0), 0.0, 1.0), atol=1e-12)


def test_intrinsics_and_config():
    cam = Camera(640, 480, 90.0)
    k = cam.intrinsics
    assert k[0, 0] == pytest.approx(320.0) and k[1, 1] == pytest.approx(320.0)
    assert (k[0, 2], k[1, 2]) == (319.5, 239.5)
    cam = Camera.from_config(EnvConfig(resolution=(320, 240), hfov_deg=HFOV))
    assert (cam.width, cam.height, cam.hfov_deg) == (320, 240, HFOV)


# ---------------------------------------------------------------------- depth
@pytest.mark.parametrize("yaw,pitch", [(0.0, 0.0), (0.7, -0.35), (2.9, 0.4)])
def test_depth_matches_analytic_box(empty_room, yaw, pitch):
    cam = Camera(160, 120, HFOV)
    pose = camera_pose((0.4, -0.3), yaw, CAM_H, pitch)
    frame = Renderer(empty_room, cam, min_depth_m=0.01, max_depth_m=100.0).render(pose)
    expected = analytic_box_depth(cam, pose)
    np.testing.assert_allclose(frame.depth, expected, atol=1e-4)
    assert frame.depth.dtype == np.float32 and frame.depth.shape == (120, 160)


def test_depth_is_z_depth_on_facing_wall(empty_room):
    cam = Camera(64, 48, HFOV)
    frame = Renderer(empty_room, cam, max_depth_m=10.0).render(camera_pose((0.0, 0.0), 0.0, CAM_H))
    wall_rows = slice(18, 30)  # around the image centre every pixel sees the x = +3 wall
    np.testing.assert_allclose(frame.depth[wall_rows, 16:48], 3.0, atol=1e-4)


def test_invalid_depth_is_zero():
    long_room = box_room_scene(size_x=14.0, objects=())
    cam = Camera(64, 48, HFOV)
    r = Renderer(long_room, cam, min_depth_m=0.5, max_depth_m=5.0)
    far = r.render(camera_pose((0.0, 0.0), 0.0, CAM_H))  # far wall 7 m away
    centre = (24, 32)
    assert far.depth[centre] == 0.0 and far.semantic[centre] == class_id("wall")
    assert (far.depth[-1] > 0.5).all()  # the nearby floor stays valid
    assert far.depth.max() <= 5.0 and far.depth[far.depth > 0].min() >= 0.5
    near = r.render(camera_pose((6.7, 0.0), 0.0, CAM_H))  # 0.3 m from the wall
    assert near.depth[centre] == 0.0 and near.semantic[centre] == class_id("wall")
    out = r.render(camera_pose((30.0, 0.0), 0.0, CAM_H))  # outside, looking away: all misses
    assert (out.depth == 0).all() and (out.semantic == -1).all() and (out.instance == -1).all()
    assert (out.rgb == 0).all()


# --------------------------------------------------------------------- labels
def test_semantic_and_instance_of_looked_at_object(room):
    cam = Camera(80, 60, HFOV)
    r = Renderer(room, cam)
    chair = room.instance_ids(class_id("chair"))[0]
    frame = r.render(look_at_pose((-1.0, 1.0, 0.45), (1.5, 1.0, 0.45)))
    assert frame.semantic[30, 40] == class_id("chair")
    assert frame.instance[30, 40] == chair
    assert frame.semantic.dtype == np.int16 and frame.instance.dtype == np.int32
    # every labelled pixel's instance belongs to its class
    inst_class = {i: room.instance_class(i) for i in np.unique(frame.instance)}
    assert all(inst_class[i] == c for i, c in zip(frame.instance.ravel(), frame.semantic.ravel()))


def test_walls_have_distinct_instances(empty_room):
    r = Renderer(empty_room, Camera(32, 24, HFOV))
    seen = {int(r.render(camera_pose((0, 0), yaw, 1.3)).instance[12, 16]) for yaw in np.arange(4) * np.pi / 2}
    walls = set(empty_room.instance_ids(class_id("wall")).tolist())
    assert seen == walls and len(walls) == 4


def test_projected_edges_land_on_predicted_pixels(empty_room):
    """The ceiling/far-wall edge and the left corner, projected with K, fall between the
    rows / columns where the rendered instance map changes (catches half-pixel errors)."""
    cam = Camera(640, 480, HFOV)
    pose = camera_pose((0.0, 0.0), 0.0, CAM_H)
    inst = Renderer(empty_room, cam, max_depth_m=10).render(pose).instance
    far_wall, ceiling = inst[240, 320], inst[0, 320]
    v_edge = project(cam, pose, (3.0, 0.0, ROOM_Z))[1]  # ~16.8
    col = inst[:, 320]
    assert (col[: int(np.floor(v_edge)) + 1] == ceiling).all()
    assert (col[int(np.ceil(v_edge)): 250] == far_wall).all()
    u_edge = project(cam, pose, (3.0, ROOM_Y / 2, 1.0))[0]  # ~60.6; +y is to the left
    row = inst[240]
    assert (row[int(np.ceil(u_edge)): 560] == far_wall).all()  # the -y wall starts at ~578
    assert (row[: int(np.floor(u_edge)) + 1] != far_wall).all()
    # fractional parts > 0.5: a principal point off by +0.5 px (create_rays_pinhole's pixel
    # centre convention fed the OpenCV K) would move both boundaries by one pixel
    assert 0.55 < v_edge % 1 < 0.98 and 0.55 < u_edge % 1 < 0.98


# ------------------------------------------------------------ rgb, noise, misc
def test_rgb_shading_and_texture(room):
    frame = Renderer(room, Camera(160, 120, HFOV)).render(camera_pose((0, 0), np.pi / 2, CAM_H))
    assert frame.rgb.dtype == np.uint8 and frame.rgb.shape == (120, 160, 3)
    wall = frame.rgb[frame.semantic == class_id("wall")].astype(int)
    assert wall.std(axis=0).max() > 3  # the stripes pattern varies
    albedo = np.array([200, 190, 170])
    assert (wall <= albedo).all() and wall.mean() > 0.4 * albedo.mean()  # lit, never brighter


def test_resolution_configurable(room):
    for w, h in ((640, 480), (160, 120), (33, 17)):
        f = Renderer(room, Camera(w, h, HFOV)).render(camera_pose((0, 0), 0.3, CAM_H))
        assert f.rgb.shape == (h, w, 3) and f.depth.shape == f.semantic.shape == f.instance.shape == (h, w)


def test_noise_off_by_default_and_seeded(room):
    cam, pose = Camera(80, 60, HFOV), camera_pose((0.5, 0.2), 1.0, CAM_H)
    clean = Renderer(room, cam).render(pose)
    again = Renderer(room, cam, seed=99).render(pose)
    for a, b in ((clean.rgb, again.rgb), (clean.depth, again.depth)):
        np.testing.assert_array_equal(a, b)
    noisy = [Renderer(room, cam, rgb_noise_std=5.0, depth_noise_std=0.01, seed=s).render(pose) for s in (3, 3, 4)]
    np.testing.assert_array_equal(noisy[0].rgb, noisy[1].rgb)
    np.testing.assert_array_equal(noisy[0].depth, noisy[1].depth)
    assert not np.array_equal(noisy[0].rgb, noisy[2].rgb)
    diff = noisy[0].rgb.astype(float) - clean.rgb
    assert 3.0 < diff.std() < 7.0
    valid = (noisy[0].depth > 0) & (clean.depth > 0)
    rel = noisy[0].depth[valid] / clean.depth[valid] - 1
    assert 0.005 < rel.std() < 0.02
    np.testing.assert_array_equal(noisy[0].semantic, clean.semantic)


def test_thread_count_does_not_change_output(room):
    cam, pose = Camera(400, 300, HFOV), camera_pose((-0.5, 0.5), -0.4, CAM_H, 0.1)
    single, multi = Renderer(room, cam, nthreads=1), Renderer(room, cam, nthreads=2)
    assert len(single._bands) == 1 and len(multi._bands) == 2  # row bands on worker threads
    a, b = single.render(pose, normals=True), multi.render(pose, normals=True)
    for name in ("rgb", "depth", "semantic", "instance", "normal"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    floor = a.semantic == class_id("floor")
    np.testing.assert_allclose(a.normal[floor], np.broadcast_to([0, 0, 1], (floor.sum(), 3)), atol=1e-6)


def test_bad_inputs_raise(room):
    with pytest.raises(ValueError):
        Camera(0, 10, HFOV)
    with pytest.raises(ValueError):
        Renderer(room, Camera(8, 8, HFOV), min_depth_m=2.0, max_depth_m=1.0)
    with pytest.raises(ValueError):
        Renderer(room, Camera(8, 8, HFOV)).render(np.eye(3))


def test_bench_env_section_runs():
    from calnav.eval.bench import env as bench_env
    from calnav.eval.bench.context import BenchContext

    class Ctx(BenchContext):
        @cached_property
        def scene(self):
            return box_room_scene()

        @cached_property
        def poses(self):
            return [camera_pose((0.0, 0.0), yaw, CAM_H) for yaw in np.linspace(0, 2 * np.pi, 6)]

    res = bench_env.run(Ctx(quick=True))
    expected = {"env.render_ms_640x480", "env.raycast_ms_640x480", "env.render_ratio_640x480",
                "env.render_ms_160x120", "env.steps_per_s_640x480", "env.steps_per_s_160x120",
                "env.navgrid_build_ms", "env.geodesic_field_ms", "env.scene_triangles", "env.house_gen_ms"}
    assert expected <= set(res)
    assert all(np.isfinite(v) and v > 0 for v in res.values())
    assert res["env.scene_triangles"] == len(box_room_scene().triangles)
