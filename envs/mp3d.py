"""Matterport3D scenes (habitat's layout, ``mp3d/<id>/``) as calnav ``Scene``s.

A scene ``<id>``'s folder holds ``<id>.glb`` (geometry, JPEG textures), ``<id>.house`` and
``<id>_semantic.ply``. As in habitat-sim:

- ``<id>.house`` (``Mp3dSemanticScene.cpp``): first line ``ASCII 1.1``; ``C`` lines
  ``C category_index category_mapping_index category_mapping_name mpcat40_index mpcat40_name ...``
  (``#`` stands for a space in the raw name), ``O`` lines ``O object_index region_index
  category_index ...`` (category -1: none; the index counts ``C`` lines in file order).
- ``<id>_semantic.ply``: its own mesh, per-face ``object_id`` (the ``O`` line's index; -1 =
  none), z-up ("MP3D semantic PLY meshes have -Z gravity"); habitat renders it as the semantic
  sensor's mesh while RGB and depth come from the GLB.
- the GLB's frame: a scene dataset config's when one is found, else habitat-sim's default for a
  ``.glb`` stage (up +z, front +y), which its comment says was chosen for MP3D.

calnav keeps one mesh: the GLB's faces (so depth and RGB are the GLB's, as in habitat), each
taking the object of the semantic face it lies on (``envs.glb_scene.transfer_faces``; faces
matching none are void, counted in ``meta["unmatched_faces"]``). Objects keep their ids as
instances; their mpcat40 names become calnav classes (chair, bed, plant, toilet, tv_monitor, sofa,
table, cabinet, shelving -> shelf, counter, sink, bathtub, stool, floor, wall, ceiling, door; a
``labels.json`` may map others); every other category is void.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calnav.envs.glb_scene import WINDING_FACES_VIEWER, glb_colours, label_settings, name_classes, transfer_faces
from calnav.envs.gltf import read_glb
from calnav.envs.scene import RGB_UNAVAILABLE, SEMANTICS_UNAVAILABLE, Scene, SceneError, Texture
from calnav.envs.scene_frame import place_on_floor, scene_frame
from calnav.envs.semantics import VOID

HOUSE_HEADER = "ASCII 1.1"
OBJECT_ID_PROPERTIES = ("object_id", "objectId")


def read_house(path: str | Path) -> dict[int, str]:
    """{object index: mpcat40 name ("" for an object without category)} of an MP3D ``.house``
    file. SceneError naming the file and line for a wrong header or a malformed C / O line."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise SceneError(f"unreadable MP3D house file {path}: {exc}") from None
    if not lines or lines[0].strip() != HOUSE_HEADER:
        raise SceneError(f"{path}: the first line must be {HOUSE_HEADER!r} (habitat-sim's MP3D house format)")
    categories: list[str] = []
    objects: dict[int, int] = {}
    for number, line in enumerate(lines[1:], start=2):
        tokens = line.split()
        if not tokens or tokens[0] not in ("C", "O"):
            continue
        try:
            index = int(tokens[1])
            if tokens[0] == "C":   # C category_index mapping_index mapping_name mpcat40_index mpcat40_name
                name = tokens[5]
            else:                  # O object_index region_index category_index ...
                category = int(tokens[3])
        except (IndexError, ValueError):
            raise SceneError(f"{path} line {number}: malformed {tokens[0]} line {line[:80]!r}") from None
        # objects name their category by index: one listed twice or out of order labels another
        if tokens[0] == "C" and index != len(categories):
            raise SceneError(f"{path} line {number}: category index {index} where {len(categories)} comes next; "
                             "the C lines number the categories 0, 1, 2, ... once each")
        if tokens[0] == "O" and index in objects:
            raise SceneError(f"{path} line {number}: object {index} is listed twice; each object has one line")
        if tokens[0] == "C":
            categories.append(name)
        else:
            objects[index] = category
    bad = {o: c for o, c in objects.items() if c >= len(categories)}
    if bad:
        o, c = next(iter(bad.items()))
        raise SceneError(f"{path}: object {o} has category {c}, but the file lists {len(categories)} categories")
    return {o: (categories[c] if c >= 0 else "") for o, c in objects.items()}


