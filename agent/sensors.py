"""What the agent knows of its sensors: Habitat's ObjectNav observations turned into geometry.

The agent reads only ``envs.task.HABITAT_KEYS`` (rgb, depth, gps, compass, objectgoal). Its
maps live in the episode-start frame (``envs.task``: origin at the start position on the
floor, +x forward at the start, +y left, +z up), as PEANUT and SemExp build theirs:

- camera pose = ``envs.task.camera_pose`` at the start-frame position and heading that gps +
  compass give, at the known camera height (``env.camera_height_m``), pitch 0 (the agent never
  tilts: it uses no LOOK_UP / LOOK_DOWN);
- intrinsics = ``envs.task.pinhole_intrinsics`` of the known resolution and hfov
  (``env.resolution``, ``env.hfov_deg``);
- depth in metres: de-normalised with ``env.min_depth_m`` / ``env.max_depth_m`` when
  ``env.normalize_depth`` is set.

These are task facts from the config the agent is built with (like max_episode_steps), not
simulator state.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calnav.envs.task import (COMPASS, DEPTH, GPS, HABITAT_KEYS, camera_pose, depth_to_metres, gps_compass_to_xy_yaw,
                       pinhole_intrinsics, require_keys)


@dataclass(frozen=True)
class SensorModel:
    """The task's sensor facts. resolution (W, H) pixels; hfov_deg degrees; camera_height_m
    metres above the floor; depth range [min_depth_m, max_depth_m] metres; normalize_depth:
    depth arrives as Habitat's normalised [0, 1] values."""

    resolution: tuple[int, int]
    hfov_deg: float
    camera_height_m: float
    min_depth_m: float
    max_depth_m: float
    normalize_depth: bool

    @classmethod
    def from_env_config(cls, env_cfg) -> "SensorModel":
        """From an ``EnvConfig``-like object (``cfg.env``)."""
        w, h = env_cfg.resolution
        return cls((int(w), int(h)), float(env_cfg.hfov_deg), float(env_cfg.camera_height_m),
                   float(env_cfg.min_depth_m), float(env_cfg.max_depth_m), bool(env_cfg.normalize_depth))

    @property
    def intrinsics(self) -> np.ndarray:
        """(3, 3) float64 K at the sensor resolution."""
        return pinhole_intrinsics(*self.resolution, self.hfov_deg)

    def check(self, obs: dict) -> None:
        """The observation has Habitat's keys and the configured resolution (one-line errors)."""
        require_keys(obs, HABITAT_KEYS)
        check_resolution(np.shape(obs[DEPTH])[:2], self.resolution)

    def xy_yaw(self, obs: dict) -> tuple[np.ndarray, float]:
        """Start-frame agent position (2,) metres and heading (rad, ccw from the start heading)."""
        return gps_compass_to_xy_yaw(obs[GPS], obs[COMPASS])

    def pose(self, obs: dict) -> np.ndarray:
        """(4, 4) float64 start-frame-from-camera pose (OpenCV axes)."""
        xy, yaw = self.xy_yaw(obs)
        return camera_pose(xy, yaw, self.camera_height_m)

    def depth_m(self, obs: dict) -> np.ndarray:
        """(H, W) float32 depth in metres, 0 = invalid."""
        d = np.asarray(obs[DEPTH], np.float32)
        d = d[..., 0] if d.ndim == 3 else d
        return depth_to_metres(d, self.normalize_depth, self.min_depth_m, self.max_depth_m)


def check_resolution(shape: tuple[int, ...], resolution: tuple[int, int]) -> None:
    """Refuse (ValueError, one line) a depth image of (H, W) ``shape`` that is not the sensor's
    ``resolution`` (W, H) pixels (``env.resolution``): the agent's intrinsics are of that size."""
    w, h = resolution
    if tuple(shape) != (h, w):
        raise ValueError(f"depth observation is {shape[1]}x{shape[0]} pixels but the agent is configured "
                         f"for env.resolution={w}x{h}: build the agent with the env's config")


# Depth a robot hands over in other units: metric depth past 100 m (the mapping's depth-range cap)
# over most of a frame is millimetres; normalised depth past 1 is metric depth.
MAX_PLAUSIBLE_DEPTH_M = 100.0
NORMALISED_DEPTH_SLACK = 1e-6


def check_depth(depth: np.ndarray, normalised: bool) -> None:
    """Refuse (ValueError, one line) depth that cannot be the metres (``normalised``: Habitat's
    [0, 1]) the agent maps: an integer image (raw sensor units), normalised depth past 1, metric
    depth beyond ``MAX_PLAUSIBLE_DEPTH_M`` over most of the frame (millimetres). NaN, inf and 0
    are invalid pixels, which the map skips."""
    unit = "normalised [0, 1] (env.normalize_depth is true)" if normalised else "metres (env.normalize_depth is false)"
    if depth.dtype.kind != "f":
        raise ValueError(f"depth must be float {unit}; got {depth.dtype}: raw sensor units? divide by the sensor's "
                         "depth scale (millimetres: 1000) into float32")
    if normalised:
        over = int(np.count_nonzero(np.isfinite(depth) & (depth > 1.0 + NORMALISED_DEPTH_SLACK)))
        if over:
            raise ValueError(f"depth must be {unit}; {over} pixels exceed 1 (max "
                             f"{float(depth[np.isfinite(depth)].max()):.4g}): "
                             "metric depth? set env.normalize_depth=false")
        return
    finite = depth[np.isfinite(depth)]   # inf (ROS REP 117: out of range) is an invalid pixel, not a far one
    far, valid = int(np.count_nonzero(finite > MAX_PLAUSIBLE_DEPTH_M)), int(np.count_nonzero(finite > 0))
    if valid and 2 * far > valid:
        raise ValueError(f"depth must be {unit}; {far} of its {valid} valid pixels lie beyond {MAX_PLAUSIBLE_DEPTH_M:g} "
                         "m: millimetres? divide by 1000")
