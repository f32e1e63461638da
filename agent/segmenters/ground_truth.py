"""``gt``: the ground-truth semantic image as logits with a fixed confidence (the paper's GT
segmentation row).

For a pixel of class c: logit log(conf) on c and log((1 - conf) / (K - 1)) on every other
class, so softmax gives exactly ``conf`` on c and the rest spread evenly. Void pixels (class
id < 0 or >= K) get all-zero logits (uniform). conf = 1 uses log(FLOAT32_TINY) for the others
(finite logits; softmax is then one-hot to float32 precision).
"""
from __future__ import annotations

import numpy as np

from calnav.agent.segmenters.base import Segmenter, SegmenterConfig, check_frame, check_label_image

FLOAT32_TINY = float(np.finfo(np.float32).tiny)  # keeps log((1 - conf) / (K - 1)) finite at conf = 1


class GroundTruthSegmenter(Segmenter):
    """segment(rgb, depth, semantic=obs['semantic']) -> (H, W, K) float32 logits."""

    name = "gt"
    needs_semantic = True

    def __init__(self, cfg: SegmenterConfig, class_names: tuple[str, ...]):
        if len(class_names) < 2:
            raise ValueError(f"gt segmenter needs at least 2 classes, got {len(class_names)}")
        self.class_names = tuple(class_names)
        k = len(self.class_names)
        conf = float(cfg.gt_confidence)
        self.confidence = conf
        self.true_logit = np.float32(np.log(conf))
        self.other_logit = np.float32(np.log(max((1.0 - conf) / (k - 1), FLOAT32_TINY)))

    def segment(self, rgb: np.ndarray, depth: np.ndarray | None = None, semantic: np.ndarray | None = None,
                **_unused) -> np.ndarray:
        """rgb (H, W, 3) uint8 (shape check only), depth unused, semantic (H, W) int class ids
        (-1 void) -> logits (H, W, K) float32. Extra keywords (instance, pose) are ignored."""
        rgb, _ = check_frame(rgb, depth, need_depth=False)
        sem = check_label_image("semantic", semantic, rgb.shape[:2]).astype(np.int64)
        k = self.num_classes
        out = np.full((*sem.shape, k), self.other_logit, dtype=np.float32)
        valid = (sem >= 0) & (sem < k)
        rows, cols = np.nonzero(valid)
        out[rows, cols, sem[valid]] = self.true_logit
        out[~valid] = 0.0
        return out
