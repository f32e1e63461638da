"""Real scans: labelled PLY meshes (ScanNet-style) as calnav ``Scene``s.

``load_labelled_ply(path, label_map)`` reads a triangle (or polygon) mesh with an integer label
per vertex (ScanNet's ``label``) or per face, optional per-vertex or per-face colours
(``red/green/blue``) and optional instance ids (``instance``/``objectId``/...), and maps the
raw labels to calnav classes:

- ``label_map`` None: the raw labels already are calnav class ids (out of range -> void).
- ``label_map`` a dict ``{raw id: class name}`` (keys may be ints or digit strings), or a path
  to a ``.json`` file holding such a dict (or a list of ``{"id": .., "name": ..}`` records),
  or a ``.tsv``/``.csv`` file with a header: the id column is the first of ``common.ply_labels.ID_COLUMNS``
  found, the name column the first of ``NAME_COLUMNS`` (ScanNet's
  ``scannetv2-labels.combined.tsv`` works: ``id`` -> ``nyu40class``).
- Names are matched case-insensitively against calnav's classes and ``common.ply_labels.SYNONYMS``
  (couch -> sofa, television -> tv_monitor, ...); anything else, and unmapped ids, become void.
  (The label-table reading and name matching live in ``common.ply_labels``, shared with the
  map evaluation of recorded sequences.)

A scan's colours already hold its lighting: a PLY with colours is marked
``meta["lighting"] = "baked"`` (the renderer does not shade it again), and every PLY
``meta["closed_solids"] = False`` (open surfaces: ``envs.navigation.closed_solids``).

Per-vertex labels become per-face by majority vote of the face's vertices (ties: the first
vertex). The mesh is rotated so that its ``up_axis`` (the file's axis pointing up: ``z``, ``y``,
``x``, ``-z``, ``-y``, ``-x``; ``y`` as glTF / many exporters write, ``-z`` for an upside-down
scan) becomes +z (``envs.scene_plausible.frame_rotation``, front as a habitat stage's) and
shifted so that its floor lies at z = 0 (``envs.scene_plausible.floor_height``: a low percentile
of floor-class vertex heights; all vertices when nothing is floor).
Instances come from the file's instance property (split where an instance spans classes) or,
without one, from connected components of same-class faces sharing a vertex.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from calnav.common.ply_labels import class_ids_of, class_index, int_keyed, read_label_table
from calnav.envs.scene import Scene, SceneError, Texture
from calnav.envs.scene_plausible import AXES, axis_vector, default_front, floor_height, frame_rotation
from calnav.envs.semantics import CLASS_NAMES, NUM_CLASSES, VOID

INSTANCE_PROPERTIES = ("instance", "objectId", "object_id", "instance_id", "objectid")
DEFAULT_ALBEDO = 180       # grey level of faces when the file has no colours, uint8
UP_AXES = AXES + tuple("-" + a for a in AXES)   # up_axis choices: the file's axis pointing up
_CALNAV_IDS = class_ids_of(CLASS_NAMES)


def _class_of_name(name) -> int:
    """calnav class id of a (possibly synonymous) name; VOID when it names no calnav class."""
    found = class_index(name, _CALNAV_IDS)
    return VOID if found is None else found


def _read_label_table(path: Path) -> dict:
    """``{raw id or name: class name}`` from a .json / .tsv / .csv label-map file."""
    try:
        return read_label_table(path)
    except ValueError as exc:
        raise SceneError(str(exc)) from exc


def _label_lut(raw: np.ndarray, label_map) -> dict[int, int]:
    """Raw label value -> calnav class id, for every distinct value in ``raw``."""
    values = np.unique(raw).tolist()
    if label_map is None:
        return {v: (v if 0 <= v < NUM_CLASSES else VOID) for v in values}
    if isinstance(label_map, (str, os.PathLike)):
        label_map = _read_label_table(Path(label_map))
    by_key = {k: _class_of_name(name) for k, name in int_keyed(label_map).items()}
    return {v: by_key.get(v, VOID) for v in values}


def _faces(ply, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) int64 triangles (polygons fan-triangulated) and (F,) the PLY face each came from."""
    if "face" not in ply or ply["face"].count == 0:
        raise SceneError(f"{path}: the PLY has no faces (a point cloud?); a labelled triangle mesh is needed")
    face = ply["face"].data
    prop = next((p for p in ("vertex_indices", "vertex_index") if p in face.dtype.names), None)
    if prop is None:
        raise SceneError(f"{path}: face element has no vertex_indices property (has {list(face.dtype.names)})")
    lists = face[prop]
    if lists.dtype != object:   # fixed-size lists come back as a 2-D array
        lists = list(lists)
    counts = np.array([len(f) for f in lists])
    if (counts < 3).any():
        raise SceneError(f"{path}: faces with fewer than 3 vertices")
    if (counts == 3).all():
        return np.stack(lists).astype(np.int64), np.arange(len(lists))
    tris, owner = [], []
    for i, f in enumerate(lists):
        for k in range(1, len(f) - 1):
            tris.append((f[0], f[k], f[k + 1]))
            owner.append(i)
    return np.asarray(tris, dtype=np.int64), np.asarray(owner)


def up_axis_rotation(up_axis: str) -> np.ndarray:
    """(3, 3) calnav-from-file rotation of a PLY whose ``up_axis`` points up: that axis becomes
    +z, the front a habitat stage's default (``y``: +90 degrees about x, (x, y, z) -> (x, -z, y))."""
    up = axis_vector(up_axis)
    return frame_rotation(up, default_front(up))


