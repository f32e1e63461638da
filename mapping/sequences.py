"""Recorded RGB-D sequences as a stream of posed frames (``SequenceFrame``), one reader per layout:

- ``scannet`` (ScanNet's SensReader export): ``color/N.jpg`` (1296x968), ``depth/N.png``
  (uint16, 640x480), ``pose/N.txt`` (4x4 camera-to-world), ``intrinsic/intrinsic_color.txt`` and
  ``intrinsic/intrinsic_depth.txt`` (4x4; the top-left 3x3 is K). Optional: ``semantic/N.png``
  (uint16 class id + 1, 0 = void, at colour resolution; written by ``calnav export-sequence``).
  Ground truth: ``<scene>_vh_clean_2.labels.ply`` (per-vertex ``label``, NYU40 ids on ScanNet).
- ``7scenes`` (7-Scenes / 3DMatch): ``frame-NNNNNN.color.{png,jpg}``, ``frame-NNNNNN.depth.png``
  (uint16 millimetres, 0 = missing, 65535 = invalid), ``frame-NNNNNN.pose.txt`` and
  ``camera-intrinsics.txt`` (3x3, in the sequence folder or its parent; colour and depth share it,
  as in 3DMatch -- 7-Scenes' own colour is not registered to its depth: colours and colour-based
  logits are then off by the sensors' baseline, a few pixels).

Every reader streams: ``Sequence.frames()`` decodes one frame at a time, so memory does not grow
with the recording. Frames whose pose is not finite (ScanNet writes rows of ``-inf`` where
tracking failed) are skipped and listed in ``Sequence.skipped``; a clearly non-rigid pose
raises ValueError naming the frame; nearly rigid ones are re-orthonormalised
(``frame_geometry.check_pose``). Depth: raw / ``depth_scale`` metres, raw 0 and
``invalid_depth_raw`` set to 0 (invalid), depth beyond ``depth_trunc_m`` set to 0.

Colour and depth may differ in resolution (ScanNet): ``Registration`` resamples colour-camera
images (rgb, labels, logits) onto the depth camera through the two intrinsics -- a depth pixel
(u, v) reads the colour image at K_c K_d^-1 (u, v, 1) (the cameras share their optical centre,
as in ScanNet's registered export). rgb is resampled bilinearly with ``cv2.remap``; class
labels and logits by nearest neighbour (an index gather: any K, no blending of label ids);
pixels falling outside the colour image get void / all-zero (uniform) logits. ``cv2.resize``
is not used: it assumes the principal points scale with the image size, which ScanNet's do not.
"""
from __future__ import annotations

import json
import re
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Literal

import cv2
import numpy as np

from mapping import frame_geometry as fg

LayoutName = Literal["scannet", "7scenes"]
LAYOUT_NAMES: tuple[str, ...] = LayoutName.__args__  # type: ignore[attr-defined]
SCANNET_EXPECTED = "color/N.jpg, depth/N.png, pose/N.txt, intrinsic/intrinsic_color.txt, intrinsic/intrinsic_depth.txt"
SEVEN_EXPECTED = "frame-NNNNNN.color.png|jpg, frame-NNNNNN.depth.png, frame-NNNNNN.pose.txt, camera-intrinsics.txt"
SEVEN_FRAME = re.compile(r"^frame-(\d+)\.depth\.png$")
VOID = -1
SEMANTIC_OFFSET = 1   # semantic PNGs store class id + 1 (0 = void) in uint16


@dataclass
class SequenceConfig:
    """How a recorded sequence is read (YAML section ``sequence``)."""

    depth_scale: float = 1000.0      # raw depth units per metre (ScanNet / 7-Scenes: millimetres -> 1000)
    depth_trunc_m: float = 0.0       # depth beyond this is invalid, metres; 0 = no truncation (mapping.depth_max_m still applies)
    invalid_depth_raw: int = 65535   # raw depth value that means invalid besides 0 (7-Scenes: 65535), raw units
    frame_stride: int = 1            # use every N-th frame of the recording, frames
    max_frames: int = 0              # use at most this many frames (after the stride); 0 = all, frames
    label_distance_m: float = 0.05   # voxel ground truth: nearest labelled vertex within this distance, metres
    label_map: str = ""              # raw PLY label -> class name (.json / .tsv / .csv); "" = <seq>/label_map.json if present, else NYU40 names
    label_property: str = "label"    # integer vertex property of the labelled PLY holding the raw label

    def __post_init__(self) -> None:
        if not self.depth_scale > 0:
            raise ValueError(f"sequence.depth_scale must be > 0, got {self.depth_scale}")
        if self.depth_trunc_m < 0 or self.max_frames < 0:
            raise ValueError("sequence.depth_trunc_m and sequence.max_frames must be >= 0")
        if self.frame_stride < 1:
            raise ValueError(f"sequence.frame_stride must be >= 1, got {self.frame_stride}")
        if not self.label_distance_m > 0:
            raise ValueError(f"sequence.label_distance_m must be > 0, got {self.label_distance_m}")


