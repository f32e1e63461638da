"""The ``rosbag`` sequence layout on bags written here from a generated recording: every storage
(ROS 1, ROS 2 sqlite3 / mcap), raw and compressed colour, 16UC1 / 32FC1 / compressedDepth depth,
TF or odometry poses, colour and depth at other rates, a dropped pose; and bad bags."""
from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest

from calnav.mapping.sequences import Sequence
from calnav.mapping.sequences import skips
from tests.rosbag_data import DROPPED, FRAMES, ODOMETRY, bag, bag_config, folder

POSE_ATOL = 1e-12   # the bag's poses: quaternions and a TF product, not the folder's 17-digit text


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    return folder(tmp_path_factory.mktemp("rosbag"))


def _same_frames(a, b, index_map=lambda i: i) -> None:
    """The frames of bag sequence ``b`` equal folder sequence ``a``'s (pixels bit for bit)."""
    fa, fb = list(a.frames()), list(b.frames())
    assert [index_map(f.index) for f in fa] == [f.index for f in fb]
    for x, y in zip(fa, fb):
        np.testing.assert_array_equal(x.rgb, y.rgb)
        np.testing.assert_array_equal(x.depth, y.depth)
        np.testing.assert_array_equal(x.semantic, y.semantic)
        np.testing.assert_allclose(x.pose, y.pose, rtol=0, atol=POSE_ATOL)
    np.testing.assert_array_equal(a.k_color, b.k_color)
    assert (a.color_size, a.depth_size) == (b.color_size, b.depth_size)


@pytest.mark.parametrize("storage,color,depth", [
    ("ros1", "raw", "16UC1"), ("ros1", "jpeg", "compressedDepth"), ("sqlite3", "raw", "32FC1"),
    ("sqlite3", "jpeg", "16UC1"), ("mcap", "raw", "compressedDepth"), ("mcap", "jpeg", "32FC1")])
def test_a_bag_reads_back_the_folders_frames(seq_dir, storage, color, depth):
    """Colour (raw rgb8 = the decoded JPEG, or the JPEG bytes), depth (millimetres, metres or
    compressedDepth) and labels come back bit for bit; poses through TF (a moving base and a
    static mounting) within 1e-12; the frame whose TF sample is missing is skipped and counted."""
    path = bag(seq_dir, f"{storage}_{color}_{depth}", storage=storage, color=color, depth=depth)
    ref, seq = Sequence(seq_dir, "scannet"), Sequence(path, "rosbag", bag_config())
    assert type(seq).__name__ == "RosbagSequence" and seq.layout == "rosbag"
    assert seq.tf_chain == ["camera_color_optical_frame", "camera_link", "base_link", "map"]
    assert seq.skipped == ref.skipped == [DROPPED] and seq.ids == ref.ids
    assert seq.has_semantic and len(seq) == FRAMES - 1
    _same_frames(ref, seq)
    last = seq.ids[-1]   # random access gives what the stream gives
    np.testing.assert_array_equal(seq.read(last).depth, ref.read(last).depth)
    seq.close()


def test_a_ros1_bag_of_the_tf_era_is_read(seq_dir):
    """ROS 1 bags recorded before tf2 (e.g. the TUM RGB-D benchmark's) carry /tf as
    tf/tfMessage, the same fields as tf2_msgs/TFMessage: the same frames and poses."""
    path = bag(seq_dir, "tf_era", tf_type="tf/msg/tfMessage")
    _same_frames(Sequence(seq_dir, "scannet"), Sequence(path, "rosbag", bag_config()))


@pytest.mark.parametrize("storage, suffix", [("sqlite3", ".db3"), ("mcap", ".mcap")])
def test_a_ros2_storage_file_is_read_without_its_directory(seq_dir, storage, suffix):
    bare = next(bag(seq_dir, f"bare_{storage}", storage=storage).glob(f"*{suffix}"))
    _same_frames(Sequence(seq_dir, "scannet"), Sequence(bare, "rosbag", bag_config()))


