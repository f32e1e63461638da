"""``onnx``: any ONNX semantic-segmentation model through ``onnxruntime`` (the common way to ship
a model to a robot). ``calnav export-onnx`` writes calnav's own networks in this form.

``segmenter.model``: the ``.onnx`` file. Inputs: the first is the image, (B, 3, H, W) float32
(``rgb / 255``, then ``(x - input_mean) / input_std``); a second input, when the graph has
one, is depth (B, 1, H, W) float32 metres (0 = invalid). Output 0: (B, K, h, w) logits. Read
from the file's metadata when present (``calnav export-onnx`` writes them):
``calnav.class_names`` (JSON list), ``calnav.input_mean`` / ``calnav.input_std`` (JSON, 3
values) -- config keys that are set win. Without class names, ``segmenter.label_map`` names the
channels in order. A graph with a fixed H x W gets frames resized to it (area for rgb, nearest
for depth); a dynamic one gets ``segmenter.resolution`` or the frame's size.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from calnav.agent.segmenters.adapter import ModelAdapter
from calnav.agent.segmenters.base import SegmenterConfig, class_list

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def _session(path: Path, threads: int, device, key: str = "segmenter"):
    try:
        import onnxruntime as ort
    except ImportError:
        raise ValueError("segmenter onnx needs onnxruntime: pip install 'calnav[onnx]'") from None
    if not path.is_file():
        raise FileNotFoundError(f"{key}.model {path} is not a file: give the .onnx model file")
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    providers = ["CPUExecutionProvider"]
    if device.type == "cuda":
        if "CUDAExecutionProvider" not in ort.get_available_providers():
            raise ValueError(f"device {device} asked for, but this onnxruntime has no CUDA provider "
                             f"(pip install onnxruntime-gpu); use {key}.device=cpu")
        providers.insert(0, ("CUDAExecutionProvider", {"device_id": device.index or 0}))
    try:
        return ort.InferenceSession(str(path), options, providers=providers)
    except Exception as exc:  # noqa: BLE001 -- onnxruntime raises its own types for a bad file
        raise ValueError(f"cannot load ONNX model {path}: {str(exc).strip().splitlines()[0]}") from None


def _static(dim) -> int | None:
    return dim if isinstance(dim, int) and dim > 0 else None


class ONNXSegmenter(ModelAdapter):
    """An ``onnxruntime`` session over ``cfg.model``; see the module docstring."""

    def __init__(self, name: str, cfg: SegmenterConfig, device: str | None, key: str = "segmenter"):
        from calnav.agent.segmenters.base import resolve_device

        dev = resolve_device(device or cfg.device or "cpu", f"{key}.device")
        self.path = Path(cfg.model)
        self.session = _session(self.path, max(cfg.threads, 0), dev, key)
        meta = self.session.get_modelmeta().custom_metadata_map
        try:
            names = json.loads(meta["calnav.class_names"]) if "calnav.class_names" in meta else None
            mean = cfg.input_mean or json.loads(meta.get("calnav.input_mean", "null")) or IMAGENET_MEAN
            std = cfg.input_std or json.loads(meta.get("calnav.input_std", "null")) or IMAGENET_STD
        except (TypeError, ValueError) as exc:
            raise ValueError(f"ONNX model {self.path}: bad calnav metadata: {exc}") from None
        if names is not None:
            names = class_list(names, f"ONNX model {self.path}: metadata calnav.class_names")
        inputs, output = self.session.get_inputs(), self.session.get_outputs()[0]
        if len(inputs) not in (1, 2) or len(inputs[0].shape) != 4 or len(output.shape) != 4:
            raise ValueError(f"ONNX model {self.path}: expected inputs image (B, 3, H, W) [+ depth (B, 1, H, W)] "
                             f"and output (B, K, h, w), got inputs {[i.shape for i in inputs]}, output {output.shape}")
        self.inputs = [i.name for i in inputs]
        self.needs_depth = len(inputs) == 2
        h, w = _static(inputs[0].shape[2]), _static(inputs[0].shape[3])
        self.resolution = (w, h) if h and w else (tuple(cfg.resolution) if tuple(cfg.resolution) != (0, 0) else None)
        self.mean = torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1) * 255.0
        self.std = torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1) * 255.0
        super().__init__(name, cfg, device, names, k_model=_static(output.shape[1]), key=key)

    def model_logits(self, rgb: np.ndarray, depth: np.ndarray | None) -> torch.Tensor:
        x = (torch.from_numpy(rgb).permute(0, 3, 1, 2).float() - self.mean) / self.std
        d = None if depth is None or not self.needs_depth else \
            torch.nan_to_num(torch.from_numpy(np.ascontiguousarray(depth, np.float32))[:, None], 0.0, 0.0, 0.0)
        if self.resolution is not None and tuple(x.shape[-2:]) != (self.resolution[1], self.resolution[0]):
            size = (self.resolution[1], self.resolution[0])
            shrink = size[0] <= x.shape[-2] and size[1] <= x.shape[-1]
            x = F.interpolate(x, size=size, mode="area" if shrink else "bilinear")
            d = None if d is None else F.interpolate(d, size=size, mode="nearest")
        feeds = {self.inputs[0]: x.contiguous().numpy()}
        if d is not None:
            feeds[self.inputs[1]] = d.contiguous().numpy()
        return torch.from_numpy(self.session.run(None, feeds)[0])
