"""The shared end of every plugged-in model: its logits -> calnav logits.

``ModelAdapter`` is the base of the adapters (``hf``, ``onnx``) and of
``PluginSegmenter`` (a user's factory). A subclass implements ``model_logits(rgb, depth)`` ->
(B, K_m, h, w) torch logits at the model's own output resolution; the base checks them (K_m,
finite), applies ``segmenter.label_map`` (``agent.segmenters.label_map``: probabilities added
per calnav class, the rest bucket spread evenly) at that resolution, upsamples to the frame
and returns (B, H, W, K) float32 numpy logits. Without a label map the model's classes must be
calnav classes, each once: they are matched by name and the logits' channels put in calnav's
order (a model that already predicts calnav's classes, in any order); a recording's logits of
another class list go through ``calnav map --logits`` instead.
"""
from __future__ import annotations

import math
import re
from abc import abstractmethod

import numpy as np
import torch
import torch.nn.functional as F

from calnav.agent.segmenters.base import (BatchSegmenter, Segmenter, SegmenterConfig, calnav_class_order, check_batch,
                                         class_list, default_class_names, resolve_device, set_cuda_precision)
from calnav.agent.segmenters.label_map import PROB_FLOOR, LabelMap, mapping_matrix, read_label_map
from calnav.common.interrupt import user_code

GENERIC_NAME = re.compile(r"^(LABEL_\d+|class_?\d+|\d+)$")   # placeholder names (a fresh HF config)


def resolve_label_map(spec: str, model_classes: tuple[str, ...] | None, k_model: int | None) -> LabelMap:
    """The label map ``spec`` aligned to the model's output channels: by name when the model
    names its classes (every name must be in the map; placeholder names such as LABEL_0 go by
    order), else by the map's order; K must agree."""
    label_map = read_label_map(spec)
    if model_classes:   # compared stripped: Segformer's ADE20K id2label spells id 7 "bed "
        model_classes = tuple(n.strip() for n in model_classes)
    if model_classes and not all(GENERIC_NAME.match(n) for n in model_classes):
        unknown = [n for n in model_classes if n not in label_map.model_classes]
        if unknown:
            shown = ", ".join(repr(n) for n in unknown[:5]) + (" ..." if len(unknown) > 5 else "")
            raise ValueError(f"label map {label_map.source} does not list the model's classes {shown} "
                             f"({len(unknown)} of {len(model_classes)}); add them (empty target = rest bucket)")
        return label_map.reorder(model_classes)
    k = len(model_classes) if model_classes else k_model
    if k is not None and k != len(label_map.model_classes):
        raise ValueError(f"the model predicts {k} classes, label map {label_map.source} lists "
                         f"{len(label_map.model_classes)}: give the map of the model's label set")
    return label_map