@dataclass
class SequenceFrame:
    """One posed RGB-D frame. index: frame number in the recording; rgb (H, W, 3) uint8 at the
    colour camera; depth (h, w) float32 metres (0 = invalid) at the depth camera; k_color /
    k_depth (3, 3) float64 pixels; pose (4, 4) float64 camera-to-world, OpenCV axes (rigid);
    semantic (H, W) int64 class ids (-1 void) at the colour camera, or None."""

    index: int
    rgb: np.ndarray
    depth: np.ndarray
    k_color: np.ndarray
    k_depth: np.ndarray
    pose: np.ndarray
    semantic: np.ndarray | None = None


def read_intrinsics(path: Path) -> np.ndarray:
    """(3, 3) float64 K from a 3x3 or 4x4 text matrix."""
    if not path.exists():
        raise ValueError(f"missing intrinsics: {path} not found")
    try:
        m = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"unreadable intrinsics {path}: {exc}") from exc
    if m.shape not in ((3, 3), (4, 4)):
        raise ValueError(f"intrinsics {path} must be a 3x3 or 4x4 matrix, got shape {m.shape}")
    try:
        return fg.check_intrinsics(m[:3, :3])
    except ValueError as exc:
        raise ValueError(f"intrinsics {path}: {exc}") from exc


def depth_from_raw(raw: np.ndarray, cfg: SequenceConfig) -> np.ndarray:
    """(h, w) float32 metres of a raw uint16 depth image: raw / depth_scale; raw 0 and
    ``invalid_depth_raw`` -> 0, beyond ``depth_trunc_m`` (when > 0) -> 0."""
    depth = raw.astype(np.float32) * np.float32(1.0 / cfg.depth_scale)
    bad = (raw == 0) | (raw == cfg.invalid_depth_raw)
    if cfg.depth_trunc_m > 0:
        bad |= depth > cfg.depth_trunc_m
    depth[bad] = 0.0
    return depth


def _imread(path: Path, flags: int) -> np.ndarray:
    img = cv2.imread(str(path), flags)
    if img is None:
        raise ValueError(f"cannot decode image {path}")
    return img