def per_face_majority(vertex_values: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Majority vote of a triangle's three vertex values (all differ: the first vertex's)."""
    a, b, c = (vertex_values[tris[:, k]] for k in range(3))
    return np.where((a == b) | (a == c), a, np.where(b == c, b, a))


def _components(tri_class: np.ndarray, tris: np.ndarray, n_verts: int) -> np.ndarray:
    """Instance ids: connected components of same-class faces sharing a vertex (void: -1)."""
    f = len(tris)
    labelled = np.flatnonzero(tri_class != VOID)
    # Faces link through (vertex, class) nodes, so two classes meeting at a vertex stay apart.
    keys = tris[labelled].ravel() * (NUM_CLASSES + 1) + np.repeat(tri_class[labelled].astype(np.int64), 3)
    _, node = np.unique(keys, return_inverse=True)
    rows = np.repeat(labelled, 3)
    n = f + node.max() + 1 if len(node) else f
    graph = coo_matrix((np.ones(len(rows)), (rows, f + node)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    inst = np.full(f, -1, dtype=np.int64)
    _, inst[labelled] = np.unique(comp[labelled], return_inverse=True)
    return inst


def load_labelled_ply(path, label_map=None, label_property: str = "label", up_axis: str = "z",
                      name: str | None = None) -> Scene:
    """A labelled PLY mesh as a ``Scene`` (see the module docstring for the conventions).

    path: .ply file (ascii or binary). label_map: None, a dict, or a .json/.tsv/.csv path.
    label_property: the vertex or face property holding integer labels. up_axis: one of
    ``UP_AXES``, the file's axis pointing up.
    Raises ``SceneError`` for a missing/corrupt file, no faces, no label property, or labels
    that map to no calnav class.
    """
    from plyfile import PlyData

    path = Path(path)
    if up_axis not in UP_AXES:
        raise ValueError(f"up_axis must be one of {', '.join(UP_AXES)} (the file's axis pointing up), got {up_axis!r}")
    if not path.exists():
        raise SceneError(f"PLY file not found: {path}")
    try:
        ply = PlyData.read(str(path), mmap=False)   # read everything now, so errors surface here
        vdata = ply["vertex"].data
        verts = np.stack([vdata["x"], vdata["y"], vdata["z"]], axis=1).astype(np.float64)
        tris, owner = _faces(ply, path)
    except SceneError:
        raise
    except Exception as exc:   # plyfile raises many types for malformed headers / bodies
        raise SceneError(f"corrupt or unparseable PLY {path}: {type(exc).__name__}: {exc}") from exc
    if len(tris) and (tris.min() < 0 or tris.max() >= len(verts)):
        raise SceneError(f"{path}: face vertex indices out of range [0, {len(verts)})")
    vnames, fdata = vdata.dtype.names, ply["face"].data
    fnames = fdata.dtype.names

    def per_face_prop(prop: str) -> np.ndarray | None:
        if prop in fnames:
            return np.asarray(fdata[prop]).astype(np.int64)[owner]
        if prop in vnames:
            return per_face_majority(np.asarray(vdata[prop]).astype(np.int64), tris)
        return None

    raw = per_face_prop(label_property)
    if raw is None:
        raise SceneError(f"{path}: no {label_property!r} property; vertex properties: {list(vnames)}, "
                         f"face properties: {list(fnames)}; name the one holding the labels in its labels.json: "
                         '{"label_map": {...}, "label_property": "..."}')
    values, inverse = np.unique(raw, return_inverse=True)
    lut = _label_lut(values, label_map)
    tri_class = np.array([lut[v] for v in values.tolist()], dtype=np.int16)[inverse.ravel()]
    if (tri_class == VOID).all():
        raise SceneError(f"{path}: none of its labels {sorted(lut)[:20]} maps to a calnav class "
                         f"({', '.join(CLASS_NAMES)}); check label_map")

    if up_axis != "z":
        verts = verts @ up_axis_rotation(up_axis).T
    floor_z = floor_height(verts, tris, tri_class)
    verts[:, 2] -= floor_z

    coloured = True
    if all(p in vnames for p in ("red", "green", "blue")):
        vcol = np.stack([vdata[c] for c in ("red", "green", "blue")], axis=1).astype(np.float64)
        vcol = vcol * 255.0 if vcol.max() <= 1.0 and vdata["red"].dtype.kind == "f" else vcol
        albedo = vcol[tris].mean(axis=1)
    elif all(p in fnames for p in ("red", "green", "blue")):
        albedo = np.stack([fdata[c] for c in ("red", "green", "blue")], axis=1).astype(np.float64)[owner]
    else:
        albedo, coloured = np.full((len(tris), 3), DEFAULT_ALBEDO, dtype=np.float64), False

    inst_prop = next((p for p in INSTANCE_PROPERTIES if p in fnames or p in vnames), None)
    if inst_prop is not None:
        raw_inst = per_face_prop(inst_prop)
        key = np.where((raw_inst >= 0) & (tri_class != VOID), raw_inst * (NUM_CLASSES + 1) + tri_class, -1)
        _, inst = np.unique(key, return_inverse=True)   # split instances that span classes
        inst = np.where(key >= 0, inst - (key < 0).any(), -1)
    else:
        inst = _components(tri_class, tris, len(verts))
    return Scene(
        name=name or path.stem, vertices=verts, triangles=tris, tri_class=tri_class, tri_instance=inst,
        tri_albedo=np.clip(np.round(albedo), 0, 255), tri_texture=np.full(len(tris), Texture.PLAIN),
        floor_z=0.0, meta={"source": str(path), "closed_solids": False, **({"lighting": "baked"} if coloured else {}),
                           "up_axis": up_axis, "floor_offset_m": floor_z,
                           "label_property": label_property, "instance_source": inst_prop or "components"},
    )