class ModelAdapter(BatchSegmenter):
    """Base of the plugged-in segmenters; see the module docstring. ``model_classes``: the
    model's class names in output order, or None when it does not carry them (the label map's
    order then names them). ``predicted_classes``: the calnav classes some model class maps to
    (the others only get the rest bucket's share). ``key``: the segmenter section
    (``segmenter``), named in the errors.

    Without a label map the model's classes must be calnav classes, each once; they are matched
    by name: ``class_names`` lists them in calnav's order and the logits' channels follow it
    (``channels``: the model channel of each, None when the model's order is calnav's), so a
    model whose list runs in another order gives the same map and episodes as one in calnav's."""

    def __init__(self, name: str, cfg: SegmenterConfig, device: str | None,
                 model_classes: tuple[str, ...] | None, k_model: int | None = None, key: str = "segmenter"):
        self.name, self.cfg = name, cfg
        self.device = resolve_device(device or cfg.device or "cpu", f"{key}.device")
        set_cuda_precision(self.device, cfg.tf32)
        self.channels: tuple[int, ...] | None = None
        if model_classes is not None:
            valid = () if cfg.label_map else default_class_names()   # named in the error when matched by name
            model_classes = class_list(model_classes, f"segmenter {name}", valid)
        if cfg.label_map:
            label_map = resolve_label_map(cfg.label_map, model_classes, k_model)
            self.class_names = default_class_names()
            self.matrix = torch.from_numpy(mapping_matrix(label_map, self.class_names)).to(self.device)
            self.model_classes = label_map.model_classes
            self.predicted_classes = tuple(n for n in self.class_names if n in set(label_map.targets))
        elif model_classes:
            self.matrix, self.model_classes = None, model_classes
            self.class_names, self.channels = calnav_class_order(   # stripped, as a label map compares them
                tuple(n.strip() for n in model_classes), f"segmenter {name}",
                f"; map the model's classes with {key}.label_map (ade20k | nyu40 | scannet20 | coco_panoptic | a file)")
            self.predicted_classes = self.class_names
        else:
            raise ValueError(f"segmenter {name}: the model does not name its classes; set {key}.label_map "
                             "(a built-in map or a file listing them in output order)")

    @abstractmethod
    def model_logits(self, rgb: np.ndarray, depth: np.ndarray | None) -> torch.Tensor:
        """rgb (B, H, W, 3) uint8, depth (B, H, W) float32 metres or None -> (B, K_m, h, w)
        logits at the model's output resolution, on any device."""

    @torch.inference_mode()
    def segment_batch(self, rgb: np.ndarray, depth: np.ndarray | None = None, **_unused) -> np.ndarray:
        """rgb (B, H, W, 3) uint8, depth (B, H, W) float metres -> (B, H, W, K) float32 logits."""
        rgb, depth = check_batch(rgb, depth, self.needs_depth, f"segmenter {self.name}")
        z = self.model_logits(rgb, None if depth is None else depth.astype(np.float32, copy=False))
        return self.to_calnav(z, rgb.shape[1:3])

    def to_calnav(self, z: torch.Tensor, size: tuple[int, int]) -> np.ndarray:
        """(B, K_m, h, w) model logits -> (B, H, W, K) calnav logits (label map, upsampling)."""
        if z.ndim != 4 or z.shape[1] != len(self.model_classes):
            raise ValueError(f"segmenter {self.name} returned logits of shape {tuple(z.shape)}; expected "
                             f"(B, {len(self.model_classes)}, h, w): one channel per model class")
        z = z.float()
        if self.matrix is not None:
            p = torch.softmax(z, dim=1).permute(0, 2, 3, 1) @ self.matrix   # (B, h, w, K)
            if tuple(p.shape[1:3]) != tuple(size):   # probabilities interpolate to probabilities
                p = F.interpolate(p.permute(0, 3, 1, 2), size=tuple(size), mode="bilinear",
                                  align_corners=False).permute(0, 2, 3, 1)
            out = torch.log(p.clamp_min(PROB_FLOOR))   # clamp keeps NaN: checked below
        else:
            if self.channels is not None:   # the model's channels in calnav's class order (by name)
                z = z[:, list(self.channels)]
            if tuple(z.shape[-2:]) != tuple(size):
                z = F.interpolate(z, size=tuple(size), mode="bilinear", align_corners=False)
            out = z.permute(0, 2, 3, 1)
        out = out.contiguous().cpu()
        # checked on the output (K calnav classes, not K_m: a NaN or +inf model logit makes its
        # pixel's softmax NaN) by one float64 sum: finite float32 values cannot overflow it, so
        # it is finite exactly when every value is, at a fraction of isfinite().all()'s cost
        if not math.isfinite(float(out.sum(dtype=torch.float64))):
            raise ValueError(f"segmenter {self.name} returned non-finite logits (NaN or inf)")
        return out.numpy()


