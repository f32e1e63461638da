"""Semantic segmenters: RGB-D frame -> per-pixel logits (H, W, K). See ``base`` for the
interface; ``make_segmenter`` builds one by name:

- ``gt``: ground truth with a fixed confidence (needs the env's ``semantic`` observation);
- ``noisy``: ground truth with a controlled, view-correlated, overconfident error model;
- ``learned_rgb``: compact CNN on RGB (Segformer stand-in), trained in the simulator;
- ``learned_rgbd``: two-branch RGB + depth CNN (ESANet stand-in).
"""
from __future__ import annotations

from typing import Callable

from calnav.agent.segmenters.base import Segmenter, SegmenterConfig, default_class_names, resolve_device, softmax

__all__ = ["SEGMENTERS", "SEGMENTER_NAMES", "Segmenter", "SegmenterConfig", "check_segmenter", "make_segmenter",
           "segmenter_needs_semantic", "softmax"]


def _ground_truth(name: str, cfg: SegmenterConfig, device: str | None, class_names) -> Segmenter:
    if (device or cfg.device or "cpu") != "cpu":  # same validation as the networks (imports torch)
        resolve_device(device or cfg.device)
    names = tuple(class_names) if class_names is not None else default_class_names()
    if name == "gt":
        from calnav.agent.segmenters.ground_truth import GroundTruthSegmenter

        return GroundTruthSegmenter(cfg, names)
    from calnav.agent.segmenters.noisy import NoisySegmenter

    return NoisySegmenter(cfg, names)


def _learned(name: str, cfg: SegmenterConfig, device: str | None, class_names) -> Segmenter:
    from calnav.agent.segmenters.learned import LearnedSegmenter

    return LearnedSegmenter(name, cfg, device)


# The registry: name -> builder(name, cfg, device, class_names). ``agent.config.SegmenterName``
# lists the same names for the config loader (a test keeps the two equal).
SEGMENTERS: dict[str, Callable[..., Segmenter]] = {
    "gt": _ground_truth, "noisy": _ground_truth, "learned_rgb": _learned, "learned_rgbd": _learned,
}
SEGMENTER_NAMES: tuple[str, ...] = tuple(SEGMENTERS)


def segmenter_needs_semantic(name: str) -> bool:
    """Whether segmenter ``name`` reads the ground-truth ``semantic`` observation (its class's
    ``needs_semantic``), so a run without that sensor cannot use it."""
    if name not in SEGMENTERS:
        raise ValueError(f"unknown segmenter {name!r}; valid names: {', '.join(SEGMENTER_NAMES)}")
    if SEGMENTERS[name] is not _ground_truth:
        return False   # the learned segmenters read rgb (and depth)
    from calnav.agent.segmenters.ground_truth import GroundTruthSegmenter
    from calnav.agent.segmenters.noisy import NoisySegmenter

    return {"gt": GroundTruthSegmenter, "noisy": NoisySegmenter}[name].needs_semantic


def check_segmenter(name: str, cfg: SegmenterConfig | None = None, device: str | None = None) -> tuple[str, ...]:
    """Open and validate everything segmenter ``name`` will need (its device; the weight file of
    a learned one, whose tensors must fit its network; the class list of the ground-truth
    based ones) without building it, and return its class names. Raises ValueError /
    FileNotFoundError naming the file: run before a run writes anything or starts workers."""
    cfg = cfg or SegmenterConfig()
    if name not in SEGMENTERS:
        raise ValueError(f"unknown segmenter {name!r}; valid names: {', '.join(SEGMENTER_NAMES)}")
    if (device or cfg.device or "cpu") != "cpu":
        resolve_device(device or cfg.device)
    if SEGMENTERS[name] is _ground_truth:
        return default_class_names()
    from calnav.agent.segmenters.learned import check_weights, default_weights_path

    return check_weights(cfg.weights or default_weights_path(name), name)


def make_segmenter(name: str, cfg: SegmenterConfig | None = None, device: str | None = None,
                   class_names: tuple[str, ...] | None = None) -> Segmenter:
    """The segmenter ``name`` (one of SEGMENTER_NAMES) configured by ``cfg``.

    device: torch device ("cpu", "cuda", "cuda:N"); None = ``cfg.device`` or cpu. A CUDA
    device on a machine without CUDA raises ValueError. class_names: classes of the
    ground-truth based segmenters (default: ``agent/weights/classes.json``, the simulator's
    list); the learned ones read theirs from the weights file.
    """
    cfg = cfg or SegmenterConfig()
    if name not in SEGMENTERS:
        raise ValueError(f"unknown segmenter {name!r}; valid names: {', '.join(SEGMENTER_NAMES)}")
    return SEGMENTERS[name](name, cfg, device, class_names)

