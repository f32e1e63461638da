"""The episode-start frame of a robot's poses (``agent.navigator``): a camera pose to the level
planar pose the agent maps with, and Habitat's gps / compass of later poses relative to the
first one."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from calnav.envs.task import xy_yaw_to_gps_compass, yaw_to_habitat_quaternion

# The agent maps with a level camera: a floor point 5 m away (env.max_depth_m's default) seen by a
# camera tilted 2 degrees lands 0.17 m off the floor, still under agent.obstacle_min_height_m
# (0.25 m); tilted more, far floor would become obstacles.
LEVEL_TOLERANCE_DEG = 2.0
# What a robot's inputs cannot be, refused rather than mapped: each is a unit or frame mix-up that
# the agent would otherwise turn into a blind search or a wrong map with no other sign.
# - pose: Habitat keeps the start position in float32 (its gps is computed so, bit for bit), whose
#   values are 2^-10 m (~1 mm) apart from 2^13 m on: UTM / GNSS frames need a local origin.
MAX_POSE_DISTANCE_M = 8192.0
ANGLE_SLACK = 1e-5   # rad: float32 round-off of an angle at +-pi


def planar_pose(pose: Any) -> tuple[np.ndarray, float]:
    """(x, y) (2,) float64 metres and yaw (rad, counter-clockwise from +x) of a camera ``pose``:
    a (4, 4) world-from-camera transform (OpenCV camera axes, world +z up) or (3,) (x, y, yaw).
    ValueError (one line) for another shape, a non-finite value or a camera tilted more than
    ``LEVEL_TOLERANCE_DEG`` (pitch: the optical axis out of the horizontal; roll: the image's x
    axis out of it)."""
    from calnav.mapping.frame_geometry import check_pose

    p = np.asarray(pose, np.float64)
    if p.shape not in ((3,), (4, 4)):
        raise ValueError(f"pose must be a (4, 4) world-from-camera transform or (x, y, yaw); got shape {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError(f"pose is not finite: {p.tolist()}")
    xy = p[:2].copy() if p.shape == (3,) else p[:2, 3].copy()
    if float(np.hypot(*xy)) >= MAX_POSE_DISTANCE_M:
        raise ValueError(f"the camera is at ({xy[0]:.6g}, {xy[1]:.6g}) m, {float(np.hypot(*xy)):.6g} m from the world "
                         f"origin (at most {MAX_POSE_DISTANCE_M:g}), where Habitat's float32 start position is 1 mm "
                         "coarse or worse: give poses in a local frame (subtract a fixed origin, e.g. the first position)")
    if p.shape == (3,):
        if abs(p[2]) > 2 * math.pi + ANGLE_SLACK:
            raise ValueError(f"yaw {p[2]:g} is not an angle in radians (|yaw| <= 2 pi): degrees? (an unwrapped "
                             "odometry yaw: wrap it with math.remainder(yaw, 2 * math.pi))")
        return xy, float(p[2])
    p = check_pose(p)   # a scaled, sheared or mirrored rotation is another convention, not a camera
    forward, right = p[:3, 2], p[:3, 0]
    pitch = math.degrees(math.asin(float(np.clip(forward[2] / max(np.linalg.norm(forward), 1e-12), -1, 1))))
    roll = math.degrees(math.asin(float(np.clip(right[2] / max(np.linalg.norm(right), 1e-12), -1, 1))))
    if max(abs(pitch), abs(roll)) > LEVEL_TOLERANCE_DEG:
        raise ValueError(f"the camera is pitched {pitch:.1f} and rolled {roll:.1f} degrees from level (at most "
                         f"{LEVEL_TOLERANCE_DEG:g}): the agent maps with a level camera at env.camera_height_m; give "
                         "a pose whose +z is up, or the level pose (x, y, yaw)")
    return xy, math.atan2(forward[1], forward[0])


@dataclass(frozen=True)
class StartFrame:
    """The episode-start frame of a first pose: ``xy`` (2,) metres and ``yaw`` rad in the
    world frame. ``gps_compass`` gives Habitat's sensors of a later pose relative to it."""

    xy: np.ndarray
    yaw: float

    def gps_compass(self, xy: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
        """gps (2,) float32 (forward, right) metres and compass (1,) float32 rad of a camera at
        world ``xy`` heading ``yaw``: the env's and habitat-lab's computation (``envs.task``)."""
        return xy_yaw_to_gps_compass(xy, yaw, self.xy, yaw_to_habitat_quaternion(self.yaw))

    def world(self, point) -> tuple[float, float]:
        """The world (x, y) metres of a start-frame ``point`` (x forward, y left at the start;
        a ``Decision``'s goals and position), e.g. to send a waypoint in the pose's frame."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        x, y = float(point[0]), float(point[1])
        return float(self.xy[0] + c * x - s * y), float(self.xy[1] + s * x + c * y)