class PluginSegmenter(ModelAdapter):
    """A segmenter built by a user's factory (``package.module:factory`` or an entry point of
    ``calnav.segmenters``): any object with ``class_names`` and ``segment(rgb, depth)`` ->
    (H, W, K) logits (``segment_batch`` used when it has one; ``needs_depth`` honoured). Its
    output is checked on every call (shape, K, finite) and label-mapped like the adapters'."""

    def __init__(self, name: str, inner, cfg: SegmenterConfig, device: str | None, key: str = "segmenter"):
        missing = [a for a in ("class_names", "segment") if not hasattr(inner, a)]
        if missing:
            raise ValueError(f"segmenter {name}: the factory returned {type(inner).__name__} without "
                             f"{', '.join(missing)}; return an object with class_names and segment(rgb, depth)")
        names = class_list(inner.class_names, f"segmenter {name}", () if cfg.label_map else default_class_names())
        self.inner = inner
        self.needs_depth = bool(getattr(inner, "needs_depth", False))
        super().__init__(name, cfg, device, names, key=key)

    def model_logits(self, rgb: np.ndarray, depth: np.ndarray | None) -> torch.Tensor:
        b, h, w = rgb.shape[:3]
        # the user's code gets copies: what it writes into its inputs (in-place preprocessing)
        # must not reach the caller's frame, which the map fuses after segmenting (the agent's
        # depth). Copies rather than read-only views: torch.from_numpy warns on those, and
        # in-place preprocessing is legitimate; measured 0.015 ms per 160x120 frame, 0.22 ms at 640x480
        rgb, depth = rgb.copy(), (None if depth is None else depth.copy())
        # the user's code: its sys.exit() (or a KeyboardInterrupt of its own) fails this frame's
        # task like any exception, instead of ending calnav; a real Ctrl-C still stops the run
        with user_code(f"segmenter {self.name}"):
            if hasattr(self.inner, "segment_batch"):
                out = np.asarray(self.inner.segment_batch(rgb, depth))
            else:
                out = np.stack([np.asarray(self.inner.segment(rgb[i], None if depth is None else depth[i]))
                                for i in range(b)])
        k = len(self.model_classes)
        if out.shape != (b, h, w, k):
            raise ValueError(f"segmenter {self.name} returned logits of shape {out.shape[1:]} for a {h}x{w} frame; "
                             f"expected (H, W, K) = ({h}, {w}, {k}), K = len(class_names)")
        if not np.issubdtype(out.dtype, np.floating):
            raise ValueError(f"segmenter {self.name} returned {out.dtype} logits; expected float")
        return torch.from_numpy(np.ascontiguousarray(out, np.float32)).permute(0, 3, 1, 2)


def check_goals(segmenter: Segmenter, goals: tuple[str, ...], key: str = "segmenter") -> None:
    """ValueError naming the goal categories ``segmenter`` cannot predict (not among its classes,
    or, label-mapped, no model class maps to them): its ObjectNav episodes would never find them.
    ``key``: the segmenter section as the running command spells it, named in the hint."""
    predicted = tuple(getattr(segmenter, "predicted_classes", segmenter.class_names))
    missing = [g for g in goals if g not in predicted]
    if missing:
        shown = ", ".join(predicted[:12]) + (f", ... ({len(predicted)} classes)" if len(predicted) > 12 else "")
        how = (f"label map {segmenter.cfg.label_map}: map a model class to each" if getattr(segmenter, "matrix", None)
               is not None else f"map the model's classes to calnav's with {key}.label_map (ade20k | nyu40 | "
               "scannet20 | coco_panoptic | a file)")
        raise ValueError(f"segmenter {segmenter.name} predicts no {', '.join(missing)} (it predicts: {shown}); "
                         f"ObjectNav needs every goal category: {how}")


def probe(segmenter: Segmenter, size: tuple[int, int] = (160, 120)) -> tuple[str, ...]:
    """Run ``segmenter`` on one synthetic frame of ``size`` (W, H) (a colour gradient, depth 1-4
    m) and check its logits: (H, W, len(class_names)), float, finite. Returns the class names;
    ValueError in one line otherwise (the user's exceptions included)."""
    w, h = size
    yy, xx = np.mgrid[0:h, 0:w]
    rgb = np.stack([xx * 255 // max(w - 1, 1), yy * 255 // max(h - 1, 1), np.full_like(xx, 128)], -1).astype(np.uint8)
    depth = (1.0 + 3.0 * yy / max(h - 1, 1)).astype(np.float32)
    try:
        out = np.asarray(segmenter.segment(rgb, depth))
    except Exception as exc:  # noqa: BLE001 -- a plugged-in model's own failure, in one line
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise ValueError(f"segmenter {segmenter.name} failed on a {w}x{h} probe frame: {type(exc).__name__}: {first}") from None
    k = len(segmenter.class_names)
    if out.shape != (h, w, k) or not np.issubdtype(out.dtype, np.floating) or not np.isfinite(out).all():
        raise ValueError(f"segmenter {segmenter.name} returned {out.dtype} logits of shape {out.shape} on a {w}x{h} "
                         f"probe frame; expected finite float ({h}, {w}, {k})")
    return tuple(segmenter.class_names)