def read_semantic_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, triangles (F, 3) int64, object id per face (F,) int64) of an
    MP3D ``_semantic.ply``. SceneError for an unreadable file or one without ``object_id``."""
    from plyfile import PlyData

    path = Path(path)
    try:
        try:   # habitat's files: binary triangles, read as fixed-size lists
            ply = PlyData.read(str(path), known_list_len={"face": {"vertex_indices": 3}})
        except Exception:
            ply = PlyData.read(str(path), mmap=False)
        v, f = ply["vertex"].data, ply["face"].data
        verts = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
        tris = np.stack(list(f["vertex_indices"])).astype(np.int64) if f.dtype["vertex_indices"] == object \
            else np.asarray(f["vertex_indices"], dtype=np.int64)
    except Exception as exc:   # plyfile raises many types for malformed headers / bodies
        raise SceneError(f"corrupt or unparseable PLY {path}: {type(exc).__name__}: {exc}") from None
    prop = next((p for p in OBJECT_ID_PROPERTIES if p in f.dtype.names), None)
    if prop is None:
        raise SceneError(f"{path}: no per-face object_id (face properties: {list(f.dtype.names)}); "
                         "habitat's <id>_semantic.ply is needed")
    if tris.ndim != 2 or tris.shape[1] != 3 or (len(tris) and (tris.min() < 0 or tris.max() >= len(verts))):
        raise SceneError(f"{path}: faces must be triangles with vertex indices in [0, {len(verts)})")
    return verts, tris, np.asarray(f[prop]).astype(np.int64)


def mp3d_files(path: Path) -> dict[str, Path | None]:
    """``house`` and ``semantic_ply`` beside the MP3D ``<id>.glb`` ``path`` (None when absent)."""
    house, ply = path.with_suffix(".house"), path.with_name(f"{path.stem}_semantic.ply")
    return {"house": house if house.is_file() else None, "semantic_ply": ply if ply.is_file() else None}


def load_mp3d_scene(path: str | Path, root: Path | None = None, config: Path | None = None,
                    name: str | None = None) -> Scene:
    """The MP3D scene whose ``<id>.glb`` is ``path`` (see the module docstring). root: the scene
    directory (highest folder searched for a config and a label map); config: an explicit scene
    dataset config. Without the ``.house`` / ``_semantic.ply`` pair it loads for geometry and RGB
    and says why in ``meta["semantics_unavailable"]``."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"MP3D scene file not found: {path}")
    files = mp3d_files(path)
    frame = scene_frame(path, root, config)
    label_map, label_file = label_settings(path, path.stem, root)
    render = read_glb(path)
    f = len(render.triangles)
    tri_class, tri_instance = np.full(f, VOID, np.int16), np.full(f, -1, np.int32)
    meta: dict = {}
    if files["house"] is None or files["semantic_ply"] is None:
        missing = [n for n, p in ((f"{path.stem}.house", files["house"]),
                                  (f"{path.stem}_semantic.ply", files["semantic_ply"])) if p is None]
        meta[SEMANTICS_UNAVAILABLE] = f"{path.parent}: {' and '.join(missing)} not found (MP3D's habitat release has them)"
    else:
        names = read_house(files["house"])
        sem_v, sem_t, sem_obj = read_semantic_ply(files["semantic_ply"])
        stray = sorted(set(np.unique(sem_obj[sem_obj >= 0]).tolist()) - set(names))
        if stray:
            raise SceneError(f"{files['semantic_ply']}: object ids {stray[:5]}{' ...' if len(stray) > 5 else ''} "
                             f"have no O line in {files['house']}; the two files are of different scenes")
        ids = np.array(sorted(names), np.int64)
        lut = np.full(int(max(ids.max(initial=0), sem_obj.max(initial=0))) + 1, VOID, np.int16)   # object -> class
        lut[ids] = name_classes([names[i] for i in ids.tolist()], label_map)
        sem_class = np.where(sem_obj >= 0, lut[np.maximum(sem_obj, 0)], VOID).astype(np.int16)
        # the semantic PLY is z-up in calnav's axes; the GLB goes through its stage frame first
        match = transfer_faces(render.positions @ frame.rotation().T, render.triangles, sem_v, sem_t)
        hit = match >= 0
        tri_class[hit] = sem_class[match[hit]]
        tri_instance[hit] = np.where(tri_class[hit] != VOID, sem_obj[match[hit]], -1)
        meta.update(unmatched_faces=int((~hit).sum()), semantic_source=str(files["semantic_ply"]))
        if (tri_class == VOID).all():
            meta[SEMANTICS_UNAVAILABLE] = (f"{files['house']}: none of its categories maps to a calnav class; "
                                           "map them in a labels.json")
    verts, floor_z = place_on_floor(render.positions, render.triangles, tri_class, frame)
    colours = glb_colours(render)
    rgb_reason = colours.pop("rgb_unavailable")
    meta.update({"source": str(path), "format": "mp3d",
                 "frame": {"up": list(frame.up), "front": list(frame.front), "source": frame.source},
                 "floor_offset_m": floor_z, "closed_solids": WINDING_FACES_VIEWER, "lighting": "baked",
                 **({"label_map_file": str(label_file)} if label_file else {}),
                 **({RGB_UNAVAILABLE: rgb_reason} if rgb_reason else {})})
    return Scene(name=name or path.stem, vertices=verts, triangles=render.triangles, tri_class=tri_class,
                 tri_instance=tri_instance, tri_texture=np.full(f, Texture.PLAIN), meta=meta, **colours)
