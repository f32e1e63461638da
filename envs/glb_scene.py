"""What HM3D and MP3D scenes share on their way into a ``Scene``: a GLB's colours, raw category
names as calnav classes, and labels carried from a separate semantic mesh onto the render mesh.

- ``glb_colours(mesh)``: per-face albedo (base colour factor x ``COLOR_0``), and for faces whose
  material has a JPEG / PNG base colour texture the texture coordinates and decoded images
  (``Scene.tri_uv`` / ``tri_material`` / ``textures``). Basis Universal / KTX2 textures are not
  decodable here: such faces stay grey and the reason comes back for ``meta["rgb_unavailable"]``.
- ``name_classes(names, label_map)``: raw names (HM3D's free text, MP3D's mpcat40) as calnav
  class ids: the label map first (``{raw name: class name or null}``), then the name itself
  through ``common.ply_labels`` (exact, then synonyms); anything else is void.
- ``label_settings(scene_file, scene_id, root)``: the label map of a scene: ``<id>.labels.json``
  or ``labels.json`` in the scene's folder or the nearest folder above it (up to ``root``).
- ``transfer_faces(...)``: which semantic-mesh face each render-mesh face lies on (habitat-sim
  renders the semantic mesh on its own; calnav keeps one mesh, so the labels move onto the render
  faces): the semantic face with the nearest centroid, kept when it is within that face's longest
  edge (plus ``TRANSFER_GAP_M``), else none. One k-d tree query, no loop per face; meshes with the
  same faces in the same order (HM3D's semantic mesh is often the render mesh) match face by face.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calnav.common.ply_labels import class_ids_of, class_index, normalise_name
from calnav.envs.gltf import GlbMesh, decode_image
from calnav.envs.scene import SceneError
from calnav.envs.semantics import CLASS_NAMES, VOID

DEFAULT_GREY = 180           # albedo of faces whose colour cannot be decoded (as envs.scan's uncoloured PLYs), uint8
TRANSFER_GAP_M = 0.05        # how far a render face's centroid may sit off its semantic face's extent, metres
LABEL_FILE = "labels.json"   # a folder's label map (a scene's own: <id>.labels.json)
# A GLB's winding decides what is walkable, as in habitat-sim: Recast marks a triangle walkable
# by its normal from the file's winding (glTF: counter-clockwise faces the viewer), so a
# reconstruction's ceiling, which faces down into the room, is never ground; judged by |normal|
# (``envs.navmesh.closed_solids`` False) it would be, and as the largest surface, the storey
WINDING_FACES_VIEWER = True
_CALNAV_IDS = class_ids_of(CLASS_NAMES)


def glb_colours(mesh: GlbMesh) -> dict:
    """Scene keyword arguments for a GLB's colours: ``tri_albedo`` (F, 3) uint8 and, when any face
    is textured, ``tri_uv`` (F, 3, 2) float32, ``tri_material`` (F,) int16, ``textures`` (list of
    (h, w, 3) uint8) and ``texture_wrap`` (T, 2); plus ``rgb_unavailable`` (str or None): why some
    textures could not be decoded."""
    f = len(mesh.triangles)
    factor = np.ones((f, 3), np.float32)
    if mesh.materials:
        table = np.vstack([np.stack([m.base_color[:3] for m in mesh.materials]), np.ones((1, 3), np.float32)])
        factor = table[mesh.tri_material]   # material -1 reads the extra white row
    if mesh.vertex_color is not None:
        vcol = mesh.vertex_color[mesh.triangles][:, :, :3].mean(axis=1)
        factor = np.where(mesh.has_vertex_color[:, None], factor * vcol, factor)
    tex_of_material = np.array([-1 if m.texture is None else m.texture for m in mesh.materials] + [-1], np.int64)
    face_tex = tex_of_material[mesh.tri_material] if mesh.tri_uv is not None else np.full(f, -1)
    used = set(face_tex.tolist())
    images = [decode_image(t) if k in used else None for k, t in enumerate(mesh.textures)]
    undecoded = sorted({k for k in face_tex.tolist() if k >= 0 and images[k] is None})
    reason = None
    if undecoded:
        basis = any(mesh.textures[k].basis for k in undecoded)
        what = ("Basis Universal / KTX2 textures cannot be decoded here; use the scene's .glb release "
                "(JPEG / PNG textures)" if basis else "its textures are neither JPEG nor PNG")
        reason = f"{mesh.path}: {what}"
    albedo = np.clip(np.round(factor * 255.0), 0, 255).astype(np.uint8)
    lost = np.isin(face_tex, undecoded)
    albedo[lost] = np.clip(np.round(factor[lost] * DEFAULT_GREY), 0, 255).astype(np.uint8)
    out: dict = {"tri_albedo": albedo, "rgb_unavailable": reason}
    kept = [k for k, img in enumerate(images) if img is not None]
    if kept:
        new_index = np.full(len(images) + 1, -1, np.int16)   # the extra slot maps -1 to -1
        new_index[kept] = np.arange(len(kept))
        out.update(tri_uv=mesh.tri_uv, tri_material=new_index[face_tex], textures=[images[k] for k in kept],
                   texture_wrap=np.array([mesh.textures[k].wrap for k in kept], np.int32))
    return out


def name_classes(names: list[str], label_map: dict | None = None) -> np.ndarray:
    """(len(names),) int16 calnav class ids of raw category names (see the module docstring)."""
    table = {normalise_name(k): v for k, v in (label_map or {}).items()}
    out = np.full(len(names), VOID, np.int16)
    for i, name in enumerate(names):
        key = normalise_name(name)
        target = table[key] if key in table else name
        found = None if target is None else class_index(target, _CALNAV_IDS)
        out[i] = VOID if found is None else found
    return out


def label_settings(scene_file: Path, scene_id: str, root: Path | None = None) -> tuple[dict | None, Path | None]:
    """(label map ``{raw name: class name or null}`` or None, the file it came from) of a scene:
    ``<id>.labels.json`` or ``labels.json`` in the scene's folder, else in the nearest folder
    above it holding one (up to ``root``). The file holds the map itself or ``{"label_map": {...}}``."""
    folder = scene_file.resolve().parent
    stop = root.resolve() if root is not None else None
    while True:
        for cand in (folder / f"{scene_id}.labels.json", folder / LABEL_FILE):
            if cand.is_file():
                return _read_label_map(cand), cand
        if folder == stop or folder.parent == folder:
            return None, None
        folder = folder.parent


def _read_label_map(path: Path) -> dict:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise SceneError(f"unreadable label file {path}: {exc}") from None
    if isinstance(data, dict) and "label_map" in data:
        unknown = set(data) - {"label_map"}
        if unknown:
            raise SceneError(f"{path}: unknown keys {sorted(unknown)} for a GLB scene's label file; valid: label_map")
        data = data["label_map"]
    if not isinstance(data, dict) or not all(isinstance(v, (str, type(None))) for v in data.values()):
        raise SceneError(f"{path}: a label map is an object {{raw name: calnav class name or null}}")
    return data


def transfer_faces(dst_verts: np.ndarray, dst_tris: np.ndarray, src_verts: np.ndarray,
                   src_tris: np.ndarray) -> np.ndarray:
    """(F_dst,) int64: the ``src`` face each ``dst`` face lies on, -1 where none is near (see the
    module docstring). Vertices (V, 3) in one frame, metres; triangles (F, 3)."""
    from scipy.spatial import cKDTree

    src = src_verts[src_tris]
    if len(dst_tris) == len(src_tris) and np.array_equal(dst_verts[dst_tris], src):
        return np.arange(len(src_tris), dtype=np.int64)   # the same faces in the same order: each is its own match
    src_c = src.mean(axis=1)
    reach = np.max(np.linalg.norm(src - np.roll(src, 1, axis=1), axis=2), axis=1) + TRANSFER_GAP_M
    dist, idx = cKDTree(src_c).query(dst_verts[dst_tris].mean(axis=1), workers=-1)
    return np.where(dist <= reach[idx], idx, -1).astype(np.int64)
