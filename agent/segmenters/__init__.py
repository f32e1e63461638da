"""Semantic segmenters: RGB-D frame -> per-pixel logits (H, W, K). See ``base`` for the
interface; ``make_segmenter(spec)`` builds one. ``spec`` (``agent.segmenter``) is

- a built-in name: ``gt`` (ground truth with a fixed confidence; needs the env's ``semantic``
  observation), ``noisy`` (ground truth with a controlled, view-correlated, overconfident
  error model), ``learned_rgb`` / ``learned_rgbd`` (calnav's CNNs trained in the simulator,
  stand-ins for Segformer / ESANet), or an adapter for the models people have: ``hf``
  (transformers), ``onnx`` (onnxruntime) -- configured by
  ``segmenter.model`` and ``segmenter.label_map``;
- ``package.module:factory``: a user's factory, imported;
- a name another installed package registers in the entry-point group ``calnav.segmenters``
  (``[project.entry-points."calnav.segmenters"] mynet = "mypkg.seg:make"``).

A factory is called as ``factory(cfg: SegmenterConfig, device: str)`` and returns an object
with ``class_names`` and ``segment(rgb, depth) -> (H, W, K) logits`` (``segment_batch`` and
``needs_depth`` optional); calnav wraps it (``adapter.PluginSegmenter``: output checked on every
call, ``segmenter.label_map`` applied).
"""
from __future__ import annotations

import importlib
import re
from importlib.metadata import entry_points
from typing import Callable

from calnav.agent.segmenters.base import Segmenter, SegmenterConfig, default_class_names, segmenter_device, softmax
from calnav.common.interrupt import UserCodeExit, user_code
from calnav.common.registry import Registry

__all__ = ["BUILTIN_SEGMENTERS", "ENTRY_POINT_GROUP", "Segmenter", "SegmenterConfig", "check_segmenter",
           "check_segmenter_spec", "make_segmenter", "segmenter_needs_semantic", "softmax"]

ENTRY_POINT_GROUP = "calnav.segmenters"
IMPORT_PATH = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


def _ground_truth(name: str, cfg: SegmenterConfig, device: str, class_names, key: str) -> Segmenter:
    names = tuple(class_names) if class_names is not None else default_class_names()
    if name == "gt":
        from calnav.agent.segmenters.ground_truth import GroundTruthSegmenter

        return GroundTruthSegmenter(cfg, names)
    from calnav.agent.segmenters.noisy import NoisySegmenter

    return NoisySegmenter(cfg, names)


def _learned(name: str, cfg: SegmenterConfig, device: str, class_names, key: str) -> Segmenter:
    from calnav.agent.segmenters.learned import LearnedSegmenter

    return LearnedSegmenter(name, cfg, device)


def _adapter(module: str, cls: str) -> Callable[..., Segmenter]:
    def build(name: str, cfg: SegmenterConfig, device: str, class_names, key: str) -> Segmenter:
        return getattr(importlib.import_module(f"calnav.agent.segmenters.{module}"), cls)(name, cfg, device, key=key)
    return build


# The built-in segmenters (agent.segmenter): name -> builder(name, cfg, device, class_names, key);
# device: the validated device string; key: the segmenter section as the command spells it (for messages).
BUILTIN_SEGMENTERS: Registry[Callable[..., Segmenter]] = Registry("segmenter", key="agent.segmenter")
BUILTIN_SEGMENTERS.add("gt", _ground_truth, "ground truth with a fixed confidence (needs the semantic observation)")
BUILTIN_SEGMENTERS.add("noisy", _ground_truth, "ground truth with a view-correlated, overconfident error model")
BUILTIN_SEGMENTERS.add("learned_rgb", _learned, "calnav's RGB network trained in the simulator")
BUILTIN_SEGMENTERS.add("learned_rgbd", _learned, "calnav's RGB-D network trained in the simulator")
BUILTIN_SEGMENTERS.add("hf", _adapter("hf", "HFSegmenter"), "a transformers model (segmenter.model)")
BUILTIN_SEGMENTERS.add("onnx", _adapter("onnx", "ONNXSegmenter"), "an ONNX model (segmenter.model)")


def _builder(spec: str) -> Callable[..., Segmenter] | None:
    """The built-in builder of ``spec``, or None for a plugin."""
    return BUILTIN_SEGMENTERS.get(spec) if spec in BUILTIN_SEGMENTERS else None


def _entry_points() -> dict:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def check_segmenter_spec(spec: str) -> str:
    """``spec`` if it names a segmenter (a built-in name, an installed ``calnav.segmenters``
    entry point, or the form ``package.module:factory``), without importing anything of it;
    else ValueError listing the choices."""
    if spec in BUILTIN_SEGMENTERS or IMPORT_PATH.match(spec) or spec in _entry_points():
        return spec
    plugins = sorted(_entry_points())
    raise ValueError(f"unknown segmenter {spec!r}; valid: {', '.join(BUILTIN_SEGMENTERS)}"
                     + (f", installed plugins: {', '.join(plugins)}" if plugins else "")
                     + ", or a factory as package.module:function")


