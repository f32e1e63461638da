"""Sequence readers: ``SequenceConfig``, ``SequenceFrame``, ``Sequence`` (one opened recording,
``scannet`` or ``7scenes`` layout), the per-layout openers ``open_scannet`` / ``open_7scenes``
(registered by name in ``mapping.registry.LAYOUTS``) and generators ``read_scannet`` /
``read_7scenes``. See ``mapping.sequences`` for the layouts and conventions."""
from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from calnav.common.ranges import Range, check_ranges
from calnav.mapping import frame_geometry as fg
from calnav.mapping.registry import LAYOUTS
from calnav.mapping.sequences.rosbag_config import RosbagConfig
from calnav.mapping.sequences.skips import NON_FINITE_POSE, SkippedFrames

SCANNET_EXPECTED = "color/N.jpg, depth/N.png, pose/N.txt, intrinsic/intrinsic_color.txt, intrinsic/intrinsic_depth.txt"
SEVEN_EXPECTED = "frame-NNNNNN.color.png|jpg, frame-NNNNNN.depth.png, frame-NNNNNN.pose.txt, camera-intrinsics.txt"
SEVEN_FRAME = re.compile(r"^frame-(\d+)\.depth\.png$")
VOID = -1
SEMANTIC_OFFSET = 1   # semantic PNGs store class id + 1 (0 = void) in uint16
# ``Sequence.check_scale``: depth in the wrong units (TUM's 5000 per metre read as 1000,
# centimetres as millimetres) puts nearly every pixel outside the mapping's depth range, and the
# map then holds a few stray voxels with exit 0. A real recording keeps most of its valid depth in
# range (a robot facing a far wall in one sampled frame is outvoted by the others).
MIN_DEPTH_IN_RANGE = 0.2          # fraction of the valid depth pixels of the first, middle and last frames
# The voxel map stores float32 coordinates, whose spacing grows with the distance from the origin
# (0.25 m at 4e6 m). Past a tenth of a voxel the voxels' centres snap to that grid (UTM / GNSS map
# frames), so such poses are refused with how to fix them.
MAX_SPACING_VOXELS = 0.1


# Size-like keys of a recording's reading (``sequence``), and why their bounds: depth is cut
# within 100 m (beyond any indoor sensor; 0 = no cut), and a voxel's label comes from a mesh
# vertex at most 1 m away (farther is another object: real meshes are denser than that).
SEQUENCE_RANGES = {
    "depth_trunc_m": Range(0.0, 100.0, "metres"),
    "label_distance_m": Range(0.0, 1.0, "metres", lo_open=True),
}


@dataclass
class SequenceConfig:
    """How a recorded sequence is read (YAML section ``sequence``)."""

    depth_scale: float = 1000.0      # raw depth units per metre (ScanNet / 7-Scenes: millimetres -> 1000)
    depth_trunc_m: float = 0.0       # depth beyond this is invalid, metres; 0 = no truncation (mapping.depth_max_m still applies)
    invalid_depth_raw: int = 65535   # raw depth value that means invalid besides 0 (7-Scenes: 65535), raw units
    frame_stride: int = 1            # use every N-th frame of the recording, frames
    max_frames: int = 0              # use at most this many frames (after the stride); 0 = all, frames
    label_distance_m: float = 0.05   # voxel ground truth: nearest labelled vertex within this distance, metres
    label_map: str = ""              # raw PLY label -> class name (.json / .tsv / .csv); "" = the label_map.json beside the PLY or in <seq>, else NYU40 names
    label_property: str = "label"    # integer vertex property of the labelled PLY holding the raw label
    frame_label_map: str = ""        # raw id -> class name table (.tsv/.csv/.json) of ScanNet's label-filt/N.png; "" = label-filt not read
    rosbag: RosbagConfig = field(default_factory=RosbagConfig)   # the rosbag layout's topics, frames, tolerances

    def __post_init__(self) -> None:
        if not self.depth_scale > 0:
            raise ValueError(f"sequence.depth_scale must be > 0, got {self.depth_scale}")
        check_ranges(self, "sequence", SEQUENCE_RANGES)
        if self.max_frames < 0:
            raise ValueError(f"sequence.max_frames must be >= 0, got {self.max_frames}")
        if self.frame_stride < 1:
            raise ValueError(f"sequence.frame_stride must be >= 1, got {self.frame_stride}")


