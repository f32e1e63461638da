"""`calnav eval-segmenter`: pixel accuracy, mIoU and calibration of a segmenter on held-out frames.

    calnav eval-segmenter --segmenter learned_rgb --split test --frames 500 --output runs/seg_rgb.json

Frames: ``--frames`` frames rendered from ``--split``'s houses (default: test, never seen in
training) with the pose seed ``data.seed + EVAL_SEED_OFFSET`` (different walks from the
training ones), at ``data.resolution``. Every non-void pixel is a sample; probabilities are
softmax(logits). Metrics (``mapping.metrics``): accuracy, mIoU over all classes present in the
labels and over the goal categories + structure classes present, ECE, TL-ECE, mECE, Brier,
per-class IoU and per-class ECE, mean top-label confidence, and each house's (K_pred, K_true)
confusion counts (``scene_confusion``, for paired house-level standard errors of a difference
between two records of the same frames: ``eval.segmenter.ablation``). ``data.eval_appearance: camera``
scores the same frames through the fixed camera shift of ``eval.segmenter.appearance``;
``recolour`` the same poses in the houses with every instance recoloured (the record names the
shift).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from calnav.common.atomic import undefined_as_null, write_json_atomic
from calnav.eval.results_dir import check_output_file, writing
from calnav.eval.config import Config
from calnav.eval.inputs import sha256_file
from calnav.eval.segmenter.appearance import camera_shift
from calnav.eval.segmenter.data import EVAL_SEED_OFFSET, load_or_render
from calnav.mapping.metrics import CalibrationStats
from dataclasses import dataclass
from typing import Literal
from calnav.eval.arguments import REQUIRED, Command, arg
from calnav.eval.config import SEGMENTER_SECTIONS
from calnav.eval.segmenter.data import segmenter_configs

BATCH = 16                     # frames per segment_batch call
CAMERA_SEED_OFFSET = 7919      # the camera shift's seed family: pose seed + this (no training stream uses it)


def evaluate(cfg: Config, model: str, split: str = "test", frames: int = 500,
             progress: bool = True) -> dict:
    """Score segmenter ``model`` on ``frames`` frames of ``split``; returns the metrics dict."""
    from tqdm import tqdm

    from calnav.agent.segmenters import make_segmenter, softmax
    from calnav.envs.semantics import CLASS_NAMES, GOAL_CATEGORIES, STRUCTURE_CLASSES

    if frames < 1:
        raise ValueError(f"--frames must be >= 1, got {frames}")
    seg = make_segmenter(model, cfg.segmenter, cfg.segmenter.device or cfg.run.device, class_names=CLASS_NAMES)
    if tuple(seg.class_names) != tuple(CLASS_NAMES):
        raise ValueError(f"{model} predicts classes {seg.class_names}, the simulator has {CLASS_NAMES}")
    data = load_or_render(cfg.env, cfg.data, split, frames=frames, seed=cfg.data.seed + EVAL_SEED_OFFSET,
                          with_instance=seg.needs_semantic, progress=progress,
                          recolour_all=cfg.data.eval_appearance == "recolour")
    if cfg.data.eval_appearance == "camera":   # after the cache: the rendered frames are shared with plain runs
        data.rgb = camera_shift(data.rgb, cfg.data.seed + EVAL_SEED_OFFSET + CAMERA_SEED_OFFSET)
    k = len(CLASS_NAMES)
    stats = CalibrationStats(k)
    n_scenes = int(data.scene.max()) + 1
    scene_conf = np.zeros(n_scenes * k * k, np.int64)   # (scene, pred, label) counts, flattened
    conf_sum = 0.0
    t0 = time.perf_counter()
    for start in tqdm(range(0, len(data), BATCH), desc=f"eval {model}", disable=not progress):
        sl = slice(start, start + BATCH)
        depth = data.depth[sl].astype(np.float32)
        extra = {}
        if seg.needs_semantic:
            extra = {"semantic": data.labels[sl], "instance": data.instance[sl], "poses": data.poses[sl].astype(np.float64)}
        probs = softmax(seg.segment_batch(data.rgb[sl], depth, **extra)).reshape(-1, k)
        labels = data.labels[sl].reshape(-1).astype(np.int64)
        stats.update(probs, labels, ignore_index=-1)
        valid = labels >= 0
        scene = np.repeat(data.scene[sl].astype(np.int64), labels.size // len(data.scene[sl]))
        scene_conf += np.bincount(((scene * k + probs.argmax(axis=1)) * k + labels)[valid], minlength=scene_conf.size)
        conf_sum += float(probs[valid].max(axis=1).sum())
    seconds = time.perf_counter() - t0
    goal_structure = [CLASS_NAMES.index(n) for n in (*GOAL_CATEGORIES, *STRUCTURE_CLASSES)]
    iou, cece = stats.per_class_iou(), stats.per_class_ece()
    present = [CLASS_NAMES[i] for i in range(k) if np.isfinite(iou[i])]
    shift = {} if cfg.data.eval_appearance == "none" else {"eval_appearance": cfg.data.eval_appearance}
    return {
        "model": model, "split": split, **shift, "n_frames": len(data), "resolution": list(data.resolution),
        "n_pixels": stats.n, "accuracy": stats.accuracy(),
        "miou": stats.miou(), "miou_goal_structure": stats.miou(goal_structure),
        "ece": stats.ece(), "tl_ece": stats.tl_ece(), "mece": stats.mece(), "brier": stats.brier(),
        "mean_confidence": conf_sum / max(stats.n, 1),
        "classes_in_miou": present,
        "classes_in_miou_goal_structure": [n for n in present if CLASS_NAMES.index(n) in goal_structure],
        "per_class_iou": {CLASS_NAMES[i]: (float(iou[i]) if np.isfinite(iou[i]) else None) for i in range(k)},
        "per_class_ece": {CLASS_NAMES[i]: (float(cece[i]) if np.isfinite(cece[i]) else None) for i in range(k)},
        "pose_seed": cfg.data.seed + EVAL_SEED_OFFSET, "segment_ms_per_frame": 1e3 * seconds / len(data),
        "weights": str(getattr(seg, "weights_path", "")),
        "weights_sha256": _weights_sha256(seg),
        "frames_sha256": frames_sha256(data),
        # per house of the split (data.scene's index): the paired house-level error of a difference
        "scene_confusion": scene_conf.reshape(n_scenes, k, k).tolist(),
    }


def frames_sha256(data) -> str:
    """sha256 of the scored frames' rgb, depth and labels, as scored (after any camera shift):
    two records scored the same frames only when it agrees. Frames of scanned houses are derived
    data (a scan made on another machine can differ), so the cache key alone does not say."""
    import hashlib

    h = hashlib.sha256()
    for a in (data.rgb, data.depth, data.labels):
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _weights_sha256(seg) -> str | None:
    """sha256 of the weights file a record scores (None for segmenters without one), so a
    record names the weights it scores, not just their path (a path can be overwritten)."""
    path = getattr(seg, "weights_path", None)
    return sha256_file(Path(path)) if path and Path(path).is_file() else None


def format_report(m: dict) -> str:
    lines = [f"{m['model']} on {m['n_frames']} {m['split']} frames ({m['resolution'][0]}x{m['resolution'][1]}, "
             f"{m['n_pixels']} labelled pixels)"]
    for key in ("accuracy", "miou", "miou_goal_structure", "ece", "tl_ece", "mece", "brier", "mean_confidence"):
        lines.append(f"  {key:<20} {m[key]:.4f}")
    lines.append("  per-class IoU: " + ", ".join(f"{n} {v:.3f}" for n, v in m["per_class_iou"].items() if v is not None))
    return "\n".join(lines)


def main_eval_segmenter(args, configs: list[Config]) -> None:
    """``configs``: ``eval.segmenter.data.segmenter_configs(args)``, checked by the preflight."""
    cfg = configs[0]
    if args.output:
        check_output_file(args.output)
    metrics = evaluate(cfg, args.segmenter, args.split, args.frames)
    print(format_report(metrics))
    if args.output:
        out = Path(args.output)
        with writing(out):
            out.parent.mkdir(parents=True, exist_ok=True)
            write_json_atomic(out, undefined_as_null(metrics), indent=1)
        print(f"wrote {out}")


@dataclass
class EvalSegmenterArgs:
    """``calnav eval-segmenter``'s flags."""

    segmenter: str = arg(REQUIRED, "segmenter to score: gt | noisy | learned_rgb | learned_rgbd | hf | onnx | "
                                   "package.module:factory | a calnav.segmenters plugin (configured by the segmenter "
                                   "section)", metavar="SEGMENTER")
    split: Literal["train", "val", "test"] = arg("test", "split whose houses are rendered")
    frames: int = arg(500, "number of frames scored")   # >= 1: evaluate() checks it
    output: str | None = arg(None, "metrics JSON path (default: print only)")


COMMAND = Command(EvalSegmenterArgs, main_eval_segmenter, segmenter_configs, config="configs/segmenter.yaml",
                  sections=SEGMENTER_SECTIONS)