def test_colour_and_depth_at_other_rates_pair_by_stamp(seq_dir):
    """Depth at twice the frame rate: each colour image takes the depth of its own stamp. Colour
    at twice the rate: the images between frames have no depth within the tolerance and are
    skipped and counted (colour image i of the bag is frame i // 2 of the folder)."""
    ref = Sequence(seq_dir, "scannet")
    fast_depth = Sequence(bag(seq_dir, "fast_depth", extra_depth=True), "rosbag", bag_config())
    _same_frames(ref, fast_depth)
    fast_color = Sequence(bag(seq_dir, "fast_color", storage="mcap", extra_color=True), "rosbag", bag_config())
    no_depth, no_pose = fast_color.skips.by_reason().values()
    assert no_depth == list(range(1, 2 * FRAMES, 2)) and no_pose == [2 * DROPPED]
    assert fast_color.skipped == sorted(no_depth + no_pose)
    assert "6 with no depth image within 0.02 s" in fast_color.skip_summary()
    _same_frames(ref, fast_color, index_map=lambda i: 2 * i)


NO_POSE = skips.no_pose(0.2)


@pytest.mark.parametrize("options, rosbag, ids, reasons", [
    # frames 4 and 5 share a stamp (TF holds two poses there): which image is whose is unknown
    ({"shared_stamp": (5,)}, {}, [0, 1, 3], {DROPPED: NO_POSE, 4: skips.SHARED_STAMP, 5: skips.SHARED_STAMP}),
    # frame 3's messages twice: the repeat (colour image 4) is skipped, the folder's frame 4 is image 5
    ({"repeat": (3,), "storage": "mcap"}, {}, [0, 1, 3, 5, 6], {DROPPED: NO_POSE, 4: skips.REPEATED}),
    # two different depth images at frame 1's stamp: which is frame 1's is unknown
    ({"second_depth": (1,)}, {}, [0, 3, 4, 5], {DROPPED: NO_POSE, 1: skips.AMBIGUOUS_DEPTH}),
    # frame 2's pose a NaN sample between samples 0.18 s apart: skipped, not interpolated across it
    ({"bad_pose": "nan", "period_s": 0.09}, {}, [0, 1, 3, 4, 5], {DROPPED: skips.NON_FINITE_POSE}),
    ({"bad_pose": "nan", "period_s": 0.09, "pose": "odometry", "storage": "sqlite3"}, ODOMETRY, [0, 1, 3, 4, 5],
     {DROPPED: skips.NON_FINITE_POSE}),
])
def test_shared_stamps_repeats_and_nan_poses_are_skipped_with_their_reason(seq_dir, options, rosbag, ids, reasons):
    """One rule for every recording: a frame whose data is not one thing is skipped and counted
    with its reason, never fused with a guess; the frames left are the folder's, bit for bit."""
    name = "_".join(f"{k}{v}" for k, v in options.items()).replace(" ", "").replace(",", "")
    seq = Sequence(bag(seq_dir, name, **options), "rosbag", bag_config(**rosbag))
    assert seq.ids == ids and seq.skips.reasons == reasons and seq.skipped == sorted(reasons)
    ref = Sequence(seq_dir, "scannet")
    assert ref.skips.reasons == {DROPPED: skips.NON_FINITE_POSE}
    if options.get("repeat"):   # the folder's frames after the repeat are one colour image later
        _same_frames(ref, seq, index_map=dict(zip(ref.ids, ids)).get)
    else:   # the folder's frames the bag keeps
        kept = Sequence(seq_dir, "scannet")
        kept.ids = ids
        _same_frames(kept, seq)


def test_sync_tolerance_decides_the_pairing(seq_dir):
    """A colour image halfway between two depth images (75 ms away) pairs with one only when the
    tolerance reaches it; the pose is the depth image's (a wider pose gap bridges the dropped one)."""
    path = bag(seq_dir, "tolerance", extra_color=True)
    assert len(Sequence(path, "rosbag", bag_config()).ids) == FRAMES - 1
    wide = Sequence(path, "rosbag", bag_config(sync_tolerance_s=0.1, pose_max_gap_s=0.4))
    assert wide.ids == list(range(2 * FRAMES)) and wide.skipped == []


