"""Small ROS bags for the rosbag layout's tests: the generated ScanNet-layout room
(``tests.sequence_data``, 6 frames of 40x30, frame 2 without a pose) written as ROS 1 / ROS 2
bags by ``mapping.sequences.rosbag_write`` (rosbags' writers and type stores)."""
from __future__ import annotations

from pathlib import Path

from calnav.mapping.sequences import SequenceConfig
from calnav.mapping.sequences.rosbag_config import RosbagConfig
from calnav.mapping.sequences.rosbag_write import BagOptions, scannet_to_bag
from tests.sequence_data import write_scannet

FRAMES, DROPPED = 6, 2
SEMANTIC_TOPIC = "/camera/semantic/image_raw"
ODOMETRY = {"pose_source": "topic", "pose_topic": "/odom"}   # sequence.rosbag keys of a bag's odometry poses
SUFFIX = {"ros1": ".bag", "sqlite3": "", "mcap": ""}   # a ROS 2 bag is a directory


def folder(tmp: Path) -> Path:
    """The ScanNet-layout recording (frame ``DROPPED`` has ScanNet's -inf pose)."""
    return write_scannet(tmp / "seq", n=FRAMES, bad_pose=DROPPED)


def bag(seq: Path, name: str, **options) -> Path:
    """``seq`` written as a bag next to it (``BagOptions`` keywords; labels on ``SEMANTIC_TOPIC``)."""
    opt = BagOptions(**{"semantic_topic": SEMANTIC_TOPIC, **options})
    return scannet_to_bag(seq, seq.parent / f"{name}{SUFFIX[opt.storage]}", opt)


def bag_config(**rosbag) -> SequenceConfig:
    """A ``SequenceConfig`` reading the labels topic, with ``sequence.rosbag`` keys set."""
    return SequenceConfig(rosbag=RosbagConfig(**{"semantic_topic": SEMANTIC_TOPIC, **rosbag}))


def overrides(**rosbag) -> list[str]:
    """The same as ``calnav map`` overrides."""
    return [f"sequence.rosbag.{k}={v}" for k, v in {"semantic_topic": SEMANTIC_TOPIC, **rosbag}.items()]
