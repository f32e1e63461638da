"""Bench section "segmenter": inference time of the learned segmenters (CPU).

- ``segmenter.<model>.ms_160x120``: one ``segment(rgb, depth)`` call on a 160x120 frame (the
  training resolution: no resizing), median over the BenchContext trajectory's frames after
  WARMUP calls, inside ``torch.inference_mode`` (the wrapper's own), with the default
  config's thread count.
- ``segmenter.<model>.ms_640x480``: the same call on the 640x480 sensor frame with the
  default config, i.e. area-downsampling to 160x120, the network, and bilinear upsampling of
  the K logits back to 640x480 (what an agent pays per full-resolution frame).
- ``segmenter.<model>.ms_640x480_native``: the network run at 640x480 itself
  (``segmenter.resolution = 640x480``), for reference.
- ``segmenter.<model>.eager_ms_160x120``: ``ms_160x120`` with ``segmenter.trace = false`` (eager
  mode), and ``segmenter.<model>.trace_speedup``: eager / traced time, frame by frame in the
  same loop (the default runs a TorchScript trace with bit-identical logits).
- ``segmenter.threads``: torch threads during the measurement (``SegmenterConfig.threads``,
  default 1).
- ``segmenter.<model>.cuda_ms_160x120`` and ``cuda_ms_640x480``: the same calls with
  ``device="cuda"`` (upload, network in eager mode -- calnav traces on CPU only -- upsampling,
  and the logits' copy back to numpy, which waits for the GPU), measured only where torch sees a
  CUDA GPU; the figures are absent elsewhere.

Models whose weight file is missing are skipped with a message (the figures are then absent).
"""
from __future__ import annotations

from calnav.eval.bench.context import timeit_ms

MODELS = ("learned_rgb", "learned_rgbd")
WARMUP = 3                   # calls before timing (allocator and oneDNN kernel caches warm up)
REPEATS_PER_FRAME = 1        # timed calls per frame


def run(ctx) -> dict[str, float]:
    import dataclasses

    import numpy as np
    import torch

    from calnav.agent.segmenters import SegmenterConfig, make_segmenter

    out: dict[str, float] = {}
    n_frames = 4 if ctx.quick else 20
    for model in MODELS:
        variants = {"ms_160x120": ((160, 120), SegmenterConfig()),
                    "ms_640x480": ((640, 480), SegmenterConfig()),
                    "ms_640x480_native": ((640, 480), dataclasses.replace(SegmenterConfig(), resolution=(640, 480)))}
        eager = None
        for figure, (res, cfg) in variants.items():
            try:
                seg = make_segmenter(model, cfg, "cpu")
            except FileNotFoundError as exc:
                print(f"[bench] segmenter: skipping {model}: {exc}", flush=True)
                break
            frames = ctx.frames(*res)[:n_frames]
            for f in frames[:WARMUP]:
                seg(f.rgb, f.depth)
            if figure == "ms_160x120":   # eager mode alongside, alternating frame by frame
                eager = make_segmenter(model, dataclasses.replace(cfg, trace=False), "cpu")
                for f in frames[:WARMUP]:
                    eager(f.rgb, f.depth)
            times, eager_times = [], []
            for f in frames:
                times.append(timeit_ms(lambda f=f: seg(f.rgb, f.depth), repeats=REPEATS_PER_FRAME, warmup=0))
                if figure == "ms_160x120":
                    eager_times.append(timeit_ms(lambda f=f: eager(f.rgb, f.depth), repeats=REPEATS_PER_FRAME,
                                                 warmup=0))
            out[f"segmenter.{model}.{figure}"] = float(np.median(times))
            if eager_times:
                out[f"segmenter.{model}.eager_ms_160x120"] = float(np.median(eager_times))
                out[f"segmenter.{model}.trace_speedup"] = float(np.median(np.divide(eager_times, times)))
        else:   # every CPU variant ran (the weights exist)
            if torch.cuda.is_available():
                out.update(_cuda_figures(ctx, model, n_frames))
    out["segmenter.threads"] = float(torch.get_num_threads())  # after the segmenters set it (config threads)
    return out


def _cuda_figures(ctx, model: str, n_frames: int) -> dict[str, float]:
    """``segmenter.<model>.cuda_ms_<W>x<H>``: median ``segment`` time on the GPU (the numpy
    result is the synchronisation point), after WARMUP calls (cuDNN picks its kernels then)."""
    import numpy as np

    from calnav.agent.segmenters import SegmenterConfig, make_segmenter

    out = {}
    for w, h in ((160, 120), (640, 480)):
        seg = make_segmenter(model, SegmenterConfig(), "cuda")
        frames = ctx.frames(w, h)[:n_frames]
        for f in frames[:WARMUP]:
            seg(f.rgb, f.depth)
        times = [timeit_ms(lambda f=f: seg(f.rgb, f.depth), repeats=REPEATS_PER_FRAME, warmup=0) for f in frames]
        out[f"segmenter.{model}.cuda_ms_{w}x{h}"] = float(np.median(times))
    return out
