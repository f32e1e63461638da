"""Bench section "adapter": what a plugged-in segmenter costs beyond its own inference, per
160x120 frame (``agent.segmenters.adapter``; median of timed calls after warm-up, 1 torch
thread as the agents run).

- ``adapter.passthrough.ms_160x120``: a plugin that predicts calnav's 18 classes (no label
  map): its output checked (shape, K, finite) and converted; the plugin itself returns a
  precomputed array, so this is the wrapper alone.
- ``adapter.ade20k_quarter.ms_160x120``: ADE20K's 150 logits at 40x30 (a Segformer's output
  for this frame: 1/4 resolution) -> calnav logits: softmax, the label-map matrix, bilinear
  upsampling of the 18 probabilities, log, numpy.
- ``adapter.ade20k_full.ms_160x120``: the same from 150 logits at the full 160x120 (a model
  with full-resolution output).
- ``adapter.onnx_learned_rgb.ms_160x120`` / ``adapter.torch_learned_rgb.ms_160x120`` and their
  ratio ``adapter.onnx_over_torch``: calnav's learned_rgb exported with ``calnav export-onnx``
  and run through the ``onnx`` adapter, against the torch segmenter (skipped without
  onnxruntime).
"""
from __future__ import annotations

import tempfile
from pathlib import Path

from calnav.eval.bench.context import timeit_ms

SIZE = (160, 120)   # W, H
REPEATS = 50


def run(ctx) -> dict[str, float]:
    import numpy as np
    import torch

    from calnav.agent.segmenters import SegmenterConfig, make_segmenter
    from calnav.agent.segmenters.adapter import ModelAdapter, PluginSegmenter
    from calnav.agent.segmenters.base import default_class_names
    from calnav.agent.segmenters.label_map import read_label_map

    torch.set_num_threads(1)
    w, h = SIZE
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    repeats = 10 if ctx.quick else REPEATS
    out: dict[str, float] = {}

    class Precomputed:
        class_names = default_class_names()

        def __init__(self):
            self.logits = rng.normal(0, 3, (h, w, len(self.class_names))).astype(np.float32)

        def segment(self, rgb, depth=None):
            return self.logits

    plugin = PluginSegmenter("bench", Precomputed(), SegmenterConfig(), "cpu")
    out["adapter.passthrough.ms_160x120"] = timeit_ms(lambda: plugin(rgb), repeats=repeats, warmup=3)

    ade = read_label_map("ade20k").model_classes

    class Fixed(ModelAdapter):
        def __init__(self, z):
            self.z = z
            super().__init__("bench", SegmenterConfig(label_map="ade20k"), "cpu", ade)

        def model_logits(self, rgb, depth):
            return self.z

    for figure, (zh, zw) in {"ade20k_quarter": (h // 4, w // 4), "ade20k_full": (h, w)}.items():
        seg = Fixed(torch.from_numpy(rng.normal(0, 3, (1, len(ade), zh, zw)).astype(np.float32)))
        out[f"adapter.{figure}.ms_160x120"] = timeit_ms(lambda: seg(rgb), repeats=repeats, warmup=3)

    try:
        from calnav.eval.segmenter.export_onnx import export
    except ImportError:
        return out
    with tempfile.TemporaryDirectory(prefix="calnav-bench-onnx-") as tmp:
        try:
            export("learned_rgb", "", Path(tmp) / "m.onnx")
        except (ValueError, FileNotFoundError) as exc:   # no onnx / onnxruntime, or no weights
            print(f"[bench] adapter: skipping the onnx figures: {exc}", flush=True)
            return out
        onnx_seg = make_segmenter("onnx", SegmenterConfig(model=str(Path(tmp) / "m.onnx"), threads=1))
        torch_seg = make_segmenter("learned_rgb", SegmenterConfig(threads=1))
        frames = ctx.frames(w, h)[:(4 if ctx.quick else 20)]
        for name, seg in (("onnx", onnx_seg), ("torch", torch_seg)):
            times = [timeit_ms(lambda f=f: seg(f.rgb), repeats=1, warmup=1) for f in frames]
            out[f"adapter.{name}_learned_rgb.ms_160x120"] = float(np.median(times))
    out["adapter.onnx_over_torch"] = out["adapter.onnx_learned_rgb.ms_160x120"] / out["adapter.torch_learned_rgb.ms_160x120"]
    return out
