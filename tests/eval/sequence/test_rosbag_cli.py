"""`calnav map BAG --layout rosbag` end to end: a recording written as ROS 1 / ROS 2 bags maps to
the folder's map, and bad bags are one line before anything is written."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from calnav.eval.cli import main
from calnav.mapping.sequences import skips
from tests.rosbag_data import DROPPED, ODOMETRY, bag, folder, overrides


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The folder, its labelled mesh, and its map (``gt`` segmenter from the semantic frames)."""
    tmp = tmp_path_factory.mktemp("rosbag_cli")
    seq = folder(tmp)
    ply = next(seq.glob("*.labels.ply"))
    out = tmp / "folder_map"
    assert main(["map", str(seq), "--layout", "scannet", "--segmenter", "gt", "--output", str(out)]) == 0
    return seq, ply, out


def _map(out):
    from calnav.common.npz import load_versioned_npz
    from calnav.eval.sequence.map_cmd import MAP_FORMAT_VERSION

    arrays, _ = load_versioned_npz(out / "map.npz", MAP_FORMAT_VERSION)
    return arrays, json.loads((out / "results.json").read_text())


@pytest.mark.parametrize("options, skipped", [
    ({"storage": "ros1", "color": "raw", "depth": "16UC1"}, [DROPPED]),
    ({"storage": "sqlite3", "color": "jpeg", "depth": "compressedDepth", "extra_depth": True}, [DROPPED]),
    # colour at twice the depth rate: colour image 2i is frame i; the odd ones have no depth
    ({"storage": "mcap", "color": "raw", "depth": "32FC1", "extra_color": True}, [1, 3, 2 * DROPPED, 5, 7, 9, 11]),
])
def test_map_of_a_bag_is_the_map_of_its_folder(recorded, tmp_path, capsys, options, skipped):
    """Same pixels, depth in metres bit for bit, poses within 1e-12 through TF: the fused map is
    bit-identical (voxel centres and probabilities) and scores the same against the mesh."""
    seq, ply, folder_out = recorded
    path = bag(seq, "_".join(str(v) for v in options.values()), **options)
    out = tmp_path / "bag_map"
    assert main(["map", str(path), "--layout", "rosbag", "--segmenter", "gt", "--labels-ply", str(ply),
                 "--output", str(out), f"sequence.label_map={seq / 'label_map.json'}", *overrides()]) == 0
    printed = capsys.readouterr().out
    assert f"5 frames fused ({len(skipped)} skipped: " in printed and "1 with no pose (" in printed, printed
    (want, want_res), (got, got_res) = _map(folder_out), _map(out)
    np.testing.assert_array_equal(got["centres"], want["centres"])
    np.testing.assert_array_equal(got["probs"], want["probs"])
    assert got_res["layout"] == "rosbag" and got_res["frames"] == want_res["frames"] == 5
    assert got_res["skipped_frames"] == skipped
    for key in ("miou", "ece", "tl_ece", "mece", "brier", "voxels", "labelled_voxels"):
        assert got_res[key] == want_res[key], key


@pytest.mark.parametrize("options, rosbag, folder_keys, reasons", [
    # frames 4 and 5 at one stamp (TF two poses there): both skipped; the folder's frames 0-3 are the rest
    ({"shared_stamp": (5,)}, {}, ["sequence.max_frames=4"],
     {skips.no_pose(0.2): [DROPPED], skips.SHARED_STAMP: [4, 5]}),
    # frame 3's messages twice: the repeat is skipped, not fused twice
    ({"repeat": (3,), "storage": "mcap"}, {}, [], {skips.no_pose(0.2): [DROPPED], skips.REPEATED: [4]}),
    # frame 2's odometry a NaN sample, its neighbours 0.18 s apart: skipped as the folder's -inf pose is
    ({"bad_pose": "nan", "period_s": 0.09, "pose": "odometry", "storage": "sqlite3"}, ODOMETRY, [],
     {skips.NON_FINITE_POSE: [DROPPED]}),
])
def test_shared_stamps_repeats_and_nan_poses_map_as_the_folder(recorded, tmp_path, capsys, options, rosbag,
                                                               folder_keys, reasons):
    """The bag's faulty frames are skipped and counted with their reasons (printed, and
    ``skip_reasons`` in results.json); the map is the folder's on the same frames."""
    seq, ply, folder_out = recorded
    if folder_keys:
        folder_out = tmp_path / "folder_map"
        assert main(["map", str(seq), "--layout", "scannet", "--segmenter", "gt", "--output", str(folder_out),
                     *folder_keys]) == 0
    path = bag(seq, "cli_" + "_".join(f"{k}{v}" for k, v in options.items()).replace(" ", "").replace(",", ""),
               **options)
    out = tmp_path / "bag_map"
    capsys.readouterr()
    assert main(["map", str(path), "--layout", "rosbag", "--segmenter", "gt", "--labels-ply", str(ply),
                 "--output", str(out), f"sequence.label_map={seq / 'label_map.json'}", *overrides(**rosbag)]) == 0
    printed = capsys.readouterr().out
    (want, want_res), (got, got_res) = _map(folder_out), _map(out)
    skipped = sorted(i for v in reasons.values() for i in v)
    assert f"{want_res['frames']} frames fused ({len(skipped)} skipped: " in printed, printed
    for reason, frames in reasons.items():
        assert f"{len(frames)} with {reason}" in printed, printed
    assert got_res["skipped_frames"] == skipped and got_res["skip_reasons"] == reasons
    assert got_res["frames"] == want_res["frames"] and got_res["voxels"] == want_res["voxels"]
    np.testing.assert_array_equal(got["centres"], want["centres"])
    np.testing.assert_array_equal(got["probs"], want["probs"])


