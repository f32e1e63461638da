"""Perception: subsample the observation to the mapping resolution and segment it (segmenter by name
from ``agent.segmenters``). It keeps no map: fusing the segmentation into the 3D voxel map and
projecting it to the 2D map is ``agent.semantic_map``'s job.

It reads ``rgb`` and ``depth`` (de-normalised by ``agent.sensors.SensorModel``) and takes the
intrinsics from the known sensor; the ``gt`` / ``noisy`` segmenters (simulated sensors, like
Habitat's semantic sensor) also get ``semantic``, ``instance`` when present, and the
simulator's ``camera_pose`` when present (``noisy`` anchors its errors in the world with it).
"""
from __future__ import annotations

import numpy as np

from calnav.agent.config import AgentConfig
from calnav.agent.segmenters import make_segmenter
from calnav.agent.sensors import SensorModel
from calnav.envs.task import CAMERA_POSE, RGB, SEMANTIC, require_keys
from calnav.mapping.frame import SegmentedFrame


def subsample_stride(width: int, height: int, target: tuple[int, int]) -> int:
    """Integer pixel stride taking (width, height) to at most ``target`` (w, h) (>= 1)."""
    return max(1, width // target[0], height // target[1])


def subsample_intrinsics(k: np.ndarray, stride: int) -> np.ndarray:
    """Intrinsics of the image ``img[::stride, ::stride]`` (pixel centres at integer
    coordinates: small pixel i is big pixel i * stride)."""
    out = np.asarray(k, np.float64).copy()
    out[:2] /= stride
    out[2, 2] = 1.0
    return out


class Perception:
    """The segmenter, stateless across frames. ``observe(obs) -> SegmentedFrame`` (``mapping.frame``)."""

    def __init__(self, cfg: AgentConfig, sensors: SensorModel, device: str = "cpu"):
        self.cfg = cfg
        self.sensors = sensors
        self.segmenter = make_segmenter(cfg.segmenter, cfg.segmenter_config, device, key="agent.segmenter_config")
        self.num_classes = self.segmenter.num_classes
        self.class_names: tuple[str, ...] = tuple(self.segmenter.class_names)

    def observe(self, obs: dict) -> SegmentedFrame:
        """Subsample and segment one observation."""
        depth = self.sensors.depth_m(obs)
        h, w = depth.shape
        s = subsample_stride(w, h, self.cfg.map_resolution)
        depth = np.ascontiguousarray(depth[::s, ::s])
        rgb = np.ascontiguousarray(np.asarray(obs[RGB])[::s, ::s])
        k = subsample_intrinsics(self.sensors.intrinsics, s)
        extra = {}
        if self.segmenter.needs_semantic:
            require_keys(obs, [SEMANTIC], f"the {self.segmenter.name!r} segmenter")
            extra["semantic"] = np.ascontiguousarray(np.asarray(obs[SEMANTIC])[::s, ::s])
            if "instance" in obs:
                extra["instance"] = np.ascontiguousarray(np.asarray(obs["instance"])[::s, ::s])
            if CAMERA_POSE in obs:  # the simulated segmenter's input, never the agent's
                extra["pose"] = np.asarray(obs[CAMERA_POSE], np.float64)
        logits = self.segmenter(rgb, depth, **extra)
        return SegmentedFrame(depth, k, logits, rgb)
