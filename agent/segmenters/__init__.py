"""Semantic segmenters: RGB-D frame -> per-pixel logits (H, W, K). See ``base`` for the
interface; ``make_segmenter`` builds one by name:

- ``gt``: ground truth with a fixed confidence (needs the env's ``semantic`` observation);
- ``noisy``: ground truth with a controlled, view-correlated, overconfident error model;
- ``learned_rgb``: compact CNN on RGB (Segformer stand-in), trained in the simulator;
- ``learned_rgbd``: two-branch RGB + depth CNN (ESANet stand-in).
"""
from __future__ import annotations

from agent.segmenters.base import Segmenter, SegmenterConfig, default_class_names, resolve_device, softmax

SEGMENTER_NAMES: tuple[str, ...] = ("gt", "noisy", "learned_rgb", "learned_rgbd")

__all__ = ["SEGMENTER_NAMES", "Segmenter", "SegmenterConfig", "make_segmenter", "softmax"]


def make_segmenter(name: str, cfg: SegmenterConfig | None = None, device: str | None = None,
                   class_names: tuple[str, ...] | None = None) -> Segmenter:
    """The segmenter ``name`` (one of SEGMENTER_NAMES) configured by ``cfg``.

    device: torch device ("cpu", "cuda", "cuda:N"); None = ``cfg.device`` or cpu. A CUDA
    device on a machine without CUDA raises ValueError. class_names: classes of the
    ground-truth based segmenters (default: ``agent/weights/classes.json``, the simulator's
    list); the learned ones read theirs from the weights file.
    """
    cfg = cfg or SegmenterConfig()
    if name not in SEGMENTER_NAMES:
        raise ValueError(f"unknown segmenter {name!r}; valid names: {', '.join(SEGMENTER_NAMES)}")
    if name in ("gt", "noisy"):
        if (device or cfg.device or "cpu") != "cpu":  # same validation as the networks (imports torch)
            resolve_device(device or cfg.device)
        names = tuple(class_names) if class_names is not None else default_class_names()
        if name == "gt":
            from agent.segmenters.ground_truth import GroundTruthSegmenter

            return GroundTruthSegmenter(cfg, names)
        from agent.segmenters.noisy import NoisySegmenter

        return NoisySegmenter(cfg, names)
    from agent.segmenters.learned import LearnedSegmenter

    return LearnedSegmenter(name, cfg, device)
