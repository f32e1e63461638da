"""Frames of a recorded sequence made ready to fuse: registered to the depth camera, segmented
(a calnav segmenter by name, or precomputed logits) and decoded ahead of the map in a
background thread (``common.prefetch``); the one fusion loop (``fuse_frames``) used by
``calnav map``, the bench and the round-trip test. The recorded-sequence frame source of
``calnav calibrate-map --sequences`` is ``eval.calibration.record.RecordedScan``.
"""
from __future__ import annotations

from typing import Iterable, Iterator

import numpy as np

from calnav.mapping.frame import SegmentedFrame
from calnav.mapping.sequences import LogitsDir, Registration, Sequence, SequenceFrame


class SegmenterLogits:
    """Logits from a calnav segmenter run on the registered frame."""

    def __init__(self, segmenter, seq: Sequence):
        if segmenter.needs_semantic and not seq.has_semantic:
            raise ValueError(f"segmenter {segmenter.name!r} needs ground-truth semantic frames (semantic/N.png), "
                             f"{seq.root} has none; use a learned segmenter or --logits")
        self.segmenter = segmenter
        self.class_names = tuple(segmenter.class_names)

    def __call__(self, frame: SequenceFrame, rgb: np.ndarray, semantic, reg: Registration) -> np.ndarray:
        k = len(self.class_names)
        if self.segmenter.needs_semantic and semantic is not None and semantic.max(initial=-1) >= k:
            # raw dataset ids where class indices belong: every pixel would be void, the map empty of them
            raise ValueError(f"frame {frame.index}: its semantic frame holds class id {int(semantic.max())}, past the "
                             f"{k} classes ({', '.join(self.class_names[:3])}, ...): semantic/N.png stores class index "
                             "+ 1 (0 = void); raw dataset ids go in label-filt/N.png with sequence.frame_label_map")
        return self.segmenter.segment(rgb, frame.depth, semantic=semantic, pose=frame.pose)


class PrecomputedLogits:
    """Logits read from a ``LogitsDir`` and registered to the depth camera when at colour size."""

    def __init__(self, logits: LogitsDir):
        self.logits = logits
        self.class_names = logits.class_names

    def __call__(self, frame: SequenceFrame, rgb: np.ndarray, semantic, reg: Registration) -> np.ndarray:
        arr = self.logits.get(frame.index)
        depth_hw = frame.depth.shape
        return arr if arr.shape[:2] == depth_hw else reg.logits(arr)


def map_frames(seq: Sequence, logits_source) -> Iterator[SegmentedFrame]:
    """The sequence's frames registered to the depth camera and segmented (invalid poses skipped)."""
    reg = Registration(seq.k_color, seq.color_size, seq.k_depth, seq.depth_size)
    for fr in seq.frames():
        rgb = reg.rgb(fr.rgb)
        sem = None if fr.semantic is None else reg.labels(fr.semantic)
        yield SegmentedFrame(fr.depth, fr.k_depth, logits_source(fr, rgb, sem, reg), rgb, fr.pose, sem, fr.index)


def fuse_frames(vmap, frames: Iterable[SegmentedFrame], total: int | None = None, progress: bool = False) -> int:
    """Integrate every frame into ``vmap`` (a ``SemanticVoxelMap``); returns the frame count."""
    from tqdm import tqdm

    n = 0
    for f in tqdm(frames, total=total, desc="map", unit="frame", disable=not progress):
        try:
            vmap.integrate(f.depth, f.k, f.pose, f.logits, f.rgb)
        except ValueError as exc:
            raise ValueError(f"frame {f.index}: {exc}") from exc
        n += 1
    return n