def test_the_label_map_beside_the_labels_ply_is_used_when_none_is_configured(recorded, tmp_path, capsys):
    """A bag file has no sequence folder: the mesh's raw labels are read through the
    label_map.json beside ``--labels-ply`` (not NYU40's ids); two different ones, beside the mesh
    and in the sequence's directory, are a one-line refusal."""
    seq, ply, folder_out = recorded
    path = bag(seq, "cli_label_map")
    out = tmp_path / "bag_map"
    assert main(["map", str(path), "--layout", "rosbag", "--segmenter", "gt", "--labels-ply", str(ply),
                 "--output", str(out), *overrides()]) == 0
    (_, want), (_, got) = _map(folder_out), _map(out)
    assert got["label_map"] == str(seq / "label_map.json") and got["miou"] == want["miou"] > 0.5
    # a ROS 2 bag directory holding its own, different, label map, and the mesh's beside it
    ros2 = bag(seq, "cli_label_map2", storage="sqlite3")
    (ros2 / "label_map.json").write_text(json.dumps({"1": "wall"}))
    capsys.readouterr()
    _fails(["map", str(ros2), "--layout", "rosbag", "--segmenter", "gt", "--labels-ply", str(ply), *overrides()],
           capsys, f"two different label maps for {ply}: {seq / 'label_map.json'} (beside it) and "
                   f"{ros2 / 'label_map.json'} (in the sequence's directory); set sequence.label_map to the one "
                   "its labels are read through", tmp_path / "ambiguous")


def _fails(args, capsys, message: str, out) -> str:
    assert main([*args, "--output", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not out.exists(), "nothing may be written on bad input"
    return err.strip()


def test_bad_bags_are_one_line_errors_before_anything_is_written(recorded, tmp_path, capsys):
    seq, _, _ = recorded
    good = bag(seq, "cli_good")
    out = tmp_path / "out"
    base = ["map", "--layout", "rosbag", "--segmenter", "gt"]
    _fails([*base, str(good), *overrides(preset="zed")], capsys,
           "has no colour image topic /zed/zed_node/rgb/image_rect_color (sequence.rosbag.color_topic, preset zed); "
           "its topics: /camera/aligned_depth_to_color/camera_info (sensor_msgs/msg/CameraInfo)", out)
    _fails([*base, str(bag(seq, "cli_encoding", depth_encoding="rgb8")), *overrides()], capsys,
           "depth encoding 'rgb8' is not supported", out)
    _fails([*base, str(bag(seq, "cli_chain", tf_child="base_footprint")), *overrides(fixed_frame="map")], capsys,
           "broken TF chain: no transform path from 'map' to 'camera_color_optical_frame'", out)
    truncated = tmp_path / "truncated.bag"
    shutil.copy(good, truncated)
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    _fails([*base, str(truncated), *overrides()], capsys, "truncated.bag is not a readable ROS bag", out)
    _fails([*base, str(good), *overrides(sync_tolerance_s=5)], capsys,
           "sequence.rosbag.sync_tolerance_s must be in [0, 1] seconds, got 5", out)


def test_bench_compares_reading_a_bag_with_the_folder(tmp_path):
    from calnav.eval.bench.sequence import measure_rosbag

    out = measure_rosbag(folder(tmp_path), "40x30", repeats=1)
    bag_ms, folder_ms = out["sequence.rosbag_read_map_ms_40x30"], out["sequence.folder_read_map_ms_40x30"]
    assert bag_ms > 0 and folder_ms > 0 and out["sequence.rosbag_raw_vs_folder"] > 0
    assert out["sequence.rosbag_vs_folder"] == pytest.approx(bag_ms / folder_ms)
