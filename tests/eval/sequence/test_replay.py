"""``calnav replay``: an episode of the agent on calnav's env, recorded as a ROS bag (its frames,
labels and camera poses), replayed open loop, takes the episode's decisions at every frame;
the same frames in ScanNet layout replay too; bad inputs are one line and nothing is written."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from calnav.eval.cli import main
from calnav.eval.config import agent_setup

SEMANTIC_TOPIC = "/camera/semantic/image_raw"
# the episode's config; the replay takes the same keys but the sensor's, which the bag sets
SENSOR = ["env.resolution=160x120"]
AGENT = ["env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=6", "env.max_episode_steps=200",
         "agent.map_size_m=24", "mapping.initial_alloc_mb=32", "agent.map_resolution=80x60"]
BAG_KEYS = [f"sequence.rosbag.semantic_topic={SEMANTIC_TOPIC}"]


def write_episode_bag(frames: list[dict], path):
    """``frames`` (the env's observations: rgb, depth, semantic, camera_pose, camera_intrinsics)
    as a ROS 1 bag, as a robot records it (``mapping.sequences.rosbag_write``'s messages, TF
    tree and RealSense topics): rgb8 colour, 32FC1 depth in metres (the observation's floats,
    bit for bit), 16UC1 labels (class id + 1), the camera pose on ``map -> base_link`` (``/tf``)
    under the mounting (``/tf_static``), a frame every 0.15 s."""
    from scipy.spatial.transform import Rotation

    from calnav.mapping.sequences import rosbag_write as rw
    from calnav.mapping.sequences.rosbag_config import ROSBAG_PRESETS
    from calnav.mapping.sequences.rosbag_tf import NS

    writer, store, ros1 = rw.open_writer(path, "ros1")
    writer.open()
    bag, topics = rw.BagWriter(writer, store, ros1), ROSBAG_PRESETS.get("realsense")
    unmount, period, t0 = np.linalg.inv(rw.mount_matrix()), int(0.15 * NS), rw.START_NS
    h, w = frames[0]["depth"].shape[:2]
    try:
        bag.tf("/tf_static", t0, [bag.transform(t0, "base_link", "camera_link", *rw.MOUNT),
                                  bag.transform(t0, "camera_link", rw.OPTICAL_FRAME, (0.0, 0.0, 0.0), rw.OPTICAL_QUAT)])
        for topic in (topics.color_info, topics.depth_info):
            bag.write(topic, "sensor_msgs/msg/CameraInfo", t0,
                      bag.camera_info(t0, rw.OPTICAL_FRAME, frames[0]["camera_intrinsics"], (w, h), ()))
        for n, f in enumerate(frames):
            stamp = t0 + n * period
            log = stamp + rw.LATENCY_NS
            base = f["camera_pose"] @ unmount
            bag.tf("/tf", stamp, [bag.transform(stamp, "map", "base_link", base[:3, 3],
                                                Rotation.from_matrix(base[:3, :3]).as_quat())])
            for topic, encoding, px in ((topics.color, "rgb8", f["rgb"]),
                                        (topics.depth, "32FC1", f["depth"][..., 0].astype(np.float32)),
                                        (SEMANTIC_TOPIC, "16UC1", (f["semantic"].astype(np.int32) + 1).astype(np.uint16))):
                bag.write(topic, "sensor_msgs/msg/Image", log, bag.image(stamp, rw.OPTICAL_FRAME, encoding, px))
    finally:
        writer.close()
    return path


@pytest.fixture(scope="module")
def episode(tmp_path_factory):
    """The agent's episode on calnav's env through the library (the same actions as calnav
    objectnav: tests/agent/test_library.py): its decisions and the frames it saw, as a bag."""
    import gymnasium as gym

    from calnav import envs
    from calnav.agent.navigator import Navigator
    from calnav.eval.config import load_config

    cfg = load_config(None, [*SENSOR, *AGENT])
    env = gym.make(envs.ENV_ID, split="val", config=cfg.env)
    index = int(np.argmin([ep.geodesic_distance for ep in env.unwrapped.episodes]))
    goal = env.unwrapped.episodes[index].object_category
    nav = Navigator(agent_setup(cfg))
    obs, _ = env.reset(options={"episode_index": index})
    nav.reset(goal)
    frames, decisions, done = [], [], False
    while not done:
        decisions.append(nav.act(obs["rgb"], obs["depth"], gps=obs["gps"], compass=obs["compass"],
                                 semantic=obs["semantic"]))
        frames.append(obs)
        obs, _, terminated, truncated, _ = env.step(decisions[-1].action)
        done = terminated or truncated
    tmp = tmp_path_factory.mktemp("replay")
    return goal, frames, decisions, nav.map(), write_episode_bag(frames, tmp / "episode.bag"), tmp


def _xy(p):
    return None if p is None else [round(p[0], 4), round(p[1], 4)]


def _frames(out) -> list[dict]:
    return [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines()]


def test_replaying_the_agents_own_episode_takes_its_decisions(episode, tmp_path, capsys):
    """Open loop on the frames the agent saw (from the bag: pixels, depth, labels, TF poses):
    the episode's action, mode, long- and short-term goal, goal component and position at every
    frame, its STOP, and its map; with --rerun, a recording."""
    pytest.importorskip("rerun")
    from calnav.agent.navigator_map import AgentMap
    from calnav.common.rerun_io import check_recording

    goal, frames, decisions, want_map, bag, _ = episode
    out = tmp_path / "replay"
    assert main(["replay", str(bag), "--goal", goal, "--segmenter", "gt", "--output", str(out), "--rerun",
                 *AGENT, *BAG_KEYS]) == 0
    printed = capsys.readouterr().out
    records = _frames(out)
    assert [r["frame"] for r in records] == list(range(len(frames)))
    for r, d in zip(records, decisions):
        assert (r["action_id"], r["action"], r["mode"], r["step"]) == (int(d.action), d.action.name, d.mode, d.step)
        assert (r["long_term_goal"], r["short_term_goal"]) == (_xy(d.long_term_goal), _xy(d.short_term_goal)), r["frame"]
        assert (r["x"], r["y"]) == tuple(_xy(d.position)) and r["yaw"] == round(d.yaw, 4)
        assert (r["goal"] is None) == (d.goal is None)
        if d.goal is not None:
            assert (r["goal"]["accepted"], r["goal"]["peak"], r["goal"]["centre"]) == \
                (d.goal.accepted, round(d.goal.peak, 4), _xy(d.goal.centre))
    modes = {r["mode"] for r in records}
    assert {"spin", "explore", "goal", "stop"} <= modes and records[-1]["action"] == "STOP"
    seen = [r for r in records if goal in {d["class"] for d in r["detections"]}]
    assert seen and all(r["goal_frame_confidence"] > 0.5 for r in seen)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == len(frames) and summary["stop_frames"] == [len(frames) - 1]
    assert summary["first_stop"]["x"] == records[-1]["x"] and summary["goal"] == goal
    assert summary["goal_first_accepted"]["frame"] == next(i for i, d in enumerate(decisions)
                                                            if d.goal is not None and d.goal.accepted)
    assert summary["sensor"] == {"resolution": [160, 120], "hfov_deg": 79.0} and summary["notes"] == []
    assert f"{len(frames)} frames replayed" in printed and f"would STOP at frame {len(frames) - 1}" in printed
    got = AgentMap.load(out / "map.npz")
    for field in ("origin", "channels", "semantic", "voxel_centres", "voxel_probs"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want_map, field), err_msg=field)
    check_recording(out / "replay.rrd")
    import yaml

    cfg = yaml.safe_load((out / "config.yaml").read_text())
    assert cfg["env"]["resolution"] == [160, 120] and cfg["env"]["normalize_depth"] is False
    assert cfg["agent"]["segmenter"] == "gt" and (out / "inputs.json").is_file()


def test_a_scannet_folder_replays_and_notes_what_the_model_misses(episode, tmp_path, capsys):
    """The same frames in ScanNet layout (depth in mm) replay through the folder reader: a
    record per frame, the sensor from its intrinsics; what the agent's sensor model misses is
    noted: a principal point 2 px off centre, a camera height other than env.camera_height_m."""
    from calnav.eval.sequence.export import ScanNetWriter

    goal, frames, _, _, _, _ = episode
    root = tmp_path / "scan"
    k = frames[0]["camera_intrinsics"].copy()
    k[0, 2] += 2.0
    writer = ScanNetWriter(root, k, k)
    for i, f in enumerate(frames):
        writer.write(i, f["rgb"], f["depth"][..., 0], f["camera_pose"], f["semantic"].astype(np.int64))
    out = tmp_path / "out"
    assert main(["replay", str(root), "--layout", "scannet", "--goal", goal, "--segmenter", "gt", "--output", str(out),
                 *AGENT, "env.camera_height_m=1.2"]) == 0
    assert len(_frames(out)) == len(frames)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["layout"] == "scannet" and summary["sensor"]["hfov_deg"] == 79.0
    assert len(summary["notes"]) == 2 and "differs from the agent's pinhole model (f 97.0, cx 79.5, cy 59.5) by " \
        "up to 2.0 px" in summary["notes"][0] and "env.camera_height_m = 1.2 m" in summary["notes"][1]
    assert "note: the recording's camera is at z 0.88 m" in capsys.readouterr().out


def _refused(argv, capsys, message: str, out) -> None:
    assert main([*argv, "--output", str(out)]) == 2
    *bar, err = capsys.readouterr().err.strip().splitlines()   # a per-frame problem: after the progress bar
    assert err.startswith("calnav replay: error: ") and all(line.startswith("replay: ") for line in bar), bar
    assert message in err, err
    assert not out.exists()


def test_bad_inputs_are_one_line_and_nothing_is_written(episode, tmp_path, capsys):
    from tests.sequence_data import write_scannet

    goal, _, _, _, bag, _ = episode
    out = tmp_path / "out"
    _refused(["replay", str(bag), "--goal", "chiar", "--segmenter", "gt", *AGENT, *BAG_KEYS], capsys,
             "unknown goal 'chiar'; valid: chair (0), bed (1), plant (2), toilet (3), tv_monitor (4), sofa (5)", out)
    _refused(["replay", str(tmp_path / "none.bag"), "--goal", goal], capsys,
             f"rosbag not found: {tmp_path / 'none.bag'}", out)
    _refused(["replay", str(bag), "--goal", goal, "env.resolution=640x480"], capsys,
             "calnav replay sets env.resolution from the recording's depth camera itself; remove the override "
             "env.resolution=640x480", out)
    _refused(["replay", str(bag), "--goal", goal, "--segmenter", "gt", *AGENT], capsys,
             f"agent.segmenter=gt reads ground-truth semantic frames, which {bag} does not hold", out)
    truncated = tmp_path / "truncated.bag"   # a ROS 1 bag's index is at its end
    truncated.write_bytes(bag.read_bytes()[: int(bag.stat().st_size * 0.9)])
    _refused(["replay", str(truncated), "--goal", goal, "--segmenter", "gt", *AGENT, *BAG_KEYS], capsys,
             f"{truncated} is not a readable ROS bag", out)
    _refused(["replay", str(bag), "--goal", goal, "--segmenter", "gt", *AGENT, *BAG_KEYS,
              "sequence.rosbag.depth_topic=/nope"], capsys,
             f"{bag} has no depth image topic /nope (sequence.rosbag.depth_topic", out)
    handheld = write_scannet(tmp_path / "handheld")   # looking 19 degrees down, as a scan does
    _refused(["replay", str(handheld), "--layout", "scannet", "--goal", "chair", "--segmenter", "gt", *AGENT],
             capsys, "frame 0: the camera is pitched -19.3 and rolled 0.0 degrees from level (at most 2)", out)
    # an earlier replay's files are not the next one's: a rerun replaces them
    assert main(["replay", str(bag), "--goal", goal, "--segmenter", "gt", "--output", str(out), *AGENT, *BAG_KEYS,
                 "sequence.max_frames=5"]) == 0
    (out / "replay.rrd").write_text("an old recording")
    assert main(["replay", str(bag), "--goal", goal, "--segmenter", "gt", "--output", str(out), *AGENT, *BAG_KEYS,
                 "sequence.max_frames=5"]) == 0
    assert not (out / "replay.rrd").exists() and len(_frames(out)) == 5
    capsys.readouterr()
    _refused_other = tmp_path / "other"
    shutil.copytree(out, _refused_other)
    assert main(["replay", str(bag), "--goal", goal, "--segmenter", "gt", "--output", str(_refused_other), *AGENT,
                 *BAG_KEYS, "sequence.max_frames=5", "agent.goal_threshold=0.5"]) == 2
    assert "holds results of a different config" in capsys.readouterr().err
