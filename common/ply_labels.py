"""Labelled meshes and label maps shared by the simulator (``envs.scan``: a labelled PLY as a
scene) and the map evaluation (``mapping.sequences``: ground truth of a recorded sequence).

- ``read_label_table(path)``: ``{raw id: class name}`` from a ``.json`` (a dict, or a list of
  ``{"id", "name"}`` records) or a ``.tsv`` / ``.csv`` file with a header (id column: the first
  of ``ID_COLUMNS`` present; name column: the first of ``NAME_COLUMNS``; ScanNet's
  ``scannetv2-labels.combined.tsv`` works: ``id`` -> ``nyu40class``).
- ``class_index(name, class_ids)``: a class name matched against a class list, exactly first
  (case-insensitive, ``-`` / ``_`` / space alike), then through ``SYNONYMS``; None when neither.
- ``NYU40_NAMES``: the NYU40 label set ScanNet's ``<scene>_vh_clean_2.labels.ply`` ``label``
  property uses (id i + 1 is ``NYU40_NAMES[i]``; 0 = unannotated).
- ``read_vertex_labels(path, prop)``: vertices (V, 3) float64 and the integer vertex property
  ``prop`` (V,) int64 of a PLY file (plyfile).

Errors are ``ValueError`` naming the file and the problem.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

ID_COLUMNS = ("id", "raw_id", "label_id", "label", "nyu40id", "index")
NAME_COLUMNS = ("calnav", "class", "class_name", "category", "nyu40class", "name", "raw_category")
# Other names of the same class (keys and values in normalised form: lower case, spaces).
SYNONYMS = {
    "couch": "sofa", "sofa chair": "chair", "armchair": "chair", "office chair": "chair", "seat": "chair",
    "potted plant": "plant", "houseplant": "plant", "flower pot": "plant",
    "tv": "tv monitor", "television": "tv monitor", "monitor": "tv monitor",
    "computer monitor": "tv monitor", "screen": "tv monitor",
    "bookshelf": "shelf", "bookcase": "shelf", "shelves": "shelf", "shelving": "shelf",
    "dresser": "cabinet", "night stand": "cabinet", "nightstand": "cabinet", "wardrobe": "cabinet",
    "kitchen cabinets": "cabinet", "kitchen cabinet": "cabinet", "cupboard": "cabinet",
    "kitchen counter": "counter", "countertop": "counter", "bath": "bathtub", "tub": "bathtub",
    "dining table": "table", "coffee table": "table", "end table": "table", "ottoman": "stool",
    "floor mat": "floor", "carpet": "floor", "rug": "floor", "doorframe": "door",
    "refridgerator": "refrigerator",   # NYU40's spelling -> ScanNet-20's
}
NYU40_NAMES: tuple[str, ...] = (
    "wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door", "window", "bookshelf",
    "picture", "counter", "blinds", "desk", "shelves", "curtain", "dresser", "pillow", "mirror", "floor mat",
    "clothes", "ceiling", "books", "refridgerator", "television", "paper", "towel", "shower curtain", "box",
    "whiteboard", "person", "night stand", "toilet", "sink", "lamp", "bathtub", "bag", "otherstructure",
    "otherfurniture", "otherprop",
)


def normalise_name(name) -> str:
    """Lower case, '-' and '_' as spaces, surrounding blanks removed."""
    return str(name).strip().lower().replace("-", " ").replace("_", " ")


def class_index(name, class_ids: dict[str, int]) -> int | None:
    """Class id of ``name`` in ``class_ids`` ({normalised class name: id}), matched exactly,
    then through ``SYNONYMS``; None when it names no class of the list."""
    if name is None:
        return None
    key = normalise_name(name)
    if key in class_ids:
        return class_ids[key]
    return class_ids.get(SYNONYMS.get(key, ""))


def class_ids_of(class_names) -> dict[str, int]:
    """{normalised name: index} of a class list."""
    return {normalise_name(n): i for i, n in enumerate(class_names)}


def read_label_table(path) -> dict:
    """``{raw id or name: class name}`` from a .json / .tsv / .csv label-map file."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"label map file not found: {path}")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text())
            if isinstance(data, list):
                if not all(isinstance(rec, dict) and {"id", "name"} <= rec.keys() for rec in data):
                    raise ValueError("a list must hold {\"id\": raw id, \"name\": class name} records; or give an "
                                     "object {raw id: class name}")
                data = {rec["id"]: rec["name"] for rec in data}
            if not isinstance(data, dict):
                raise ValueError("expected an object {raw id: class name} or a list of {id, name} records")
            return data
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f, delimiter="\t" if path.suffix.lower() == ".tsv" else ","))
    except (ValueError, KeyError, TypeError, csv.Error) as exc:
        raise ValueError(f"unreadable label map {path}: {exc}") from exc
    header = list(rows[0].keys()) if rows else []
    id_col = next((c for c in ID_COLUMNS if c in header), None)
    name_col = next((c for c in NAME_COLUMNS if c in header), None)
    if id_col is None or name_col is None:
        raise ValueError(f"label map {path} needs an id column (one of {ID_COLUMNS}) and a name column "
                         f"(one of {NAME_COLUMNS}); its header is {header}")
    return {row[id_col]: row[name_col] for row in rows}


def int_keyed(table: dict) -> dict[int, str]:
    """The entries of a label table whose key is an integer (or a digit string)."""
    out = {}
    for k, name in dict(table).items():
        try:
            out[int(k)] = name
        except (TypeError, ValueError):
            continue   # a non-numeric key cannot match an integer label
    return out


def read_vertex_labels(path, prop: str = "label") -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64 metres, vertex property ``prop`` (V,) int64) of a PLY file."""
    from plyfile import PlyData

    path = Path(path)
    if not path.exists():
        raise ValueError(f"labelled PLY not found: {path}")
    try:
        try:   # fast path: faces read as fixed-size triangle lists (only the vertices are used)
            ply = PlyData.read(str(path), known_list_len={"face": {"vertex_indices": 3}})
        except Exception:   # polygons, another face property name, ascii: plyfile's generic parser
            ply = PlyData.read(str(path), mmap=False)
        v = ply["vertex"].data
        names = v.dtype.names
    except Exception as exc:   # plyfile raises many types for malformed headers / bodies
        raise ValueError(f"corrupt or unparseable PLY {path}: {type(exc).__name__}: {exc}") from exc
    if prop not in names:
        raise ValueError(f"{path}: the PLY has no vertex property {prop!r} (it has {list(names)}); "
                         f"a labelled mesh such as ScanNet's <scene>_vh_clean_2.labels.ply is needed")
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    return xyz, np.asarray(v[prop]).astype(np.int64)