@dataclass
class SequenceFrame:
    """One posed RGB-D frame. index: frame number in the recording; rgb (H, W, 3) uint8 at the
    colour camera; depth (h, w) float32 metres (0 = invalid) at the depth camera; k_color /
    k_depth (3, 3) float64 pixels; pose (4, 4) float64 camera-to-world, OpenCV axes (rigid);
    semantic int64 class ids (-1 void) at the colour (H, W) or the depth (h, w) size, or None."""

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
    valid pose), ``skips`` those left out with their reasons (``mapping.sequences.skips``, one
    rule for every layout; ``skipped`` their numbers); ``frames()`` yields ``SequenceFrame`` one
    at a time. Every pose is checked when the sequence is opened."""

    def __new__(cls, root=None, layout: str = "", cfg: SequenceConfig | None = None):
        # a layout registered as a Sequence subclass (rosbag) reads its recording itself
        part = LAYOUTS.get(layout) if cls is Sequence and layout in LAYOUTS else None
        return super().__new__(part if isinstance(part, type) and issubclass(part, Sequence) else cls)

    def __init__(self, root, layout: str, cfg: SequenceConfig | None = None):
        self.root = root = Path(root)
        self.cfg = cfg = cfg or SequenceConfig()
        LAYOUTS.check(layout)
        if not root.is_dir():
            raise ValueError(f"sequence directory not found: {root}")
        self.layout = layout
        ids, self._paths, self.k_color, self.k_depth = LAYOUTS.get(layout)(root)
        ids = ids[::cfg.frame_stride]
        ids = ids[:cfg.max_frames] if cfg.max_frames else ids
        # every pose is read up front (small text files: ~0.1 ms each), so a non-rigid pose is
        # reported before anything is written and the invalid ones are known
        self._poses = {i: self._read_pose(i) for i in ids}
        self.skips = SkippedFrames()
        self.skips.add([i for i in ids if self._poses[i] is None], NON_FINITE_POSE)
        self.ids = [i for i in ids if i not in self.skips]
        if not self.ids:
            raise ValueError(f"{root}: no frames to read ({len(ids)} after frame_stride {cfg.frame_stride} / max_frames "
                             f"{cfg.max_frames}, {self.skips.summary()})")
        first = self.ids[0]
        rgb = _imread(self._paths(first)["color"], cv2.IMREAD_COLOR)
        depth = _imread(self._paths(first)["depth"], cv2.IMREAD_UNCHANGED)
        if depth.ndim != 2 or depth.dtype != np.uint16:
            raise ValueError(f"depth {self._paths(first)['depth']} must be a single-channel 16-bit PNG, "
                             f"got {depth.dtype} with shape {depth.shape}")
        self.color_size = (rgb.shape[1], rgb.shape[0])    # (W, H) pixels
        self.depth_size = (depth.shape[1], depth.shape[0])
        for what, k, (w, h) in (("colour", self.k_color, self.color_size), ("depth", self.k_depth, self.depth_size)):
            try:   # against the images' size: a K for another resolution skews the whole map
                fg.check_intrinsics(k, w, h)
            except ValueError as exc:
                raise ValueError(f"{root}: the {what} intrinsics for its {w}x{h} {what} images: {exc}") from None
        self._has_labels = {k: self._paths(first).get(k) is not None for k in ("semantic", "label_raw")}
        self._label_lut: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.ids)

    def pose_of(self, index: int) -> np.ndarray:
        """(4, 4) camera-to-world pose of frame ``index`` (one of ``ids``)."""
        return self._poses[index]

    def check_scale(self, depth_min_m: float, depth_max_m: float, voxel_size_m: float) -> None:
        """Refuse (ValueError, one line) a recording the map would hold wrongly with no other
        sign: depth mostly outside ``depth_min_m``-``depth_max_m`` in sampled frames (its units
        are not ``sequence.depth_scale``'s), or a camera so far from the origin that float32
        voxel coordinates are coarser than a tenth of ``voxel_size_m``."""
        picks = sorted({self.ids[0], self.ids[len(self.ids) // 2], self.ids[-1]})
        valid = np.concatenate([d[d > 0] for d in (self.read(i).depth for i in picks)])
        if valid.size:
            inside = float(((valid >= depth_min_m) & (valid <= depth_max_m)).mean())
            if inside < MIN_DEPTH_IN_RANGE:
                raise ValueError(f"{self.root}: only {inside:.1%} of the valid depth of frames {picks} lies within "
                                 f"mapping.depth_min_m-depth_max_m ({depth_min_m:g}-{depth_max_m:g} m; median "
                                 f"{float(np.median(valid)):.3g} m): a depth range that misses the recording, or depth in "
                                 f"other units? sequence.depth_scale is {self.cfg.depth_scale:g} raw units per metre "
                                 "(ScanNet / 7-Scenes: 1000, TUM: 5000)")
        reach = max(float(np.abs(self.pose_of(i)[:3, 3]).max()) for i in self.ids)
        spacing = float(np.spacing(np.float32(reach)))
        if spacing > MAX_SPACING_VOXELS * voxel_size_m:
            raise ValueError(f"{self.root}: a camera position lies {reach:.4g} m from the origin, where the map's float32 "
                             f"coordinates are {spacing:.2g} m apart (mapping.voxel_size_m is {voxel_size_m:g} m): give "
                             "the poses in a local frame (subtract a fixed origin, e.g. the first camera position)")

    @property
    def skipped(self) -> list[int]:
        """The frame numbers left out (``skips``), in order."""
        return self.skips.frames

    def skip_summary(self) -> str:
        """Why the ``skipped`` frames were left out, for a one-line report: "1 with a non-finite pose ..."."""
        return self.skips.summary()

    @property
    def has_semantic(self) -> bool:
        """Whether frames carry class labels (``semantic/``, or ``label-filt/`` once mapped)."""
        return self._has_labels["semantic"] or self._label_lut is not None

    def use_class_names(self, class_names) -> None:
        """Map ScanNet's ``label-filt/`` raw ids to indices of ``class_names`` through
        ``cfg.frame_label_map`` (when both exist; ``semantic/`` frames take precedence)."""
        from calnav.common.ply_labels import class_ids_of, class_index, int_keyed, read_label_table

        if self._has_labels["semantic"] or not self._has_labels["label_raw"] or not self.cfg.frame_label_map:
            return
        table = int_keyed(read_label_table(self.cfg.frame_label_map))
        ids = class_ids_of(class_names)
        lut = np.full(max(table, default=0) + 1, VOID, np.int64)
        for raw, name in table.items():
            if raw >= 0 and (c := class_index(name, ids)) is not None:
                lut[raw] = c
        if not (lut != VOID).any():
            raise ValueError(f"frame_label_map {self.cfg.frame_label_map}: no raw id maps to a class of "
                             f"{', '.join(class_names)}")
        self._label_lut = lut

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
            with warnings.catch_warnings():   # an empty file: numpy warns, then the shape check names it
                warnings.simplefilter("ignore", UserWarning)
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
        if raw.ndim != 2 or raw.dtype != np.uint16:   # an 8-bit PNG read as millimetres would be 0-25 cm
            raise ValueError(f"frame {index}: depth {paths['depth']} must be a single-channel 16-bit PNG, "
                             f"got {raw.dtype} with shape {raw.shape}")
        if (raw.shape[1], raw.shape[0]) != self.depth_size:
            raise ValueError(f"frame {index}: depth {paths['depth']} is {raw.shape[1]}x{raw.shape[0]}, the sequence's is "
                             f"{self.depth_size[0]}x{self.depth_size[1]}")
        depth = depth_from_raw(raw, self.cfg)
        rgb = cv2.cvtColor(_imread(paths["color"], cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        if (rgb.shape[1], rgb.shape[0]) != self.color_size:
            raise ValueError(f"frame {index}: colour {paths['color']} is {rgb.shape[1]}x{rgb.shape[0]}, the sequence's "
                             f"is {self.color_size[0]}x{self.color_size[1]}")
        sem = None
        if paths.get("semantic") is not None:
            sem = _imread(paths["semantic"], cv2.IMREAD_UNCHANGED).astype(np.int64) - SEMANTIC_OFFSET
        elif self._label_lut is not None and paths.get("label_raw") is not None:
            raw_ids = _imread(paths["label_raw"], cv2.IMREAD_UNCHANGED).astype(np.int64)
            lut = self._label_lut
            sem = np.where(raw_ids < len(lut), lut[np.minimum(raw_ids, len(lut) - 1)], VOID)
        return SequenceFrame(index, rgb, depth, self.k_color, self.k_depth, pose, sem)

    def frames(self) -> Iterator[SequenceFrame]:
        """The frames of ``ids`` in order, decoded one at a time."""
        for index in self.ids:
            yield self.read(index)


def _numeric_stems(folder: Path, suffix: str) -> set[int]:
    return {int(p.stem) for p in folder.glob(f"*{suffix}") if p.stem.isdigit()} if folder.is_dir() else set()


def open_scannet(root: Path) -> tuple[list[int], Callable[[int], dict], np.ndarray, np.ndarray]:
    """The ``scannet`` layout's opener (``mapping.registry.LAYOUTS``): the recording's frame
    ids, ``paths(id)`` -> {color, depth, pose, semantic, label_raw: Path | None}, and the colour
    and depth intrinsics K (3, 3); ValueError naming what is missing."""
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
    missing = sorted((color | pose) - depth)   # a lost depth frame would silently drop its frame
    if missing:
        raise ValueError(f"{root}: {len(missing)} colour / pose frames have no depth/N.png file, e.g. frame {missing[0]}")
    sem_dir, raw_dir = root / "semantic", root / "label-filt"
    sem, raw = _numeric_stems(sem_dir, ".png"), _numeric_stems(raw_dir, ".png")
    for name, have in (("semantic", sem), ("label-filt", raw)):
        missing = sorted(depth - have) if have else []   # labels for some frames only: scores would skip the rest
        if missing:
            raise ValueError(f"{root}: {len(missing)} depth frames have no {name}/ file, e.g. frame {missing[0]}")

    def paths(i: int) -> dict:
        return {"color": root / "color" / f"{i}{ext}", "depth": root / "depth" / f"{i}.png",
                "pose": root / "pose" / f"{i}.txt", "semantic": sem_dir / f"{i}.png" if i in sem else None,
                "label_raw": raw_dir / f"{i}.png" if i in raw else None}

    return sorted(depth), paths, k_color, k_depth


def open_7scenes(root: Path) -> tuple[list[int], Callable[[int], dict], np.ndarray, np.ndarray]:
    """The ``7scenes`` layout's opener (as ``open_scannet``; colour and depth share one K)."""
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
    others = {int(m.group(1)) for p in root.glob("frame-*.*")
              if (m := re.match(r"^frame-(\d+)\.(pose\.txt|color\.png|color\.jpg)$", p.name))}
    missing = sorted(others - set(ids))   # a lost depth frame would silently drop its frame
    if missing:
        raise ValueError(f"{root}: {len(missing)} colour / pose frames have no depth file, e.g. frame {missing[0]}")
    for i in ids:
        for kind, suffix in (("colour", ext), ("pose", ".pose.txt")):
            if not (root / f"{name(i)}{suffix}").exists():
                raise ValueError(f"{root}: frame {i} has no {kind} file {name(i)}{suffix} (expected {SEVEN_EXPECTED})")

    def paths(i: int) -> dict:
        return {"color": root / f"{name(i)}{ext}", "depth": root / f"{name(i)}.depth.png",
                "pose": root / f"{name(i)}.pose.txt", "semantic": None, "label_raw": None}

    return ids, paths, k, k.copy()


def read_scannet(root, cfg: SequenceConfig | None = None) -> Iterator[SequenceFrame]:
    """The frames of a ScanNet SensReader export, one at a time (validated on the first ``next``;
    open a ``Sequence`` to validate first and to read ``skipped``)."""
    yield from Sequence(root, "scannet", cfg).frames()


def read_7scenes(root, cfg: SequenceConfig | None = None) -> Iterator[SequenceFrame]:
    """The frames of a 7-Scenes / 3DMatch sequence folder, one at a time."""
    yield from Sequence(root, "7scenes", cfg).frames()
