"""``learned_rgb`` / ``learned_rgbd``: the networks of ``agent.segmenters.network`` trained on
simulator frames (``calnav train-segmenter``), wrapped for inference.

Weight file (``torch.save`` of a plain dict, loaded with ``weights_only=True``):

    format: WEIGHTS_FORMAT        model: "learned_rgb" | "learned_rgbd"
    spec: NetSpec.to_dict()       state_dict: {name: fp16 tensor}
    class_names: [K names]        resolution: [W, H] training resolution, pixels
    meta: {command, seed, frames, epochs, wall_s, val metrics, ...}

Inference: the frame is resized to the network resolution (``SegmenterConfig.resolution``,
default: the training resolution; area averaging for rgb, nearest for depth so invalid zeros
never blend into valid depth), run through the network in eval mode with BatchNorm folded and
channels-last memory, and the logits are bilinearly upsampled back to the frame size. With
``segmenter.trace`` (the default) the network runs on the CPU as a TorchScript trace made on the
first call of each input shape: it records the same operations, so the logits are bit-identical to
eager mode (a test checks both models), with less Python work per call.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from calnav.common.atomic import atomic_path
from calnav.common.weights import load_weight_dict
from calnav.agent.segmenters.base import (WEIGHTS_DIR, BatchSegmenter, SegmenterConfig, calnav_class_order, check_batch,
                                          resolve_device, set_cuda_precision)
from calnav.agent.segmenters.network import NetSpec, SegNet, fuse_batchnorm

WEIGHTS_FORMAT = 1
LEARNED_MODELS: tuple[str, ...] = ("learned_rgb", "learned_rgbd")


def default_weights_path(model: str) -> Path:
    """agent/weights/<model>.pt (located relative to this package, so editable and regular
    installs both find it)."""
    return WEIGHTS_DIR / f"{model}.pt"


def train_command(model: str, path: Path | str) -> str:
    """The exact command that creates the weight file ``path`` for ``model``."""
    out = Path(path)
    default = default_weights_path(model)
    suffix = "" if out.resolve() == default.resolve() else f" --output {out}"
    return f"calnav train-segmenter --segmenter {model}{suffix}"


def load_weights(path: Path | str, model: str | None = None) -> dict:
    """The weight dict of ``path``; FileNotFoundError names the path and the command that
    creates it; ValueError when the file is not a calnav segmenter (or is for another model)."""
    path = Path(path)
    data = load_weight_dict(path, "segmenter", WEIGHTS_FORMAT, train_command(model or "learned_rgb", path))
    if model is not None and data.get("model") != model:
        raise ValueError(f"{path} holds weights for {data.get('model')!r}, not {model!r}")
    return data


def check_weights(path: Path | str, model: str) -> tuple[str, ...]:
    """Validate the weight file ``path`` of ``model`` without keeping the network: readable,
    for this model, one class name per network output, each a distinct calnav class, tensors
    that fit the network's spec. Returns the class names in calnav's order (the segmenter's
    ``class_names``); FileNotFoundError / ValueError name the file."""
    data = load_weights(path, model)
    try:
        spec = NetSpec.from_dict(data["spec"])
        names = tuple(str(n) for n in data["class_names"])
        if len(names) != spec.num_classes:
            raise ValueError(f"{len(names)} class names for a {spec.num_classes}-class network")
        SegNet(spec).load_state_dict({k: v.float() for k, v in data["state_dict"].items()})
        if len(data["resolution"]) != 2:
            raise ValueError(f"resolution must be [W, H], got {data['resolution']}")
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:  # RuntimeError: tensors of another shape
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"damaged segmenter weights {path}: {first}") from None
    return calnav_class_order(data["class_names"], f"segmenter weights {path}")[0]


def save_weights(net: SegNet, path: Path | str, model: str, class_names, resolution: tuple[int, int],
                 meta: dict | None = None) -> Path:
    """Write ``net`` as a weight file (floating tensors as fp16; see the module docstring),
    atomically (a temporary file renamed into place). Returns the path."""
    if model not in LEARNED_MODELS:
        raise ValueError(f"unknown learned model {model!r}; valid: {', '.join(LEARNED_MODELS)}")
    if len(class_names) != net.spec.num_classes:
        raise ValueError(f"{len(class_names)} class names for a {net.spec.num_classes}-class network")
    state = {k: (v.detach().cpu().half() if v.is_floating_point() else v.detach().cpu()) for k, v in net.state_dict().items()}
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save({"format": WEIGHTS_FORMAT, "model": model, "spec": net.spec.to_dict(), "state_dict": state,
                    "class_names": list(class_names), "resolution": [int(v) for v in resolution],
                    "meta": dict(meta or {})}, tmp)
    return path


def build_network(data: dict, device: torch.device) -> SegNet:
    """Eval-mode network (BatchNorm folded, channels-last, float32) from a weight dict."""
    net = SegNet(NetSpec.from_dict(data["spec"]))
    net.load_state_dict({k: v.float() for k, v in data["state_dict"].items()})
    net.eval()
    fuse_batchnorm(net)
    return net.to(device=device, memory_format=torch.channels_last)


class LearnedSegmenter(BatchSegmenter):
    """A trained ``SegNet``. ``segment(rgb, depth)`` -> (H, W, K) float32 logits; depth is
    required by ``learned_rgbd`` and ignored (may be None) by ``learned_rgb``."""

    def __init__(self, name: str, cfg: SegmenterConfig, device: str | None = None):
        if name not in LEARNED_MODELS:
            raise ValueError(f"unknown learned model {name!r}; valid: {', '.join(LEARNED_MODELS)}")
        self.name, self.cfg = name, cfg
        self.device = resolve_device(device or cfg.device or "cpu")
        set_cuda_precision(self.device, cfg.tf32)
        if cfg.threads > 0:
            torch.set_num_threads(cfg.threads)
        self.weights_path = Path(cfg.weights) if cfg.weights else default_weights_path(name)
        data = load_weights(self.weights_path, name)
        self.meta = dict(data.get("meta", {}))
        # the network's channels matched to calnav's classes by name (None: already calnav's order)
        self.class_names, self.channels = calnav_class_order(data["class_names"],
                                                             f"segmenter weights {self.weights_path}")
        self.train_resolution = tuple(int(v) for v in data["resolution"])
        w, h = cfg.resolution
        self.resolution = (int(w), int(h)) if (w, h) != (0, 0) else self.train_resolution
        self.net = build_network(data, self.device)
        self.needs_depth = bool(self.net.spec.in_depth)
        self._traces: dict[tuple, torch.jit.ScriptModule] = {}   # (rgb shape, depth shape) -> trace

    def _run(self, x: torch.Tensor, d: torch.Tensor | None) -> torch.Tensor:
        """The network's logits for x (B, 3, h, w) and d (B, 1, h, w) or None: eager, or the trace
        for this input shape (``segmenter.trace``; traced on first use)."""
        # CPU only: on CUDA, TorchScript's profiling executor may fuse element-wise ops after the
        # first calls, which would not be bit-identical (and is untested here); a torch without
        # jit.trace runs eager too -- the same logits either way
        if not self.cfg.trace or self.device.type != "cpu" or not hasattr(torch.jit, "trace"):
            return self.net(x, d)
        key = (tuple(x.shape), None if d is None else tuple(d.shape))
        traced = self._traces.get(key)
        if traced is None:
            inputs = (x,) if d is None else (x, d)
            with warnings.catch_warnings():
                # deprecated in torch 2.x in favour of torch.compile / torch.export, but still the
                # fastest bit-identical runner here (measured 1 thread, 160x120: eager 2.4-3.1 ms,
                # torch.fx 2.2-2.4, torch.export 2.6-2.8, jit.trace 1.9-2.3)
                warnings.simplefilter("ignore", DeprecationWarning)
                traced = self._traces[key] = torch.jit.trace(self.net, inputs, check_trace=False)
        return traced(x) if d is None else traced(x, d)

    @torch.inference_mode()
    def segment_batch(self, rgb: np.ndarray, depth: np.ndarray | None = None, **_unused) -> np.ndarray:
        """rgb (B, H, W, 3) uint8, depth (B, H, W) float metres -> logits (B, H, W, K) float32."""
        rgb, depth = check_batch(rgb, depth, self.needs_depth, self.name)
        b, h, w = rgb.shape[:3]
        x = torch.from_numpy(rgb).to(self.device).permute(0, 3, 1, 2).float().mul_(1.0 / 255.0)
        d = None
        if self.needs_depth:
            d = torch.from_numpy(np.ascontiguousarray(depth, dtype=np.float32)).to(self.device)[:, None]
            d = torch.nan_to_num(d, nan=0.0, posinf=0.0, neginf=0.0)
        nw, nh = self.resolution
        if (w, h) != (nw, nh):
            x = F.interpolate(x, size=(nh, nw), mode="area" if (nw <= w and nh <= h) else "bilinear")
            if d is not None:
                d = F.interpolate(d, size=(nh, nw), mode="nearest")
        x = x.contiguous(memory_format=torch.channels_last)
        logits = self._run(x, d)
        if self.channels is not None:
            logits = logits[:, list(self.channels)]
        if logits.shape[-2:] != (h, w):
            logits = F.interpolate(logits, size=(h, w), mode="bilinear", align_corners=False)
        # channels-last logits are already (B, H, W, K) in memory: the permute is free
        return logits.permute(0, 2, 3, 1).float().contiguous().cpu().numpy()
