"""How a ROS bag is read as a recorded sequence (``sequence.rosbag``): topic names, frames,
tolerances, and the drivers' default topic names (``ROSBAG_PRESETS``).

Cheap to import (no rosbags, no OpenCV): ``SequenceConfig`` holds a ``RosbagConfig`` and the
config loader validates it without reading a bag.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from calnav.common.ranges import Range, check_ranges
from calnav.common.registry import Registry


@dataclass(frozen=True)
class RosbagPreset:
    """The topics one RGB-D driver publishes by default: colour image, depth image registered to
    the colour camera, and their ``sensor_msgs/CameraInfo``."""

    color: str
    depth: str
    color_info: str
    depth_info: str


# Default topic names of the common RGB-D drivers (each from the driver's documentation or
# launch files). Depth is the driver's depth registered to the colour camera: the reader maps
# depth in the colour camera's optical frame. A recording of the compressed image_transport
# topics (``<topic>/compressed``, ``<topic>/compressedDepth``) is found from the same names.
ROSBAG_PRESETS: Registry = Registry("rosbag preset", key="sequence.rosbag.preset")
# realsense2_camera (ROS 1, and the ROS 2 wrapper before 4.54) with align_depth:=true
ROSBAG_PRESETS.add("realsense", RosbagPreset(
    "/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw",
    "/camera/color/camera_info", "/camera/aligned_depth_to_color/camera_info"),
    "Intel RealSense (realsense2_camera, align_depth:=true)")
# the ROS 2 wrapper from 4.54 on names its node 'camera' in namespace 'camera'
ROSBAG_PRESETS.add("realsense_ros2", RosbagPreset(
    "/camera/camera/color/image_raw", "/camera/camera/aligned_depth_to_color/image_raw",
    "/camera/camera/color/camera_info", "/camera/camera/aligned_depth_to_color/camera_info"),
    "Intel RealSense, ROS 2 wrapper >= 4.54 (align_depth.enable:=true)")
# Azure_Kinect_ROS_Driver: depth_to_rgb is the depth image transformed into the colour camera
ROSBAG_PRESETS.add("azure_kinect", RosbagPreset(
    "/rgb/image_raw", "/depth_to_rgb/image_raw", "/rgb/camera_info", "/depth_to_rgb/camera_info"),
    "Azure Kinect DK (Azure_Kinect_ROS_Driver)")
# OrbbecSDK_ROS1 / OrbbecSDK_ROS2 with depth_registration:=true (depth aligned to colour)
ROSBAG_PRESETS.add("orbbec", RosbagPreset(
    "/camera/color/image_raw", "/camera/depth/image_raw", "/camera/color/camera_info", "/camera/depth/camera_info"),
    "Orbbec (OrbbecSDK_ROS1 / ROS2, depth_registration:=true)")
# zed-ros-wrapper / zed-ros2-wrapper: depth_registered is the depth of the left (rgb) camera
for _model in ("zed", "zed2", "zed2i"):
    ROSBAG_PRESETS.add(_model, RosbagPreset(
        f"/{_model}/zed_node/rgb/image_rect_color", f"/{_model}/zed_node/depth/depth_registered",
        f"/{_model}/zed_node/rgb/camera_info", f"/{_model}/zed_node/depth/camera_info"),
        f"Stereolabs {_model.upper()} (zed-ros-wrapper / zed-ros2-wrapper, camera_model {_model})")

IDENTITY_EXTRINSIC = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
# a camera_extrinsic quaternion is renormalised when its norm is within this of 1; farther is a
# typo (or Euler angles), refused
QUATERNION_NORM_TOL = 1e-3

# Declared ranges of the bag reading (``sequence.rosbag``), and why: colour and depth of one
# RGB-D frame are at most a second apart (drivers stamp them within a frame period, 33 ms at
# 30 Hz; 0 = identical stamps only); a pose is interpolated between samples at most 10 s apart
# (a robot's odometry or TF runs at >= 1 Hz; a longer gap is a lost pose, not motion to
# interpolate); the camera sits within 10 m of the body whose pose a topic gives.
ROSBAG_RANGES = {
    "sync_tolerance_s": Range(0.0, 1.0, "seconds"),
    "pose_max_gap_s": Range(0.0, 10.0, "seconds", lo_open=True),
}
EXTRINSIC_TRANSLATION_RANGE = Range(-10.0, 10.0, "metres")


@dataclass
class RosbagConfig:
    """How a ROS bag is read (``sequence.rosbag``; ``calnav map BAG --layout rosbag``)."""

    preset: str = "realsense"          # the driver whose default topic names apply (ROSBAG_PRESETS)
    color_topic: str = ""              # colour images (sensor_msgs/Image or CompressedImage); "" = the preset's
    depth_topic: str = ""              # depth registered to colour (Image 16UC1 mm / 32FC1 m, or compressedDepth); "" = the preset's
    color_info_topic: str = ""         # colour CameraInfo (intrinsics); "" = the preset's
    depth_info_topic: str = ""         # depth CameraInfo; "" = the preset's, else the colour CameraInfo when absent
    semantic_topic: str = ""           # optional per-frame labels: mono16 / 16UC1 images of class id + 1 (0 = void); "" = none
    pose_source: Literal["tf", "topic"] = "tf"   # camera poses from the TF tree, or from pose_topic + camera_extrinsic
    fixed_frame: str = ""              # the map's frame (TF); "" = the root of the TF tree above the camera
    camera_frame: str = ""             # the colour camera's optical frame (TF); "" = the colour images' header.frame_id
    pose_topic: str = ""               # pose_source=topic: nav_msgs/Odometry, geometry_msgs/PoseStamped or PoseWithCovarianceStamped
    # pose_source=topic: the colour camera's optical frame in the pose topic's body frame: x, y, z
    # metres, then the rotation as a quaternion qx, qy, qz, qw (ROS order)
    camera_extrinsic: tuple[float, float, float, float, float, float, float] = IDENTITY_EXTRINSIC
    sync_tolerance_s: float = 0.02     # a colour image's depth image is the one nearest in stamp within this, seconds
    pose_max_gap_s: float = 0.2        # a pose is interpolated between samples at most this far apart, seconds
    assume_registered: bool = False    # accept depth whose header.frame_id is not the colour camera's (a driver that registers depth but keeps its frame name)

    def __post_init__(self) -> None:
        ROSBAG_PRESETS.check(self.preset)
        check_ranges(self, "sequence.rosbag", ROSBAG_RANGES)
        if self.pose_source == "topic" and not self.pose_topic:
            raise ValueError("sequence.rosbag.pose_source=topic needs sequence.rosbag.pose_topic "
                             "(a nav_msgs/Odometry, geometry_msgs/PoseStamped or PoseWithCovarianceStamped topic)")
        for axis, value in zip("xyz", self.camera_extrinsic[:3]):
            EXTRINSIC_TRANSLATION_RANGE.check(f"sequence.rosbag.camera_extrinsic {axis}", value)
        norm = math.sqrt(sum(q * q for q in self.camera_extrinsic[3:]))
        if not abs(norm - 1.0) <= QUATERNION_NORM_TOL:
            raise ValueError(f"sequence.rosbag.camera_extrinsic: the quaternion (qx, qy, qz, qw) = "
                             f"{tuple(self.camera_extrinsic[3:])} has norm {norm:.4g}; it must be a unit quaternion")

    def topics(self) -> RosbagPreset:
        """The topics read: each key given here, else the preset's."""
        p = ROSBAG_PRESETS.get(self.preset)
        return RosbagPreset(self.color_topic or p.color, self.depth_topic or p.depth,
                            self.color_info_topic or p.color_info, self.depth_info_topic or p.depth_info)
