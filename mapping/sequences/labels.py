"""Class information of a recording: precomputed logits (``LogitsDir``) with their class list
(``read_class_list``), and per-vertex ground truth of its labelled mesh (``vertex_ground_truth``)."""
from __future__ import annotations

import json
import zipfile
from contextlib import nullcontext
from pathlib import Path

import numpy as np

from calnav.mapping.sequences.readers import VOID, Sequence, SequenceConfig


def read_class_list(path) -> tuple[str, ...]:
    """Class names from a .json file (a list, or {"class_names": [...]}) or a text file (one per line)."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"class list not found: {path}")
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"class list {path} is not valid JSON ({exc})") from None
        names = data.get("class_names") if isinstance(data, dict) else data
    else:
        names = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    if not isinstance(names, list) or len(names) < 2 or not all(isinstance(n, str) for n in names):
        raise ValueError(f"class list {path} must name at least 2 classes (a JSON list or one name per line)")
    seen: set[str] = set()
    repeated = [n for n in names if n in seen or seen.add(n)]
    if repeated:   # two logit channels of one name: ground truth would match only the first
        raise ValueError(f"class list {path} names {repeated[0]!r} twice; every class needs its own name")
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
        try:
            with (np.load(path) if path.suffix == ".npz" else nullcontext(np.load(path))) as data:
                arr = data if isinstance(data, np.ndarray) else data["logits" if "logits" in data.files else data.files[0]]
        except (OSError, ValueError, EOFError, KeyError, IndexError, zipfile.BadZipFile) as exc:   # truncated / not numpy
            raise ValueError(f"cannot read logits {path} of frame {index}: {exc}") from None
        if arr.ndim != 3 or arr.dtype not in (np.float16, np.float32):
            raise ValueError(f"logits {path} must be (H, W, K) float16 / float32, got {arr.dtype} {arr.shape}")
        if arr.shape[2] != self.num_classes:
            raise ValueError(f"logits {path} have K = {arr.shape[2]} classes, the class list names {self.num_classes}")
        size = (arr.shape[1], arr.shape[0])
        if size not in self.sizes:
            valid = " or ".join(f"{w}x{h} ({what})" for (w, h), what in self.sizes.items())
            raise ValueError(f"logits {path} are {size[0]}x{size[1]} pixels; expected {valid}")
        arr = arr.astype(np.float32, copy=False)
        if not np.isfinite(arr).all():
            raise ValueError(f"logits {path} of frame {index} hold NaN or inf")
        return arr



def label_map_source(cfg: SequenceConfig, seq_root=None, ply=None) -> str:
    """The label map a labelled mesh's raw labels are read through: ``cfg.label_map``, else the
    ``label_map.json`` beside the mesh ``ply`` or in the sequence directory ``seq_root`` (a bag
    file has none: the one beside ``--labels-ply`` serves it), else ``nyu40`` (ScanNet's ids).
    ValueError (one line) when both are there and differ: which one the labels mean is unknown."""
    if cfg.label_map:
        return cfg.label_map
    found: list[tuple[Path, str]] = []
    for folder, where in ((ply and Path(ply).parent, "beside it"), (seq_root, "in the sequence's directory")):
        path = Path(folder) / "label_map.json" if folder is not None else None
        if path is None or not path.is_file() or any(path.samefile(p) for p, _ in found):
            continue
        if found and path.read_bytes() != found[0][0].read_bytes():
            raise ValueError(f"two different label maps for {ply}: {found[0][0]} ({found[0][1]}) and {path} ({where}); "
                             "set sequence.label_map to the one its labels are read through")
        found.append((path, where))
    return str(found[0][0]) if found else "nyu40"


def vertex_ground_truth(ply_path, class_names, cfg: SequenceConfig, seq_root=None) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64 m, class per vertex (V,) int64 index into ``class_names``, -1
    void) of a labelled PLY. Raw labels (``cfg.label_property``) map to names through
    ``cfg.label_map``: a .json / .tsv / .csv file, ``nyu40`` (ScanNet's NYU40 ids), or "" = the
    ``label_map.json`` beside the PLY or in ``seq_root`` (``label_map_source``), else ``nyu40``;
    names match ``class_names`` exactly, then by synonym (``common.ply_labels``). Raises
    ValueError when nothing maps."""
    from calnav.common.ply_labels import NYU40_NAMES, class_ids_of, class_index, int_keyed, read_label_table, read_vertex_labels

    vertices, raw = read_vertex_labels(ply_path, cfg.label_property)
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices).all(axis=1)).sum())
        raise ValueError(f"{ply_path}: {bad} vertices have NaN or inf coordinates")
    source = label_map_source(cfg, seq_root, ply_path)
    if source == "nyu40":
        table = {i + 1: n for i, n in enumerate(NYU40_NAMES)}
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
