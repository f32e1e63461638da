"""The rosbag layout's parts on hand-made messages: TF interpolation and chains
(``rosbag_tf``), image decoding (``rosbag_images``: encodings, strides, byte order, the
compressed_depth format), and CameraInfo with distortion (``rosbag_camera``)."""
from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calnav.mapping.sequences import SequenceConfig
from calnav.mapping.sequences.rosbag_camera import camera_from_info
from calnav.mapping.sequences.rosbag_images import COMPRESSED, IMAGE, color_rgb, depth_metres, label_ids
from calnav.mapping.sequences.rosbag_tf import AMBIGUOUS, NO_SAMPLES, NON_FINITE, NS, POSE_OK, PoseTrack, TfTree

Z90 = tuple(Rotation.from_euler("z", 90, degrees=True).as_quat())
IDENTITY_Q = (0.0, 0.0, 0.0, 1.0)


def test_a_track_interpolates_linearly_and_by_slerp_between_close_samples():
    # given out of order: sorted by stamp
    track = PoseTrack([NS, 0], [(2.0, 0.0, 0.0), (0.0, 0.0, 0.0)], [Z90, IDENTITY_Q])
    poses, status = track.at(np.array([0, NS // 4, NS, NS + 1, -1]), max_gap_ns=NS)
    assert (status == POSE_OK).tolist() == [True, True, True, False, False]
    np.testing.assert_array_equal(poses[0], np.eye(4))   # a sample's own stamp: the sample as it is
    np.testing.assert_allclose(poses[1][:3, 3], (0.5, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(poses[1][:3, :3], Rotation.from_euler("z", 22.5, degrees=True).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(poses[2][:3, :3], Rotation.from_quat(Z90).as_matrix(), atol=1e-15)
    _, status = track.at(np.array([NS // 4, 0]), max_gap_ns=NS // 2)   # samples 1 s apart: no pose between them
    assert status.tolist() == [NO_SAMPLES, POSE_OK]


def test_a_track_gives_no_pose_at_or_across_samples_that_are_no_rigid_transform():
    """NaN / inf and zero quaternions (a lost tracker): no pose at them, nor interpolated across
    them even when the samples around are close enough to bridge a missing one."""
    track = PoseTrack([0, NS // 10, 2 * NS // 10, 3 * NS // 10], [(0, 0, 0), (np.nan, 0, 0), (0, 0, 0), (1, 0, 0)],
                      [IDENTITY_Q, IDENTITY_Q, (0, 0, 0, 0), IDENTITY_Q])
    assert track.dropped == 2 and track.stamps.tolist() == [0, 3 * NS // 10]
    _, status = track.at(np.array([0, NS // 10, 2 * NS // 10, NS // 20]), max_gap_ns=NS)
    assert status.tolist() == [POSE_OK, NON_FINITE, NON_FINITE, NON_FINITE]
    _, status = PoseTrack([0], [(np.inf, 0, 0)], [IDENTITY_Q]).at(np.array([0]), max_gap_ns=NS)
    assert status.tolist() == [NON_FINITE]
    # a missing sample is bridged (the samples around it within max_gap_ns), a NaN one is not
    _, status = PoseTrack([0, 2 * NS // 10], [(0, 0, 0), (1, 0, 0)], [IDENTITY_Q, IDENTITY_Q]).at(
        np.array([NS // 10]), max_gap_ns=NS)
    assert status.tolist() == [POSE_OK]


def test_a_stamp_with_two_different_samples_is_ambiguous_and_a_repeated_one_is_not():
    """Two different samples at one stamp (two frames stamped alike): no pose at or across it,
    which is right is unknown; the same sample twice (a repeated message) counts once."""
    t = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)]
    track = PoseTrack([0, NS // 10, NS // 10, 2 * NS // 10], t, [IDENTITY_Q] * 4)
    poses, status = track.at(np.array([0, NS // 10, NS // 20, 2 * NS // 10]), max_gap_ns=NS)
    assert status.tolist() == [POSE_OK, AMBIGUOUS, AMBIGUOUS, POSE_OK]
    np.testing.assert_array_equal(poses[1], np.eye(4))
    repeated = PoseTrack([0, NS // 10, NS // 10], [(0, 0, 0), (1, 0, 0), (1, 0, 0)], [IDENTITY_Q] * 3)
    poses, status = repeated.at(np.array([NS // 10, NS // 20]), max_gap_ns=NS)
    assert status.tolist() == [POSE_OK, POSE_OK] and poses[0][0, 3] == 1.0 and poses[1][0, 3] == 0.5


def test_messages_sharing_a_stamp_are_repeats_or_clashes():
    """Same stamp and pixels: a repeat (the first kept); same stamp, other pixels: every message
    of the stamp clashes (none can be told from the others)."""
    from calnav.mapping.sequences.rosbag_sync import digest, stamp_clashes

    a, b = (SimpleNamespace(data=np.full(4, v, np.uint8)) for v in (1, 2))
    repeat, shared = stamp_clashes([0, 5, 5, 9, 9, 9, 12], [digest(m) for m in (a, a, a, a, b, a, b)])
    assert repeat.tolist() == [False, False, True, False, False, False, False]
    assert shared.tolist() == [False, False, False, True, True, True, False]
    assert not any(stamp_clashes([0, 1, 2], [1, 1, 1])[0])


def test_the_tf_chain_composes_parent_transforms_from_the_fixed_frame_down():
    """map -> base (moving along x, turned 90 deg), base -> cam (static: 1 m ahead of the base,
    turned 90 deg more): the camera sits at base + R_z90 (1, 0, 0) = base + (0, 1, 0) in map,
    turned 180 deg."""
    static = [("base", "cam", 0, (1.0, 0.0, 0.0), Z90)]
    moving = [("/map", "base", 0, (0.0, 0.0, 0.0), Z90), ("map", "base", NS, (2.0, 0.0, 0.0), Z90)]
    tree = TfTree.from_transforms(static, moving)
    path = tree.chain("cam")   # the root above the camera ('/map' named as tf2 does: 'map')
    assert path == ["cam", "base", "map"] and tree.chain("cam", "base") == ["cam", "base"]
    poses, status = tree.poses(path, np.array([NS // 2]), max_gap_ns=NS)
    assert (status == POSE_OK).all()
    np.testing.assert_allclose(poses[0][:3, 3], (1.0, 1.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(poses[0][:3, :3], Rotation.from_euler("z", 180, degrees=True).as_matrix(), atol=1e-12)
    with pytest.raises(ValueError, match="broken TF chain: no transform path from 'odom' to 'cam'; the chain from the "
                                         "camera ends at 'map' \\(cam <- base <- map\\)"):
        tree.chain("cam", "odom")


def test_a_tf_tree_with_two_parents_or_a_cycle_is_refused():
    with pytest.raises(ValueError, match="TF frame 'cam' has two parents: 'base' \\(/tf_static\\) and 'arm' \\(/tf\\)"):
        TfTree.from_transforms([("base", "cam", 0, (0, 0, 0), IDENTITY_Q)], [("arm", "cam", 0, (0, 0, 0), IDENTITY_Q)])
    with pytest.raises(ValueError, match="'cam' is published on both /tf_static and /tf"):
        TfTree.from_transforms([("base", "cam", 0, (0, 0, 0), IDENTITY_Q)], [("base", "cam", 0, (0, 0, 0), IDENTITY_Q)])
    loop = TfTree.from_transforms([("a", "b", 0, (0, 0, 0), IDENTITY_Q), ("b", "a", 0, (0, 0, 0), IDENTITY_Q)], [])
    with pytest.raises(ValueError, match="the TF tree has a cycle: b <- a <- b"):
        loop.chain("b")


def _raw(encoding: str, px: np.ndarray, pad: int = 0, big_endian: bool = False):
    """A sensor_msgs/Image of ``px`` with ``pad`` bytes after each row."""
    h, w = px.shape[:2]
    rows = px.astype(px.dtype.newbyteorder(">" if big_endian else "<")).view(np.uint8).reshape(h, -1)
    data = np.concatenate([rows, np.full((h, pad), 7, np.uint8)], axis=1).reshape(-1)
    return SimpleNamespace(encoding=encoding, height=h, width=w, step=rows.shape[1] + pad,
                           is_bigendian=int(big_endian), data=data)


def test_raw_images_honour_step_byte_order_and_channel_order():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (5, 7, 3), dtype=np.uint8)
    np.testing.assert_array_equal(color_rgb(_raw("rgb8", rgb, pad=3), IMAGE), rgb)
    np.testing.assert_array_equal(color_rgb(_raw("bgr8", rgb[..., ::-1].copy()), IMAGE), rgb)
    bgra = np.concatenate([rgb[..., ::-1], np.full((5, 7, 1), 255, np.uint8)], axis=2)
    np.testing.assert_array_equal(color_rgb(_raw("bgra8", bgra, pad=1), IMAGE), rgb)
    gray = rgb[..., 0].copy()
    np.testing.assert_array_equal(color_rgb(_raw("mono8", gray), IMAGE), np.repeat(gray[..., None], 3, axis=2))
    mm = rng.integers(0, 5000, (5, 7)).astype(np.uint16)
    mm[0, 0], mm[0, 1] = 0, 65535   # 0 and invalid_depth_raw: invalid
    want = mm.astype(np.float32) * np.float32(1 / 1000)
    want[0, :2] = 0
    for big in (False, True):
        np.testing.assert_array_equal(depth_metres(_raw("16UC1", mm, pad=2, big_endian=big), IMAGE, SequenceConfig()), want)
    metres = want.copy()
    metres[1, 1], metres[1, 2] = np.nan, -1.0   # NaN and <= 0: invalid
    got = depth_metres(_raw("32FC1", metres, big_endian=True), IMAGE, SequenceConfig())
    assert got[1, 1] == 0 and got[1, 2] == 0 and np.array_equal(np.delete(got.ravel(), [8, 9]), np.delete(want.ravel(), [8, 9]))
    np.testing.assert_array_equal(label_ids(_raw("mono16", mm), IMAGE), mm.astype(np.int64) - 1)
    with pytest.raises(ValueError, match="colour encoding 'bayer_rggb8' is not supported; supported: raw rgb8"):
        color_rgb(_raw("bayer_rggb8", gray), IMAGE)
    with pytest.raises(ValueError, match="truncated message"):
        color_rgb(SimpleNamespace(**{**vars(_raw("rgb8", rgb)), "data": np.zeros(10, np.uint8)}), IMAGE)


def _compressed_depth(fmt: str, png_pixels: np.ndarray, quant=(0.0, 0.0)):
    header = np.array([0], "<i4").tobytes() + np.array(quant, "<f4").tobytes()
    ok, png = cv2.imencode(".png", png_pixels)
    assert ok
    return SimpleNamespace(format=fmt, data=np.frombuffer(header + png.tobytes(), np.uint8))


def test_compressed_depth_is_read_as_compressed_depth_image_transport_writes_it():
    """16UC1: the PNG holds millimetres. 32FC1: inverse depth quantised as codec.cpp does
    (depthQuantA = z0 (z0 + 1), depthQuantB = 1 - A / depth_max; v = A / depth + B)."""
    mm = np.array([[0, 500, 1234], [4000, 65535, 9]], np.uint16)
    got = depth_metres(_compressed_depth("16UC1; compressedDepth png", mm), COMPRESSED, SequenceConfig())
    np.testing.assert_array_equal(got, depth_metres(_raw("16UC1", mm), IMAGE, SequenceConfig()))
    z0, depth_max = 100.0, 10.0   # the plugin's defaults: depth_quantization 100, depth_max 10 m
    a, b = np.float32(z0 * (z0 + 1.0)), np.float32(1.0 - z0 * (z0 + 1.0) / depth_max)
    metres = np.array([[0.3, 1.0, 2.5], [7.9, 12.0, np.nan]], np.float32)
    v = np.where(metres < depth_max, a / metres + b, 0).astype(np.uint16)   # NaN / beyond depth_max: 0
    got = depth_metres(_compressed_depth("32FC1; compressedDepth png", v, (a, b)), COMPRESSED, SequenceConfig())
    valid = metres < depth_max
    np.testing.assert_allclose(got[valid], metres[valid], rtol=1e-3)   # quantised: 1 step of A / v
    assert (got[~valid] == 0).all()
    with pytest.raises(ValueError, match="compressedDepth format '16UC1; compressedDepth rvl' is not supported"):
        depth_metres(_compressed_depth("16UC1; compressedDepth rvl", mm), COMPRESSED, SequenceConfig())
    jpeg = SimpleNamespace(format="jpeg", data=np.frombuffer(cv2.imencode(".jpg", np.zeros((4, 4, 3), np.uint8))[1], np.uint8))
    with pytest.raises(ValueError, match="compressed depth 'jpeg' decodes to uint8"):
        depth_metres(jpeg, COMPRESSED, SequenceConfig())


def _info(k: np.ndarray, size, d=(), model="plumb_bob", ros1=False):
    fields = {"k": k.reshape(-1), "d": np.array(d, np.float64)}
    if ros1:
        fields = {name.upper(): v for name, v in fields.items()}
    return SimpleNamespace(width=size[0], height=size[1], distortion_model=model, **fields)


def test_camera_info_with_distortion_undistorts_onto_its_k():
    """An image distorted with D comes back onto the pinhole K (bilinear: within a few levels on
    a smooth pattern away from the border); D all zero leaves images as they are; ROS 1 spells
    the fields K and D."""
    w, h = 160, 120
    k = np.array([[120.0, 0, 79.5], [0, 120.0, 59.5], [0, 0, 1]])
    d = (-0.2, 0.05, 0.001, -0.001, 0.0)
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    pinhole = (127 + 60 * np.sin(u / 9.0) * np.cos(v / 7.0)).astype(np.uint8)
    # the distorted image: its pixel (u, v) sees the pinhole point undistortPoints(u, v)
    pts = cv2.undistortPoints(np.stack([u.ravel(), v.ravel()], 1)[:, None, :], k, np.array(d), P=k)[:, 0]
    distorted = cv2.remap(pinhole, pts[:, 0].reshape(h, w), pts[:, 1].reshape(h, w), cv2.INTER_LINEAR)
    cam = camera_from_info(_info(k, (w, h), d, ros1=True), (w, h))
    back = cam.undistort(distorted, nearest=False).astype(float)
    inner = (slice(20, h - 20), slice(20, w - 20))
    assert np.abs(back[inner] - pinhole[inner]).mean() < 2.0
    plain = camera_from_info(_info(k, (w, h)), (w, h))
    assert plain.undistort(distorted, nearest=False) is distorted
    labels = np.full((h, w), 3, np.int64)
    labels[:, :5] = -1
    assert set(np.unique(cam.undistort(labels, nearest=True))) <= {-1, 3}   # nearest: no blended ids
    with pytest.raises(ValueError, match="distortion model 'fov' with D = .* is not supported"):
        camera_from_info(_info(k, (w, h), (0.1,), model="fov"), (w, h))
    with pytest.raises(ValueError, match="it is for 160x120 images, the images are 320x240"):
        camera_from_info(_info(k, (w, h)), (320, 240))
