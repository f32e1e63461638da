"""Perception: subsample the frame to the mapping resolution, segment it (segmenter by name
from ``agent.segmenters``) and, for ``map_type: fused``, fuse it into the 3D voxel map with the
configured strategy (``mapping.fusion``; logit scaling, GLFS parameters and sample weighting
come from the mapping config and are applied inside the voxel map).

For ``map_type: ndf`` the per-pixel probabilities are softmax(logits / mapping.temperature)
(the scalar temperature; no 3D fusion).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agent.config import AgentConfig
from agent.segmenters import make_segmenter
from mapping.config import MappingConfig
from mapping.voxel_map import SemanticVoxelMap


@dataclass
class Frame:
    """One frame at the mapping resolution: depth (h, w) float32 m, labels (h, w) int64
    arg-max class of the segmentation, probs (h, w, K) float32,
    intrinsics (3, 3) at (w, h), rgb (h, w, 3) uint8, vmap the voxel map it was fused into
    (None for ndf)."""

    depth: np.ndarray
    labels: np.ndarray
    probs: np.ndarray
    intrinsics: np.ndarray
    rgb: np.ndarray
    vmap: SemanticVoxelMap | None


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


def softmax(logits: np.ndarray, temperature: float) -> np.ndarray:
    """softmax(logits / temperature) over the last axis, float32."""
    z = logits / temperature
    z = z - z.max(axis=-1, keepdims=True)
    e = np.exp(z)
    return (e / e.sum(axis=-1, keepdims=True)).astype(np.float32)


class Perception:
    """Segmenter + (per episode) voxel map. ``observe(obs) -> Frame``."""

    def __init__(self, cfg: AgentConfig, mapping_cfg: MappingConfig, device: str = "cpu"):
        self.cfg, self.mapping_cfg = cfg, mapping_cfg
        self.segmenter = make_segmenter(cfg.segmenter, cfg.segmenter_config, device)
        self.num_classes = self.segmenter.num_classes
        self.vmap: SemanticVoxelMap | None = None

    def reset(self) -> None:
        """A fresh voxel map for a new episode (fused) or none (ndf)."""
        self.vmap = None
        if self.cfg.map_type == "fused":
            self.vmap = SemanticVoxelMap(self.num_classes, self.mapping_cfg, class_names=self.segmenter.class_names)

    def observe(self, obs: dict) -> Frame:
        """Segment (and fuse) one observation."""
        depth = np.asarray(obs["depth"], np.float32)
        depth = depth[..., 0] if depth.ndim == 3 else depth
        h, w = depth.shape
        s = subsample_stride(w, h, self.cfg.map_resolution)
        depth = np.ascontiguousarray(depth[::s, ::s])
        rgb = np.ascontiguousarray(np.asarray(obs["rgb"])[::s, ::s])
        k = subsample_intrinsics(obs["camera_intrinsics"], s)
        pose = np.asarray(obs["camera_pose"], np.float64)
        extra = {}
        if self.segmenter.needs_semantic:
            extra["semantic"] = np.ascontiguousarray(np.asarray(obs["semantic"])[::s, ::s])
            if "instance" in obs:
                extra["instance"] = np.ascontiguousarray(np.asarray(obs["instance"])[::s, ::s])
            extra["pose"] = pose
        logits = self.segmenter(rgb, depth, **extra)
        if self.vmap is not None:
            self.vmap.integrate(depth, k, pose, logits=logits, rgb=rgb)
            probs = logits  # unused by the fused projection (it reads the voxel map)
        else:
            probs = softmax(logits, self.mapping_cfg.temperature)
        return Frame(depth, logits.argmax(axis=-1), probs, k, rgb, self.vmap)
