"""Segmenter factories the plugin tests load by import path (``tests.agent.segmenter_plugins:NAME``).
Each is ``factory(cfg, device)`` as ``agent.segmenters`` calls it."""
from __future__ import annotations

import numpy as np

from calnav.agent.segmenters import make_segmenter
from calnav.agent.segmenters.base import default_class_names
from calnav.agent.segmenters.label_map import read_label_map


def wrapped_learned_rgbd(cfg, device):
    """calnav's learned_rgbd behind the plugin interface (a user's model that already predicts
    calnav's classes): its maps and episodes must equal the built-in's."""
    return make_segmenter("learned_rgbd", cfg, device)


class Constant:
    """Logits that depend only on the image size: (H, W, K) copies of ``row``."""

    def __init__(self, class_names, row, needs_depth=False, shape_fn=None):
        self.class_names = tuple(class_names)
        self.row = np.asarray(row, np.float32)
        self.needs_depth = needs_depth
        self.shape_fn = shape_fn

    def segment(self, rgb, depth=None):
        h, w = rgb.shape[:2]
        if self.shape_fn:
            h, w = self.shape_fn(h, w)
        return np.broadcast_to(self.row, (h, w, len(self.row))).copy()


def nyu40_constant(cfg, device):
    """A model over NYU40's classes that always says 'chair' (channel 4) at logit 3."""
    names = read_label_map("nyu40").model_classes
    row = np.zeros(len(names), np.float32)
    row[names.index("chair")] = 3.0
    return Constant(names, row)


def raising(cfg, device):
    raise RuntimeError("no GPU memory left\nsecond line")


def wrong_k(cfg, device):
    names = default_class_names()
    return Constant(names, np.zeros(len(names) - 1))


def wrong_shape(cfg, device):
    names = default_class_names()
    return Constant(names, np.zeros(len(names)), shape_fn=lambda h, w: (h // 2, w))


def nan_logits(cfg, device):
    names = default_class_names()
    row = np.zeros(len(names), np.float32)
    row[3] = np.nan
    return Constant(names, row)


def no_tv(cfg, device):
    names = tuple(n for n in default_class_names() if n != "tv_monitor")
    return Constant(names, np.zeros(len(names)))


def not_a_segmenter(cfg, device):
    return object()


NOT_CALLABLE = 3


def wrapped_learned_rgb(cfg, device):
    """calnav's learned_rgb behind the plugin interface (RGB only: runs without a depth input)."""
    return make_segmenter("learned_rgb", cfg, device)
