"""Frames of a recorded sequence made ready to fuse: registered to the depth camera, segmented
(a calnav segmenter by name, or precomputed logits) and decoded ahead of the map in a
background thread; the one fusion loop (``fuse_frames``) used by ``calnav map``, the bench and
the round-trip test; and ``RecordedScan``, the recorded-sequence frame source of
``calnav calibrate-map --sequences`` (``eval.calibration.record.HouseScan`` is the house one).
"""
from __future__ import annotations

import itertools
import queue
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from mapping.sequences import LAYOUT_NAMES, LogitsDir, Registration, Sequence, SequenceFrame, vertex_ground_truth

PREFETCH_FRAMES = 2     # frames decoded ahead of the map (bounded: memory does not grow with the recording)
ROLES = ("calib_train", "calib_val", "test")


@dataclass
class MapFrame:
    """One frame at the depth camera, ready for ``SemanticVoxelMap.integrate``: index (frame
    number), depth (h, w) float32 m, k (3, 3), pose (4, 4) world-from-camera, logits (h, w, K)
    float32, rgb (h, w, 3) uint8, semantic (h, w) int class ids (-1 void) or None."""

    index: int
    depth: np.ndarray
    k: np.ndarray
    pose: np.ndarray
    logits: np.ndarray
    rgb: np.ndarray
    semantic: np.ndarray | None = None


class SegmenterLogits:
    """Logits from a calnav segmenter run on the registered frame."""

    def __init__(self, segmenter, seq: Sequence):
        if segmenter.needs_semantic and not seq.has_semantic:
            raise ValueError(f"segmenter {segmenter.name!r} needs ground-truth semantic frames (semantic/N.png), "
                             f"{seq.root} has none; use a learned segmenter or --logits")
        self.segmenter = segmenter
        self.class_names = tuple(segmenter.class_names)

    def __call__(self, frame: SequenceFrame, rgb: np.ndarray, semantic, reg: Registration) -> np.ndarray:
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


def prefetched(items: Iterable, depth: int = PREFETCH_FRAMES) -> Iterator:
    """``items`` produced by a background thread at most ``depth`` ahead (image decoding and
    Open3D release the GIL, so decoding overlaps fusion); exceptions are re-raised here."""
    q: queue.Queue = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def work():
        try:
            for item in items:
                if stop.is_set():
                    return
                q.put((True, item))
            q.put((True, done))
        except BaseException as exc:   # re-raised in the consumer
            q.put((False, exc))

    thread = threading.Thread(target=work, daemon=True)
    thread.start()
    try:
        while True:
            ok, item = q.get()
            if not ok:
                raise item
            if item is done:
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():   # unblock a producer waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                thread.join(0.01)


def map_frames(seq: Sequence, logits_source) -> Iterator[MapFrame]:
    """The sequence's frames at the depth camera with their logits (invalid poses skipped)."""
    reg = Registration(seq.k_color, seq.color_size, seq.k_depth, seq.depth_size)
    for fr in seq.frames():
        rgb = reg.rgb(fr.rgb)
        sem = None if fr.semantic is None else reg.labels(fr.semantic)
        yield MapFrame(fr.index, fr.depth, fr.k_depth, fr.pose, logits_source(fr, rgb, sem, reg), rgb, sem)


def fuse_frames(vmap, frames: Iterable[MapFrame], total: int | None = None, progress: bool = False) -> int:
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


# ---------------------------------------------------------------- calibrate-map
def read_sequence_list(path, default_layout: str = "scannet") -> dict[str, list[tuple[str, Path, str]]]:
    """{role: [(sequence id, directory, layout)]} of a list file: one ``<role> <dir> [layout]``
    per line (``#`` comments; relative directories are relative to the list file). The id is
    the directory name and must be unique."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"sequence list not found: {path}")
    out: dict[str, list] = {r: [] for r in ROLES}
    seen: set[str] = set()
    for n, line in enumerate(path.read_text().splitlines(), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        if len(parts) not in (2, 3) or parts[0] not in ROLES:
            raise ValueError(f"{path}:{n}: expected '<role> <dir> [layout]' with role one of {', '.join(ROLES)}, "
                             f"got {line.strip()!r}")
        layout = parts[2] if len(parts) == 3 else default_layout
        if layout not in LAYOUT_NAMES:
            raise ValueError(f"{path}:{n}: unknown layout {layout!r}; valid layouts: {', '.join(LAYOUT_NAMES)}")
        folder = Path(parts[1]) if Path(parts[1]).is_absolute() else path.parent / parts[1]
        if not folder.is_dir():
            raise ValueError(f"{path}:{n}: sequence directory not found: {folder}")
        sid = folder.resolve().name
        if sid in seen:
            raise ValueError(f"{path}:{n}: a second sequence named {sid!r} (ids are directory names)")
        seen.add(sid)
        out[parts[0]].append((sid, folder, layout))
    return out


class RecordedScan:
    """A recorded sequence as a calibrate-map frame source (the interface of
    ``eval.calibration.record.HouseScan``): frames registered to the depth camera; voxel labels
    from the labelled PLY by nearest vertex."""

    def __init__(self, seq: Sequence, class_names: tuple[str, ...]):
        self.seq, self.class_names = seq, tuple(class_names)
        seq.use_class_names(self.class_names)   # 2D labels from ScanNet's label-filt/ when mapped
        self.intrinsics = seq.k_depth
        self.ply = seq.labelled_ply()
        if self.ply is None:
            raise ValueError(f"{seq.root} has no labelled mesh (*_vh_clean_2.labels.ply) to label its voxels")
        self.vertices, self.vertex_class = vertex_ground_truth(self.ply, self.class_names, seq.cfg, seq.root)

    def __len__(self) -> int:
        return len(self.seq)

    def batches(self, size: int):
        reg = Registration(self.seq.k_color, self.seq.color_size, self.seq.k_depth, self.seq.depth_size)
        batch: list[SequenceFrame] = []
        frames = prefetched(self.seq.frames())
        for fr in itertools.chain(frames, [None]):   # None: flush the last batch
            if fr is not None:
                batch.append(fr)
            if batch and (fr is None or len(batch) == size):
                w, h = self.seq.depth_size
                sem = [np.full((h, w), -1) if f.semantic is None else reg.labels(f.semantic) for f in batch]
                yield (np.stack([reg.rgb(f.rgb) for f in batch]), np.stack([f.depth for f in batch]),
                       np.stack(sem).astype(np.int16), np.stack([f.pose for f in batch]))
                batch = []

    def label(self, cache) -> None:
        from mapping.ground_truth import nearest_vertex_labels

        cache.set_labels(nearest_vertex_labels(cache.coords, self.vertices, self.vertex_class,
                                               self.seq.cfg.label_distance_m))


def recorded_scan(cfg, scene_id: str) -> RecordedScan | None:
    """The ``RecordedScan`` of ``scene_id`` when ``cfg.sequences.list`` lists it, else None."""
    from agent.segmenters.base import default_class_names

    if not cfg.sequences.list:
        return None
    for entries in read_sequence_list(cfg.sequences.list, cfg.sequences.layout).values():
        for sid, folder, layout in entries:
            if sid == scene_id:
                return RecordedScan(Sequence(folder, layout, cfg.sequence), default_class_names())
    return None