def _load_factory(spec: str) -> Callable:
    """The factory of an import path or entry point; ValueError with one line for every failure."""
    try:
        with user_code("its module"):   # importing it runs user code too
            if IMPORT_PATH.match(spec):
                module, _, attr = spec.partition(":")
                factory = getattr(importlib.import_module(module), attr)
            else:
                factory = _entry_points()[spec].load()
    except UserCodeExit as exc:
        raise ValueError(f"segmenter plugin {spec!r} cannot be loaded: {exc}") from None
    except Exception as exc:  # noqa: BLE001 -- any failure of the user's module is reported in one line
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        hint = " (install it, or put its folder on PYTHONPATH)" if isinstance(exc, ModuleNotFoundError) else ""
        raise ValueError(f"segmenter plugin {spec!r} cannot be loaded: {type(exc).__name__}: {first}{hint}") from None
    if not callable(factory):
        raise ValueError(f"segmenter plugin {spec!r} is a {type(factory).__name__}, not a factory function")
    return factory


def segmenter_needs_semantic(spec: str) -> bool:
    """Whether segmenter ``spec`` reads the ground-truth ``semantic`` observation (its class's
    ``needs_semantic``), so a run without that sensor cannot use it."""
    check_segmenter_spec(spec)
    if _builder(spec) is not _ground_truth:
        return False   # networks and plugins read rgb (and depth)
    from calnav.agent.segmenters.ground_truth import GroundTruthSegmenter
    from calnav.agent.segmenters.noisy import NoisySegmenter

    return {"gt": GroundTruthSegmenter, "noisy": NoisySegmenter}[spec].needs_semantic


def check_segmenter(spec: str, cfg: SegmenterConfig | None = None, device: str | None = None,
                    probe_size: tuple[int, int] = (160, 120), goals: tuple[str, ...] = (),
                    key: str = "segmenter") -> tuple[str, ...]:
    """Open and validate everything segmenter ``spec`` will need and return its class names:
    its device (``<key>.device`` when set, else ``device``); the weight file of a learned one
    (tensors must fit its network, its class list calnav's classes); the class list of the
    ground-truth ones; an adapter or plugin is built (its classes matched to calnav's by name)
    and run on one probe frame of ``probe_size`` (W, H) (import errors, factory errors, wrong
    output shape or K, non-finite logits); each of ``goals`` must be a class it predicts
    (ObjectNav). ``key``: the segmenter section
    (``segmenter``), named in the errors. Raises ValueError /
    FileNotFoundError in one line: run before a run writes anything or starts workers."""
    from calnav.agent.segmenters.adapter import check_goals, probe

    cfg = cfg or SegmenterConfig()
    check_segmenter_spec(spec)
    device = segmenter_device(cfg, device, key)
    if _builder(spec) in (_ground_truth, _learned):
        if _builder(spec) is _ground_truth:
            names = default_class_names()
        else:
            from calnav.agent.segmenters.learned import check_weights, default_weights_path

            names = check_weights(cfg.weights or default_weights_path(spec), spec)
        segmenter = type("Checked", (), {"name": spec, "class_names": names})()
    else:
        segmenter = make_segmenter(spec, cfg, device, key=key)
        names = probe(segmenter, probe_size)
    check_goals(segmenter, goals, key)
    return names


def make_segmenter(spec: str, cfg: SegmenterConfig | None = None, device: str | None = None,
                   class_names: tuple[str, ...] | None = None, key: str = "segmenter") -> Segmenter:
    """The segmenter ``spec`` (see the module docstring) configured by ``cfg``.

    device: torch device ("cpu", "cuda", "cuda:N"; the caller's ``run.device``), used when
    ``cfg.device`` is not set (``cfg.device`` wins); None = cpu. A device that is not cpu / cuda,
    or a CUDA device this machine lacks, raises ValueError naming the key. class_names: classes
    of the ground-truth based segmenters (default: ``agent/weights/classes.json``, the
    simulator's list); the others carry theirs (weights file, model, label map), matched to
    calnav's classes by name. key: the segmenter section (``segmenter``), named
    in error messages.
    """
    cfg = cfg or SegmenterConfig()
    check_segmenter_spec(spec)
    dev = segmenter_device(cfg, device, key)
    if spec in BUILTIN_SEGMENTERS:
        return BUILTIN_SEGMENTERS.get(spec)(spec, cfg, dev, class_names, key)
    from calnav.agent.segmenters.adapter import PluginSegmenter

    factory = _load_factory(spec)
    try:
        with user_code("its factory"):   # sys.exit() / its own KeyboardInterrupt -> UserCodeExit; Ctrl-C propagates
            inner = factory(cfg, dev)
    except UserCodeExit as exc:
        raise ValueError(f"segmenter plugin {spec!r}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 -- the user's factory: report it in one line
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise ValueError(f"segmenter plugin {spec!r}: its factory raised {type(exc).__name__}: {first}") from None
    return PluginSegmenter(spec, inner, cfg, dev, key=key)