@pytest.mark.parametrize("storage, pose", [("sqlite3", "odometry"), ("ros1", "pose_stamped"), ("mcap", "pose_stamped")])
def test_poses_from_a_pose_topic_and_the_camera_extrinsic(seq_dir, storage, pose):
    """nav_msgs/Odometry or geometry_msgs/PoseStamped of the camera: the folder's frames, the
    dropped pose skipped; camera_extrinsic moves the camera along its own axes."""
    path = bag(seq_dir, f"{pose}_{storage}", storage=storage, pose=pose)
    ref = Sequence(seq_dir, "scannet")
    seq = Sequence(path, "rosbag", bag_config(pose_source="topic", pose_topic="/odom"))
    assert seq.skipped == [DROPPED]
    _same_frames(ref, seq)
    shifted = Sequence(path, "rosbag", bag_config(pose_source="topic", pose_topic="/odom",
                                                  camera_extrinsic=(0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0)))
    f0, g0 = next(seq.frames()), next(shifted.frames())   # 0.5 m along the camera's viewing axis
    np.testing.assert_allclose(g0.pose[:3, 3], f0.pose[:3, 3] + 0.5 * f0.pose[:3, 2], atol=1e-12)


def test_depth_in_another_optical_frame_is_refused_unless_declared_registered(seq_dir):
    path = bag(seq_dir, "unregistered", depth_frame="camera_depth_optical_frame")
    with pytest.raises(ValueError, match="depth images .* are in frame 'camera_depth_optical_frame', colour images in "
                                         "'camera_color_optical_frame': calnav maps depth registered to the colour camera"):
        Sequence(path, "rosbag", bag_config())
    assert len(Sequence(path, "rosbag", bag_config(assume_registered=True)).ids) == FRAMES - 1


def test_compressed_topics_are_found_from_the_presets_names(seq_dir):
    """The preset names /camera/color/image_raw; the bag has only .../compressed (and depth only
    .../compressedDepth): those are read. Another driver's preset names topics the bag lacks."""
    path = bag(seq_dir, "compressed", color="jpeg", depth="compressedDepth")
    seq = Sequence(path, "rosbag", bag_config())
    assert seq._color == "/camera/color/image_raw/compressed"
    assert seq._depth == "/camera/aligned_depth_to_color/image_raw/compressedDepth"
    with pytest.raises(ValueError, match=r"has no colour image topic /rgb/image_raw \(sequence.rosbag.color_topic, "
                                         r"preset azure_kinect\); its topics: /camera/aligned_depth_to_color/camera_info "
                                         r"\(sensor_msgs/msg/CameraInfo\), .*/tf_static \(tf2_msgs/msg/TFMessage\)$"):
        Sequence(path, "rosbag", bag_config(preset="azure_kinect"))


def _raises(path, cfg, message: str) -> None:
    with pytest.raises(ValueError) as info:
        Sequence(path, "rosbag", cfg)
    text = str(info.value)
    assert message in text and "\n" not in text, text


def test_bad_bags_are_one_line_errors(seq_dir, tmp_path):
    good = bag(seq_dir, "good")
    _raises(bag(seq_dir, "bad_encoding", depth_encoding="8UC1"), bag_config(),
            "depth topic /camera/aligned_depth_to_color/image_raw: depth encoding '8UC1' is not supported; supported: "
            "raw 16UC1 / mono16 (millimetres) or 32FC1 (metres)")
    _raises(good, bag_config(fixed_frame="odom"), "broken TF chain: no transform path from 'odom' to "
            "'camera_color_optical_frame'; the chain from the camera ends at 'map'")
    # the moving transform names another child: the camera's chain is static up to base_link
    _raises(bag(seq_dir, "static_chain", tf_child="base_footprint"), bag_config(),
            "the TF chain camera_color_optical_frame <- camera_link <- base_link is static (/tf_static only)")
    _raises(bag(seq_dir, "broken_chain", tf_child="base_footprint"), bag_config(fixed_frame="map"),
            "broken TF chain: no transform path from 'map' to 'camera_color_optical_frame'")
    _raises(good, bag_config(camera_frame="camera_ir_frame"), "the camera frame 'camera_ir_frame' is in no transform")
    _raises(good, bag_config(semantic_topic="/labels"), "has no semantic image topic /labels")
    _raises(good, bag_config(color_topic="/tf"), "colour image topic /tf is tf2_msgs/msg/TFMessage; expected "
            "sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage")
    no_poses = bag(seq_dir, "no_poses", drop_poses=(0, 1))
    with pytest.raises(ValueError, match="no frames to read: 2 colour images after frame_stride 1 / max_frames 2, 2 with "
                                         "no pose \\(the pose samples around it"):
        Sequence(no_poses, "rosbag", replace(bag_config(), max_frames=2))
    _raises(tmp_path / "nothing.bag", bag_config(), "rosbag not found")
    (tmp_path / "notes.bag").write_text("not a bag")
    _raises(tmp_path / "notes.bag", bag_config(), "notes.bag is not a readable ROS bag")


