"""The frame the mapping pipeline starts from: one segmented RGB-D view, ready to fuse.

Every producer makes this one type: the agent's perception (a Habitat observation subsampled
to the mapping resolution and segmented, ``agent.perception``), a recorded sequence registered
to its depth camera and segmented (``eval.sequence.source``). What comes before it has other
names: the simulator renders a ``envs.render.RenderedView``, a recording's reader yields a
``mapping.sequences.SequenceFrame`` (two cameras, not yet segmented).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class SegmentedFrame:
    """depth (h, w) float32 metres (0 = invalid); k (3, 3) float64 pixel intrinsics at (w, h);
    logits (h, w, K) float32 segmenter scores; rgb (h, w, 3) uint8; pose (4, 4) float64
    world-from-camera (OpenCV axes), or None where the consumer poses it (the agent, from gps +
    compass); semantic (h, w) int ground-truth class ids (-1 void) or None; index: frame number
    in a recording (-1 for a live frame)."""

    depth: np.ndarray
    k: np.ndarray
    logits: np.ndarray
    rgb: np.ndarray
    pose: np.ndarray | None = None
    semantic: np.ndarray | None = None
    index: int = -1
    _labels: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def labels(self) -> np.ndarray:
        """(h, w) int64 arg-max class of the logits (computed once)."""
        if self._labels is None:
            self._labels = self.logits.argmax(axis=-1)
        return self._labels
