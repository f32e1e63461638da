"""The perceive stage: subsample the observation to the mapping resolution and segment it
(segmenter by name from ``agent.segmenters``). It keeps no map: fusing the segmentation into
the 3D voxel map and projecting it to the 2D map is the map stage's (``agent.semantic_map``).

It reads ``rgb`` and ``depth`` of the ``agent.contract.Observation`` (depth de-normalised by
``agent.sensors.SensorModel``) and takes the intrinsics from the known sensor; the ``gt`` /
``noisy`` segmenters (simulated sensors, like Habitat's semantic sensor: ``needs_semantic``)
also get ``semantic``. Of the privileged part it hands the segmenter only what the segmenter's
class declares (``agent.contract.handed``): ``noisy`` declares the simulator's ``camera_pose``
(it anchors its errors in the world with it) and ``instance``; no other segmenter gets either.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from calnav.agent.config import AgentConfig
from calnav.agent.contract import Privileged, handed
from calnav.agent.segmenters import make_segmenter
from calnav.agent.segmenters.base import SegmenterConfig
from calnav.agent.sensors import SensorModel
from calnav.envs.task import RGB, SEMANTIC, require_keys
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
    """The segmenter, stateless across frames. ``observe(obs) -> SegmentedFrame`` (``mapping.frame``).
    ``cfg.segmenter`` names the segmenter, ``segmenter_cfg`` (the ``segmenter`` section) sets it up."""

    def __init__(self, cfg: AgentConfig, segmenter_cfg: SegmenterConfig, sensors: SensorModel, device: str = "cpu"):
        self.cfg = cfg
        self.sensors = sensors
        self.segmenter = make_segmenter(cfg.segmenter, segmenter_cfg, device)
        self.num_classes = self.segmenter.num_classes
        self.class_names: tuple[str, ...] = tuple(self.segmenter.class_names)

    def observe(self, obs: Mapping, privileged: Privileged | None = None) -> SegmentedFrame:
        """Subsample and segment one observation (``obs``: Habitat's keys); ``privileged``:
        the observation's privileged part, of which the segmenter gets what it declares."""
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
        given = handed(self.segmenter, privileged)   # the simulated segmenter's input, never the agent's
        if given.instance is not None:
            extra["instance"] = np.ascontiguousarray(np.asarray(given.instance)[::s, ::s])
        if given.camera_pose is not None:
            extra["pose"] = np.asarray(given.camera_pose, np.float64)
        logits = self.segmenter(rgb, depth, **extra)
        return SegmentedFrame(depth, k, logits, rgb)
