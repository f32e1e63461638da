"""Segmenter factories the plugin tests load by import path (``tests.agent.segmenter_plugins:NAME``).
Each is ``factory(cfg, device)`` as ``agent.segmenters`` calls it."""
from __future__ import annotations

import os
import sys
import time

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


class _Counting(Constant):
    """Uniform logits over calnav's classes; ``on_call(n)`` runs before the n-th ``segment``
    call of this instance (1-based), ``delay_s`` seconds of sleep on every call."""

    def __init__(self, on_call=None, delay_s: float = 0.0):
        names = default_class_names()
        super().__init__(names, np.zeros(len(names)))
        self.calls, self.on_call, self.delay_s = 0, on_call, delay_s

    def segment(self, rgb, depth=None):
        self.calls += 1
        if self.on_call is not None:
            self.on_call(self.calls)
        if self.delay_s:
            time.sleep(self.delay_s)
        return super().segment(rgb, depth)


EXIT_CALL = 5   # the call on which the exiting / interrupting plugins below stop


def exits_in_factory(cfg, device):
    """A factory that ends the process instead of raising (user code calling sys.exit())."""
    sys.exit()


def interrupts_in_factory(cfg, device):
    """A factory that raises KeyboardInterrupt itself (no Ctrl-C was pressed)."""
    raise KeyboardInterrupt


def _exit_on(n):
    if n == EXIT_CALL:
        sys.exit()


def _interrupt_on(n):
    if n == EXIT_CALL:
        raise KeyboardInterrupt


def exits_on_call(cfg, device):
    """Segments EXIT_CALL - 1 frames, then calls sys.exit() (exit status 0) on the next."""
    return _Counting(_exit_on)


def interrupts_on_call(cfg, device):
    """Segments EXIT_CALL - 1 frames, then raises KeyboardInterrupt itself on the next."""
    return _Counting(_interrupt_on)


SLOW_S = float(os.environ.get("CALNAV_TEST_SLOW_SEGMENTER_S", "0.2"))   # seconds per frame


def slow(cfg, device):
    """Uniform logits after SLOW_S seconds per frame (a slow model: a run that takes a while)."""
    return _Counting(delay_s=SLOW_S)


class Reversed:
    """Another segmenter behind the plugin interface with its class list and its logits'
    channels both reversed: the same predictions under another class order."""

    def __init__(self, inner):
        self.inner = inner
        self.class_names = tuple(reversed(inner.class_names))
        self.needs_depth = inner.needs_depth

    def segment(self, rgb, depth=None):
        return self.inner.segment(rgb, depth)[..., ::-1]


def reversed_learned_rgb(cfg, device):
    """calnav's learned_rgb with classes and channels reversed: its episodes must be learned_rgb's."""
    return Reversed(make_segmenter("learned_rgb", cfg, device))


class Named:
    """Zero logits under whatever ``class_names`` is given (a list, a string, ...), kept as given."""

    def __init__(self, class_names, k):
        self.class_names, self.k = class_names, k

    def segment(self, rgb, depth=None):
        return np.zeros((*rgb.shape[:2], self.k), np.float32)


def duplicate_classes(cfg, device):
    """calnav's classes with 'wall' in the place of 'ceiling' (two channels named wall)."""
    names = tuple("wall" if n == "ceiling" else n for n in default_class_names())
    return Named(names, len(names))


def unknown_classes(cfg, device):
    """calnav's classes and two it does not have."""
    names = (*default_class_names(), "sky", "person")
    return Named(names, len(names))


def string_classes(cfg, device):
    """class_names given as one string rather than a list of names."""
    return Named("chair", 5)


class Mutating:
    """learned_rgbd that, after segmenting, writes zeros into the depth and rgb it was given
    (user code preprocessing in place)."""

    def __init__(self, inner):
        self.inner, self.class_names, self.needs_depth = inner, inner.class_names, True

    def segment(self, rgb, depth=None):
        out = self.inner.segment(rgb, depth)
        depth[...] = 0.0
        rgb[...] = 0
        return out


def mutating_learned_rgbd(cfg, device):
    return Mutating(make_segmenter("learned_rgbd", cfg, device))


def no_bed(cfg, device):
    """Every calnav class but bed (so each goal after it sits one channel before its id)."""
    names = tuple(n for n in default_class_names() if n != "bed")
    return Constant(names, np.zeros(len(names)))
