"""``calnav map SEQUENCE_DIR --layout scannet|7scenes [--segmenter NAME | --logits DIR]``: fuse a
recorded RGB-D sequence into a ``SemanticVoxelMap`` (any fusion strategy / GLFS parameters:
``mapping.*`` overrides) and score it against a labelled mesh when one is found.

Writes to ``--output``: ``config.yaml``; ``map.npz`` (versioned: ``centres`` (N, 3) float32
voxel centres in metres, ``probs`` (N, K) float32 fused probabilities, meta: class names, voxel
size, frames); ``map.ply`` (one vertex per voxel centre, coloured by its argmax class, with
``label`` and ``confidence`` = top probability properties); and ``results.json`` (frames used,
frames skipped (``skipped_frames``) and why (``skip_reasons``: {reason: frames}, the readers' one
rule, ``mapping.sequences.skips``), seconds, frames/s; with a labelled mesh also mIoU / ECE /
TL-ECE / mECE / Brier over the labelled voxels -- ground truth per voxel = the nearest labelled
vertex within ``sequence.label_distance_m``, others ignored) with ``reliability.png`` and
``reliability_classes.png``; with ``--rerun``, ``map.rrd`` (``eval.sequence.recording``: frames and
poses on a ``frame`` timeline, the map by class and by confidence, correct / wrong voxels and
the labelled mesh). Every input is checked before anything is written.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calnav.eval.results_dir import ResultsDir, writing
from calnav.eval.config import Config
from calnav.common.prefetch import prefetched
from calnav.eval.sequence.source import PrecomputedLogits, SegmenterLogits, fuse_frames, map_frames
from calnav.mapping.sequences import LogitsDir, Sequence, label_map_source, vertex_ground_truth

DEFAULT_CONFIG = "configs/map_sequence.yaml"
MAP_FORMAT_VERSION = 1
# what one run writes besides config.yaml (results.json last: its presence means a finished map)
MAP_FILES: tuple[str, ...] = ("map.npz", "map.ply", "map.rrd", "reliability.png", "reliability_classes.png",
                              "results.json")


@dataclass
class MappedSequence:
    """What ``map_sequence`` returns: the map, frames fused, frame numbers skipped and {reason:
    frame numbers} (``Sequence.skips``), wall seconds of reading + segmenting + fusing."""

    vmap: object
    frames: int
    skipped: list[int] = field(default_factory=list)
    seconds: float = 0.0
    skip_reasons: dict[str, list[int]] = field(default_factory=dict)


def logits_source(seq: Sequence, cfg: Config, segmenter: str | None, logits: str | None,
                  classes: str | None):
    """The per-frame logits of ``--segmenter`` or ``--logits`` (exactly one)."""
    if bool(segmenter) == bool(logits):
        raise ValueError("pass exactly one of --segmenter NAME and --logits DIR")
    if logits:
        return PrecomputedLogits(LogitsDir(logits, seq, classes))
    from calnav.agent.segmenters import make_segmenter

    seg = make_segmenter(segmenter, cfg.segmenter, device=cfg.run.device)
    seq.use_class_names(seg.class_names)   # label-filt/ frames (ScanNet) for gt / noisy
    return SegmenterLogits(seg, seq)


def map_sequence(seq: Sequence, source, mapping_cfg, progress: bool = False, vmap=None,
                 frame_log=None) -> MappedSequence:
    """Fuse every frame of ``seq`` with logits from ``source`` into ``vmap`` (default: a new
    ``SemanticVoxelMap`` of ``mapping_cfg``); ``frame_log`` (``eval.sequence.recording.FrameLog``)
    keeps thumbnails of the frames for ``--rerun``."""
    from calnav.mapping.voxel_map import SemanticVoxelMap

    if vmap is None:
        vmap = SemanticVoxelMap(len(source.class_names), mapping_cfg, class_names=tuple(source.class_names))
    t0 = time.perf_counter()
    frames = prefetched(map_frames(seq, source))
    n = fuse_frames(vmap, frame_log.tap(frames) if frame_log is not None else frames, total=len(seq), progress=progress)
    return MappedSequence(vmap, n, list(seq.skipped), time.perf_counter() - t0, seq.skips.by_reason())


def score(probs: np.ndarray, labels: np.ndarray, num_classes: int):
    """``mapping.metrics.CalibrationStats`` of the labelled voxels (label -1 ignored)."""
    from calnav.mapping import metrics

    return metrics.CalibrationStats(num_classes).update(probs, labels, ignore_index=-1)


def write_map(out: Path, coords: np.ndarray, probs: np.ndarray, class_names, meta: dict) -> None:
    """``map.npz`` and ``map.ply`` (see the module docstring)."""
    from plyfile import PlyData, PlyElement

    from calnav.agent.visualize import class_palette
    from calnav.common.npz import save_versioned_npz

    save_versioned_npz(out / "map.npz", {"centres": coords.astype(np.float32), "probs": probs.astype(np.float32)},
                       {"class_names": list(class_names), **meta}, MAP_FORMAT_VERSION)
    label = probs.argmax(axis=1) if len(probs) else np.zeros(0, np.int64)
    colours = class_palette(len(class_names))[label]
    v = np.empty(len(coords), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"),
                                     ("blue", "u1"), ("label", "u2"), ("confidence", "f4")])
    v["x"], v["y"], v["z"] = coords.T
    v["red"], v["green"], v["blue"] = colours.T
    v["label"] = label
    v["confidence"] = probs.max(axis=1) if len(probs) else np.zeros(0)
    PlyData([PlyElement.describe(v, "vertex")]).write(str(out / "map.ply"))


def map_configs(args) -> list[Config]:
    """The config ``calnav map`` runs (its sections: ``eval.config.MAP_SECTIONS``)."""
    from calnav.eval.shorthands import load_command_config

    return [load_command_config(args, config=args.config or DEFAULT_CONFIG)]


def main_map(args, configs: list[Config]) -> None:
    """``configs``: ``map_configs(args)``, checked by the preflight."""
    cfg = configs[0]
    frame_log = None
    if getattr(args, "rerun", False):
        from calnav.common.rerun_io import require_rerun
        from calnav.eval.sequence.recording import FrameLog

        require_rerun("--rerun")   # the install command, before anything is read or written
        frame_log = FrameLog()
    seq = Sequence(args.sequence_dir, args.layout, cfg.sequence)
    seq.check_scale(cfg.mapping.depth_min_m, cfg.mapping.depth_max_m, cfg.mapping.voxel_size_m)   # units, frame
    source = logits_source(seq, cfg, args.segmenter, args.logits, args.classes)
    names = tuple(source.class_names)
    ply = Path(args.labels_ply) if args.labels_ply else seq.labelled_ply()
    gt = vertex_ground_truth(ply, names, cfg.sequence, seq.root) if ply is not None else None
    from calnav.mapping.voxel_map import SemanticVoxelMap

    vmap = SemanticVoxelMap(len(names), cfg.mapping, class_names=names)   # GLFS parameter file / K checked here
    out = Path(args.output)
    # the results directory's owner: a lock (a second run into it is refused), the config check
    # (another config is refused unless --force), and no file of an earlier run left beside this one
    results_dir = ResultsDir(out, cfg, force=args.force, discard=MAP_FILES, files=MAP_FILES)
    results_dir.check()   # refused now rather than after the fusion, and nothing written yet
    # every frame is read (and its problems named) while fusing in memory, before anything is written
    res = map_sequence(seq, source, cfg.mapping, progress=True, vmap=vmap, frame_log=frame_log)
    coords, probs = res.vmap.voxels()
    labels = check_map(seq, res, cfg, coords, ply, gt)   # an empty or unscorable map is refused, unwritten
    with results_dir:
        for name in MAP_FILES:
            (out / name).unlink(missing_ok=True)
        with writing(out):
            _write_results(out, cfg, seq, res, names, ply, gt, args, coords, probs, labels, frame_log)


def check_map(seq: Sequence, res: MappedSequence, cfg: Config, coords: np.ndarray, ply, gt
              ) -> np.ndarray | None:
    """The ground-truth label of each voxel ((N,) int, -1 = none within
    ``sequence.label_distance_m``; None without a labelled mesh), after refusing (ValueError,
    one line) a map that holds no voxel, or, with a labelled mesh, no labelled voxel: its
    metrics would be NaN, not numbers, and its files a map of nothing."""
    from calnav.mapping.ground_truth import nearest_vertex_labels

    m = cfg.mapping
    if len(coords) == 0:
        raise ValueError(f"{seq.name}: the map holds no voxels after fusing {res.frames} frames "
                         f"(mapping.voxel_size_m {m.voxel_size_m:g} m, depth {m.depth_min_m:g}-{m.depth_max_m:g} m): "
                         "no surface was reconstructed, nothing is written; check mapping.voxel_size_m and "
                         "mapping.depth_min_m / depth_max_m against the recording's scale and depth")
    if gt is None:
        return None
    labels = nearest_vertex_labels(coords, *gt, cfg.sequence.label_distance_m)
    if not (labels >= 0).any():
        raise ValueError(f"{seq.name}: none of the map's {len(coords)} voxels lies within sequence.label_distance_m "
                         f"({cfg.sequence.label_distance_m:g} m) of a labelled vertex of {ply}: there is nothing to "
                         "score, nothing is written; check that the mesh is this sequence's (same frame)")
    return labels


def _write_results(out: Path, cfg, seq, res: MappedSequence, names, ply, gt, args, coords: np.ndarray,
                   probs: np.ndarray, labels: np.ndarray | None, frame_log=None) -> None:
    from calnav.common.atomic import write_json_atomic

    meta = {"sequence": str(seq.root), "layout": seq.layout, "voxel_size_m": cfg.mapping.voxel_size_m,
            "fusion": cfg.mapping.fusion, "frames": res.frames, "skipped_frames": res.skipped,
            "skip_reasons": res.skip_reasons}
    write_map(out, coords, probs, names, meta)
    results = {**meta, "seconds": res.seconds, "frames_per_s": res.frames / max(res.seconds, 1e-9),
               "voxels": int(len(coords)), "segmenter": args.segmenter or "", "logits": args.logits or ""}
    if gt is not None:
        from calnav.eval.calibration.plots import plot_reliability, plot_reliability_per_class

        stats = score(probs, labels, len(names))
        results.update({"labels_ply": str(ply), "label_map": label_map_source(cfg.sequence, seq.root, ply),
                        "labelled_voxels": int((labels >= 0).sum()), "miou": stats.miou(),
                        "ece": stats.ece(), "tl_ece": stats.tl_ece(), "mece": stats.mece(), "brier": stats.brier()})
        table = {cfg.mapping.fusion: stats.reliability()}
        plot_reliability(table, out / "reliability.png", title=f"{seq.name} ({stats.n} labelled voxels)")
        plot_reliability_per_class(table, names, out / "reliability_classes.png")
    if frame_log is not None:
        from calnav.eval.sequence.recording import write_map_recording

        write_map_recording(out / "map.rrd", frame_log, coords, probs, names, cfg.mapping.voxel_size_m,
                            labels=labels if gt is not None else None, ply=ply, gt=gt)
    write_json_atomic(out / "results.json", results, indent=1)
    skipped = f" ({len(res.skipped)} skipped: {seq.skip_summary()})" if res.skipped else ""
    print(f"{seq.name}: {res.frames} frames fused{skipped} in {res.seconds:.1f} s "
          f"({results['frames_per_s']:.1f} frames/s), {len(coords)} voxels")
    if gt is not None:
        print("  ".join(f"{k} {results[k]:.4f}" for k in ("miou", "ece", "tl_ece", "mece", "brier"))
              + f"  ({results['labelled_voxels']} labelled voxels; ground truth through label map "
                f"{results['label_map']})")
    print(f"wrote {out / 'map.npz'}, {out / 'map.ply'}, {out / 'results.json'}"
          + (f", {out / 'map.rrd'} (calnav view {out / 'map.rrd'})" if frame_log is not None else ""))