class Sequence:
    """An opened (validated) recording: ``ids`` the frame numbers used (stride, max_frames,
    valid pose), ``skipped`` those dropped for a non-finite pose; ``frames()`` yields
    ``SequenceFrame`` one at a time. Every pose is checked when the sequence is opened."""

    def __init__(self, root, layout: str, cfg: SequenceConfig | None = None):
        self.root = root = Path(root)
        self.cfg = cfg = cfg or SequenceConfig()
        if layout not in LAYOUT_NAMES:
            raise ValueError(f"unknown sequence layout {layout!r}; valid layouts: {', '.join(LAYOUT_NAMES)}")
        if not root.is_dir():
            raise ValueError(f"sequence directory not found: {root}")
        self.layout = layout
        ids, self._paths, self.k_color, self.k_depth = (_open_scannet if layout == "scannet" else _open_7scenes)(root)
        ids = ids[::cfg.frame_stride]
        ids = ids[:cfg.max_frames] if cfg.max_frames else ids
        # every pose is read up front (small text files: ~0.1 ms each), so a non-rigid pose is
        # reported before anything is written and the invalid ones are known
        self._poses = {i: self._read_pose(i) for i in ids}
        self.skipped = [i for i in ids if self._poses[i] is None]
        self.ids = [i for i in ids if self._poses[i] is not None]
        if not self.ids:
            raise ValueError(f"{root}: no frames to read ({len(ids)} after frame_stride {cfg.frame_stride} / max_frames "
                             f"{cfg.max_frames}, {len(self.skipped)} of them with an invalid pose)")
        first = self.ids[0]
        rgb = _imread(self._paths(first)["color"], cv2.IMREAD_COLOR)
        depth = _imread(self._paths(first)["depth"], cv2.IMREAD_UNCHANGED)
        if depth.ndim != 2 or depth.dtype != np.uint16:
            raise ValueError(f"depth {self._paths(first)['depth']} must be a single-channel 16-bit PNG, "
                             f"got {depth.dtype} with shape {depth.shape}")
        self.color_size = (rgb.shape[1], rgb.shape[0])    # (W, H) pixels
        self.depth_size = (depth.shape[1], depth.shape[0])
        self.has_semantic = self._paths(first).get("semantic") is not None

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def name(self) -> str:
        return self.root.name

    def labelled_ply(self) -> Path | None:
        """The ground-truth mesh in the sequence directory (``*_vh_clean_2.labels.ply``, else
        ``*.labels.ply``), or None."""
        for pattern in ("*_vh_clean_2.labels.ply", "*.labels.ply"):
            found = sorted(self.root.glob(pattern))
            if found:
                return found[0]
        return None

    def _read_pose(self, index: int) -> np.ndarray | None:
        """Rigid (4, 4) pose of frame ``index``; None when not finite; ValueError naming the
        frame when unreadable or not rigid."""
        path = self._paths(index)["pose"]
        try:
            pose = np.loadtxt(path, dtype=np.float64, ndmin=2)
        except ValueError as exc:
            raise ValueError(f"frame {index}: unreadable pose {path}: {exc}") from exc
        if pose.shape != (4, 4):
            raise ValueError(f"frame {index}: pose {path} must be 4x4, got shape {pose.shape}")
        if not np.isfinite(pose).all():   # ScanNet: -inf rows where tracking failed
            return None
        try:
            return fg.check_pose(pose)
        except ValueError as exc:
            raise ValueError(f"frame {index} ({path}): {exc}") from exc

    def read(self, index: int) -> SequenceFrame:
        """Frame ``index`` (one of ``ids``)."""
        paths = self._paths(index)
        pose = self._poses[index]
        raw = _imread(paths["depth"], cv2.IMREAD_UNCHANGED)
        if (raw.shape[1], raw.shape[0]) != self.depth_size:
            raise ValueError(f"frame {index}: depth is {raw.shape[1]}x{raw.shape[0]}, the sequence's is "
                             f"{self.depth_size[0]}x{self.depth_size[1]}")
        depth = depth_from_raw(raw, self.cfg)
        rgb = cv2.cvtColor(_imread(paths["color"], cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        if (rgb.shape[1], rgb.shape[0]) != self.color_size:
            raise ValueError(f"frame {index}: colour is {rgb.shape[1]}x{rgb.shape[0]}, the sequence's is "
                             f"{self.color_size[0]}x{self.color_size[1]}")
        sem = None
        if paths.get("semantic") is not None:
            sem = _imread(paths["semantic"], cv2.IMREAD_UNCHANGED).astype(np.int64) - SEMANTIC_OFFSET
        return SequenceFrame(index, rgb, depth, self.k_color, self.k_depth, pose, sem)

    def frames(self) -> Iterator[SequenceFrame]:
        """The frames of ``ids`` in order, decoded one at a time."""
        for index in self.ids:
            yield self.read(index)


def _numeric_stems(folder: Path, suffix: str) -> set[int]:
    return {int(p.stem) for p in folder.glob(f"*{suffix}") if p.stem.isdigit()} if folder.is_dir() else set()


def _open_scannet(root: Path):
    found = [d for d in ("color", "depth", "pose") if (root / d).is_dir()]
    if not found:
        hint = " (it looks like the 7scenes layout: pass --layout 7scenes)" if any(root.glob("frame-*.depth.png")) else ""
        raise ValueError(f"{root} matches no scannet layout: expected {SCANNET_EXPECTED}{hint}")
    for d in ("color", "depth", "pose"):
        if d not in found:
            raise ValueError(f"{root} is not a complete scannet export: {d}/ is missing (expected {SCANNET_EXPECTED})")
    k_color = read_intrinsics(root / "intrinsic" / "intrinsic_color.txt")
    k_depth = read_intrinsics(root / "intrinsic" / "intrinsic_depth.txt")
    depth = _numeric_stems(root / "depth", ".png")
    color = _numeric_stems(root / "color", ".jpg") or _numeric_stems(root / "color", ".png")
    ext = ".jpg" if _numeric_stems(root / "color", ".jpg") else ".png"
    pose = _numeric_stems(root / "pose", ".txt")
    if not depth:
        raise ValueError(f"{root}/depth holds no N.png frames (expected {SCANNET_EXPECTED})")
    for name, have in (("color", color), ("pose", pose)):
        missing = sorted(depth - have)
        if missing:
            raise ValueError(f"{root}: {len(missing)} depth frames have no {name} file, e.g. frame {missing[0]}")
    sem_dir = root / "semantic"
    sem = _numeric_stems(sem_dir, ".png")

    def paths(i: int) -> dict:
        return {"color": root / "color" / f"{i}{ext}", "depth": root / "depth" / f"{i}.png",
                "pose": root / "pose" / f"{i}.txt", "semantic": sem_dir / f"{i}.png" if i in sem else None}

    return sorted(depth), paths, k_color, k_depth


def _open_7scenes(root: Path):
    ids = sorted(int(m.group(1)) for p in root.glob("frame-*.depth.png") if (m := SEVEN_FRAME.match(p.name)))
    if not ids:
        hint = " (it looks like the scannet layout: pass --layout scannet)" if (root / "depth").is_dir() else ""
        raise ValueError(f"{root} matches no 7scenes layout: expected {SEVEN_EXPECTED}{hint}")
    intr = next((p for p in (root / "camera-intrinsics.txt", root.parent / "camera-intrinsics.txt") if p.exists()),
                root / "camera-intrinsics.txt")
    k = read_intrinsics(intr)
    width = len(re.match(r"frame-(\d+)", next(root.glob("frame-*.depth.png")).name).group(1))
    name = (lambda i: f"frame-{i:0{width}d}")
    ext = ".color.png" if (root / f"{name(ids[0])}.color.png").exists() else ".color.jpg"
    for i in ids:
        for kind, suffix in (("colour", ext), ("pose", ".pose.txt")):
            if not (root / f"{name(i)}{suffix}").exists():
                raise ValueError(f"{root}: frame {i} has no {kind} file {name(i)}{suffix} (expected {SEVEN_EXPECTED})")

    def paths(i: int) -> dict:
        return {"color": root / f"{name(i)}{ext}", "depth": root / f"{name(i)}.depth.png",
                "pose": root / f"{name(i)}.pose.txt", "semantic": None}

    return ids, paths, k, k.copy()


class Registration:
    """Colour camera -> depth camera resampling (see the module docstring). Identity (no copy)
    when both cameras have the same K and size."""

    def __init__(self, k_color: np.ndarray, color_size: tuple[int, int], k_depth: np.ndarray,
                 depth_size: tuple[int, int]):
        self.color_size, self.depth_size = tuple(color_size), tuple(depth_size)
        self.identity = self.color_size == self.depth_size and np.allclose(k_color, k_depth, rtol=0, atol=1e-9)
        if self.identity:
            return
        wd, hd = depth_size
        wc, hc = color_size
        v, u = np.mgrid[0:hd, 0:wd].astype(np.float64)
        h = k_color @ np.linalg.inv(k_depth)
        z = h[2, 0] * u + h[2, 1] * v + h[2, 2]
        self.map_x = ((h[0, 0] * u + h[0, 1] * v + h[0, 2]) / z).astype(np.float32)
        self.map_y = ((h[1, 0] * u + h[1, 1] * v + h[1, 2]) / z).astype(np.float32)
        ui, vi = np.rint(self.map_x).astype(np.int64), np.rint(self.map_y).astype(np.int64)
        self.inside = ((ui >= 0) & (ui < wc) & (vi >= 0) & (vi < hc)).ravel()
        self.nearest = np.where(self.inside, vi.ravel() * wc + ui.ravel(), 0)

    def rgb(self, rgb: np.ndarray) -> np.ndarray:
        """(Hc, Wc, 3) uint8 -> (Hd, Wd, 3) uint8, bilinear (black outside the colour image)."""
        if self.identity:
            return rgb
        return cv2.remap(rgb, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def labels(self, labels: np.ndarray) -> np.ndarray:
        """(Hc, Wc) int class ids -> (Hd, Wd), nearest (void outside)."""
        if self.identity:
            return labels
        out = np.where(self.inside, labels.ravel()[self.nearest], VOID)
        return out.reshape(self.depth_size[1], self.depth_size[0])

    def logits(self, logits: np.ndarray) -> np.ndarray:
        """(Hc, Wc, K) -> (Hd, Wd, K) float32, nearest (all-zero = uniform outside)."""
        if self.identity:
            return logits
        k = logits.shape[2]
        out = np.take(logits.reshape(-1, k), self.nearest, axis=0).astype(np.float32, copy=False)
        out[~self.inside] = 0.0
        return out.reshape(self.depth_size[1], self.depth_size[0], k)


def read_class_list(path) -> tuple[str, ...]:
    """Class names from a .json file (a list, or {"class_names": [...]}) or a text file (one per line)."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"class list not found: {path}")
    if path.suffix.lower() == ".json":
        data = json.loads(path.read_text())
        names = data.get("class_names") if isinstance(data, dict) else data
    else:
        names = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    if not isinstance(names, list) or len(names) < 2 or not all(isinstance(n, str) for n in names):
        raise ValueError(f"class list {path} must name at least 2 classes (a JSON list or one name per line)")
    return tuple(names)


class LogitsDir:
    """Precomputed per-frame logits ``<dir>/N.npy`` or ``N.npz`` (the array ``logits``, or the
    only one), (H, W, K) float16 / float32 at the colour or the depth resolution, with the class
    list in ``classes`` (default ``<dir>/classes.json`` or ``classes.txt``). The first frame is
    checked when opened (K, size); every frame when read."""

    def __init__(self, folder, seq: Sequence, classes=None):
        self.folder = folder = Path(folder)
        if not folder.is_dir():
            raise ValueError(f"logits directory not found: {folder}")
        if classes is None:
            classes = next((folder / n for n in ("classes.json", "classes.txt") if (folder / n).exists()), None)
            if classes is None:
                raise ValueError(f"{folder} has no classes.json / classes.txt: pass the class list file with --classes")
        self.class_names = read_class_list(classes)
        self.sizes = {seq.color_size: "colour", seq.depth_size: "depth"}
        self.get(seq.ids[0])

    @property
    def num_classes(self) -> int:
        return len(self.class_names)

    def get(self, index: int) -> np.ndarray:
        """(H, W, K) float32 logits of frame ``index``."""
        path = next((self.folder / f"{index}{s}" for s in (".npy", ".npz") if (self.folder / f"{index}{s}").exists()), None)
        if path is None:
            raise ValueError(f"no logits for frame {index}: expected {self.folder}/{index}.npy or .npz")
        with (np.load(path) if path.suffix == ".npz" else nullcontext(np.load(path))) as data:
            arr = data if isinstance(data, np.ndarray) else data["logits" if "logits" in data.files else data.files[0]]
        if arr.ndim != 3 or arr.dtype not in (np.float16, np.float32):
            raise ValueError(f"logits {path} must be (H, W, K) float16 / float32, got {arr.dtype} {arr.shape}")
        if arr.shape[2] != self.num_classes:
            raise ValueError(f"logits {path} have K = {arr.shape[2]} classes, the class list names {self.num_classes}")
        size = (arr.shape[1], arr.shape[0])
        if size not in self.sizes:
            valid = " or ".join(f"{w}x{h} ({what})" for (w, h), what in self.sizes.items())
            raise ValueError(f"logits {path} are {size[0]}x{size[1]} pixels; expected {valid}")
        return arr.astype(np.float32, copy=False)



def vertex_ground_truth(ply_path, class_names, cfg: SequenceConfig, seq_root=None) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64 m, class per vertex (V,) int64 index into ``class_names``, -1
    void) of a labelled PLY. Raw labels (``cfg.label_property``) map to names through
    ``cfg.label_map``: a .json / .tsv / .csv file, ``nyu40`` (ScanNet's NYU40 ids), or "" =
    ``<seq_root>/label_map.json`` when present, else ``nyu40``; names match ``class_names``
    exactly, then by synonym (``common.ply_labels``). Raises ValueError when nothing maps."""
    from common.ply_labels import NYU40_NAMES, class_ids_of, class_index, int_keyed, read_label_table, read_vertex_labels

    vertices, raw = read_vertex_labels(ply_path, cfg.label_property)
    source = cfg.label_map
    if not source and seq_root is not None and (Path(seq_root) / "label_map.json").exists():
        source = str(Path(seq_root) / "label_map.json")
    if not source or source == "nyu40":
        table, source = {i + 1: n for i, n in enumerate(NYU40_NAMES)}, "nyu40"
    else:
        table = int_keyed(read_label_table(source))
    ids = class_ids_of(class_names)
    values, inverse = np.unique(raw, return_inverse=True)
    lut = np.array([c if (c := class_index(table.get(int(v)), ids)) is not None else VOID for v in values], np.int64)
    classes = lut[inverse.ravel()] if len(values) else np.zeros(0, np.int64)
    if not (classes != VOID).any():
        raise ValueError(f"{ply_path}: none of its labels {values[:20].tolist()} maps to a class of "
                         f"{', '.join(class_names)} through the label map {source}")
    return vertices, classes
