"""``calnav export-onnx``: calnav's learned segmenters as ONNX models for the ``onnx`` adapter
(``onnxruntime``; the usual way to ship a model to a robot).

    calnav export-onnx --segmenter learned_rgb --output learned_rgb.onnx
    calnav objectnav agent.segmenter=onnx segmenter.model=learned_rgb.onnx ...

The graph holds the network with its BatchNorm folded at the training resolution (fixed H x W,
dynamic batch): input ``rgb`` (B, 3, H, W) float32 = rgb / 255 (the network normalises
inside), for ``learned_rgbd`` also ``depth`` (B, 1, H, W) float32 metres; output ``logits``
(B, K, H', W'). Metadata: ``calnav.class_names``, ``calnav.input_mean`` = [0, 0, 0],
``calnav.input_std`` = [1, 1, 1], ``calnav.source``. Before the file is written the export is
checked: ``onnx`` segmenter and the torch segmenter agree within ``--atol`` on frames rendered
at a size the network must resize from.
"""
from __future__ import annotations

import contextlib
import json
import logging
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
import torch

from calnav.common.atomic import atomic_path
from calnav.eval.results_dir import check_output_file, writing
from dataclasses import dataclass
from typing import Literal
from calnav.eval.arguments import REQUIRED, Command, arg

ATOL = 1e-4


@contextlib.contextmanager
def _quiet_exporter():
    """torch.export / torch.onnx narrate their passes (warnings and log lines about optional
    operator sets such as torchvision's): keep the command's output to its result."""
    loggers = [logging.getLogger(n) for n in ("torch.onnx", "torch.export", "torch._dynamo", "torch.fx")]
    levels = [lg.level for lg in loggers]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for lg in loggers:
            lg.setLevel(logging.ERROR)
        try:
            yield
        finally:
            for lg, level in zip(loggers, levels):
                lg.setLevel(level)


def network_class_names(seg) -> list[str]:
    """The class of each output channel of ``seg.net`` in the network's own order (the graph's
    metadata names its outputs; ``seg.class_names`` is calnav's order, reached through
    ``seg.channels`` when the weight file lists the classes in another)."""
    if seg.channels is None:
        return list(seg.class_names)
    names = [""] * seg.net.spec.num_classes
    for name, channel in zip(seg.class_names, seg.channels):
        names[channel] = name
    return names


def export(model: str, weights: str, output: Path, atol: float = ATOL) -> dict:
    """Export ``model`` (``learned_rgb`` | ``learned_rgbd``, weights ``weights`` or the shipped
    ones) to ``output``; returns {max_abs_diff, frames, resolution}. ValueError when onnxruntime's
    logits differ from torch's by more than ``atol`` (nothing written then)."""
    try:
        import onnx
    except ImportError:
        raise ValueError("export-onnx needs onnx and onnxruntime: pip install 'calnav[onnx]'") from None
    from calnav.agent.segmenters.base import SegmenterConfig
    from calnav.agent.segmenters.learned import LearnedSegmenter
    from calnav.agent.segmenters.onnx import ONNXSegmenter

    seg = LearnedSegmenter(model, SegmenterConfig(weights=weights), "cpu")
    net = seg.net.to(memory_format=torch.contiguous_format).eval()   # forward(rgb[, depth]): the graph's inputs
    w, h = seg.resolution
    names = ["rgb", "depth"] if seg.needs_depth else ["rgb"]
    args = (torch.rand(2, 3, h, w),) + ((1.0 + 3.0 * torch.rand(2, 1, h, w),) if seg.needs_depth else ())
    batch = torch.export.Dim("batch", min=1, max=1024)
    shapes = tuple({0: batch} for _ in args)
    with tempfile.TemporaryDirectory(prefix="calnav-onnx-") as tmp:
        raw = Path(tmp) / "model.onnx"
        with _quiet_exporter(), torch.no_grad():
            torch.onnx.export(net, args, str(raw), input_names=names, output_names=["logits"],
                              dynamic_shapes=shapes, opset_version=18, dynamo=True, verbose=False)
        graph = onnx.load(str(raw))
        meta = {"calnav.class_names": json.dumps(network_class_names(seg)), "calnav.input_mean": "[0, 0, 0]",
                "calnav.input_std": "[1, 1, 1]", "calnav.source": f"{model} {seg.weights_path.name}"}
        for key, value in meta.items():
            graph.metadata_props.add(key=key, value=value)
        onnx.checker.check_model(graph)
        onnx.save(graph, str(raw))
        check = _compare(seg, ONNXSegmenter("onnx", SegmenterConfig(model=str(raw), threads=1), "cpu"), atol)
        with writing(output):
            output.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(output) as dest:
                shutil.copyfile(raw, dest)
    return {**check, "resolution": [w, h]}


def _compare(torch_seg, onnx_seg, atol: float) -> dict:
    """Both segmenters on frames at the network size and at 1.5x it (resized by both)."""
    rng = np.random.default_rng(0)
    w, h = torch_seg.resolution
    diff = 0.0
    for size in ((w, h), (w * 3 // 2, h * 3 // 2)):
        rgb = rng.integers(0, 256, (2, size[1], size[0], 3), dtype=np.uint8)
        depth = rng.uniform(0.0, 5.0, (2, size[1], size[0])).astype(np.float32)
        a, b = torch_seg.segment_batch(rgb, depth), onnx_seg.segment_batch(rgb, depth)
        diff = max(diff, float(np.abs(a - b).max()))
    if not diff <= atol:
        raise ValueError(f"the ONNX export differs from the torch network by {diff:.2e} > {atol:.0e} in logits; "
                         "nothing written")
    return {"max_abs_diff": diff, "frames": 4}


def main_export_onnx(args, configs) -> None:
    out = Path(args.output)
    check_output_file(out)
    result = export(args.segmenter, args.weights or "", out)
    print(f"{args.segmenter} -> {out} (input {result['resolution'][0]}x{result['resolution'][1]}, logits equal to "
          f"torch within {result['max_abs_diff']:.1e} on {result['frames']} frames)")


@dataclass
class ExportOnnxArgs:
    """``calnav export-onnx``'s flags."""

    segmenter: Literal["learned_rgb", "learned_rgbd"] = arg(REQUIRED, "network to export")
    weights: str | None = arg(None, "weight file (default: the shipped agent/weights/<segmenter>.pt)")
    output: str = arg(REQUIRED, "the .onnx file to write")


COMMAND = Command(ExportOnnxArgs, main_export_onnx, sections=(), overrides=None)   # reads a weight file, no config