@pytest.mark.parametrize("storage", ["ros1", "sqlite3", "mcap"])
def test_a_truncated_bag_is_a_one_line_error(seq_dir, tmp_path, storage):
    path = bag(seq_dir, f"truncate_{storage}", storage=storage)
    copy = tmp_path / path.name
    (shutil.copytree if path.is_dir() else shutil.copy)(path, copy)
    data = next(p for p in [copy, *sorted(copy.glob("*"))] if p.suffix in (".bag", ".db3", ".mcap"))
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    _raises(copy, bag_config(), "is not a readable ROS bag")


def test_config_keys_are_checked_on_load():
    from calnav.mapping.sequences.rosbag_config import RosbagConfig

    with pytest.raises(ValueError, match="unknown rosbag preset 'kinect' for sequence.rosbag.preset; valid choices: "
                                         "realsense, realsense_ros2, azure_kinect, orbbec, zed"):
        RosbagConfig(preset="kinect")
    with pytest.raises(ValueError, match=r"sequence.rosbag.sync_tolerance_s must be in \[0, 1\] seconds, got 2"):
        RosbagConfig(sync_tolerance_s=2)
    with pytest.raises(ValueError, match=r"sequence.rosbag.pose_max_gap_s must be in \(0, 10\] seconds"):
        RosbagConfig(pose_max_gap_s=0.0)
    with pytest.raises(ValueError, match="pose_source=topic needs sequence.rosbag.pose_topic"):
        RosbagConfig(pose_source="topic")
    with pytest.raises(ValueError, match="has norm 2; it must be a unit quaternion"):
        RosbagConfig(camera_extrinsic=(0, 0, 0, 0, 0, 0, 2))
    with pytest.raises(ValueError, match=r"camera_extrinsic x must be in \[-10, 10\] metres"):
        RosbagConfig(camera_extrinsic=(20, 0, 0, 0, 0, 0, 1))
    assert RosbagConfig(preset="zed2").topics().depth == "/zed2/zed_node/depth/depth_registered"
    assert RosbagConfig(preset="zed2", depth_topic="/d").topics().depth == "/d"


def test_without_rosbags_the_layout_names_the_extra(seq_dir, monkeypatch):
    import sys

    path = bag(seq_dir, "no_rosbags")
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)   # as if the [ros] extra were not installed
    _raises(path, bag_config(), 'the rosbag layout needs rosbags: pip install -e ".[ros]"')


def _open_files() -> set[str]:
    import os

    fds = "/proc/self/fd"
    return {os.path.realpath(os.path.join(fds, fd)) for fd in os.listdir(fds)}


def test_checking_a_bags_scale_leaves_no_file_open(seq_dir):
    """The scale check samples frames through the random-access reader; a command that maps
    many bags in one process must not keep one open file per bag afterwards."""
    path = bag(seq_dir, "scale_check")
    seq = Sequence(path, "rosbag", bag_config())
    seq.check_scale(0.1, 10.0, 0.05)
    assert not any(f.startswith(str(path.resolve())) for f in _open_files())
    seq.read(seq.ids[-1])   # random access opens it again, and close() lets it go
    assert any(f.startswith(str(path.resolve())) for f in _open_files())
    seq.close()
    assert not any(f.startswith(str(path.resolve())) for f in _open_files())
