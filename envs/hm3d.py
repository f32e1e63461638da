"""HM3D scenes (habitat's layout, ``hm3d/{train,val,minival}/NNNNN-<id>/``) as calnav ``Scene``s.

A scene ``<id>``'s folder holds ``<id>.glb`` (JPEG / PNG textures) and / or ``<id>.basis.glb``
(Basis Universal textures): the geometry and its colour, the ``.glb`` preferred when both are
there; and, from HM3D-Semantics v0.2, ``<id>.semantic.glb`` with ``<id>.semantic.txt``.

``<id>.semantic.txt`` follows habitat-sim's ``HM3DSemanticScene.cpp``: a first line holding
``HM3D Semantic Annotations``, then one line per object ``id,RRGGBB,"raw name",region`` (the name
may hold commas, never quotes; region -1 = none). The object whose colour a semantic-mesh face
carries is the face's instance (its id kept); colour 000000 / id 0 is unannotated (void). A face's
colour is read from the semantic GLB's base colour texture at three points just inside its
corners (majority; all three differ: the texel at its centroid), texel bytes compared as stored
(habitat-sim's ``convertRGBToSemanticId``), or, where the semantic GLB has no decodable texture
or its scene dataset config says ``has_semantic_textures: false``, from its ``COLOR_0`` vertex
colours converted linear -> sRGB as habitat-sim converts those of a non-PLY semantic mesh
(``BaseMesh::convertMeshColors``: Magnum's ``toSrgb``), per face by vertex majority. A colour
the txt does not list is refused (habitat-sim would map it to id 0 silently).

Raw names become calnav classes through ``envs.glb_scene.name_classes`` (a ``labels.json``
first, then synonyms); the labels move onto the render mesh's faces (``transfer_faces``); the
frame is the scene dataset config's (``envs.scene_frame``). Without the semantic pair the scene
loads for geometry and RGB and says why in ``meta["semantics_unavailable"]``.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calnav.envs.glb_scene import WINDING_FACES_VIEWER, glb_colours, label_settings, name_classes, transfer_faces
from calnav.envs.gltf import GlbMesh, decode_image, read_glb, wrap_texels
from calnav.envs.scan import per_face_majority
from calnav.envs.scene import RGB_UNAVAILABLE, SEMANTICS_UNAVAILABLE, Scene, SceneError, Texture
from calnav.envs.scene_frame import place_on_floor, scene_frame
from calnav.envs.semantics import VOID

HM3D_HEADER = "HM3D Semantic Annotations"
_LINE = re.compile(r'^\s*(\d+)\s*,\s*([0-9A-Fa-f]{6})\s*,\s*"([^"]*)"\s*,\s*(-?\d+)\s*$')
# barycentric weights of the texel look-ups per face: a point just inside each corner (a corner
# itself sits on the texture chart's edge, where the neighbouring chart's texels begin), and the centroid
_SAMPLE_WEIGHTS = np.array([[4, 1, 1], [1, 4, 1], [1, 1, 4], [2, 2, 2]], np.float64) / 6.0


@dataclass(frozen=True)
class SemanticObject:
    """One line of a ``.semantic.txt``: instance id, colour (0xRRGGBB), raw name, region id."""

    id: int
    colour: int
    name: str
    region: int


def scene_id_of(path: Path) -> str:
    """``TEEsavR23oF`` of ``.../TEEsavR23oF.basis.glb`` or ``.../TEEsavR23oF.glb``."""
    name = path.name
    for suffix in (".basis.glb", ".glb"):
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return path.stem


def read_semantic_txt(path: str | Path) -> dict[int, SemanticObject]:
    """{colour: object} of an HM3D ``.semantic.txt`` (see the module docstring); SceneError
    naming the file and line for a wrong header, a malformed line or a repeated id / colour."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"unreadable HM3D semantic file {path}: {exc}") from None
    if not lines or HM3D_HEADER not in lines[0]:
        first = lines[0] if lines else ""
        raise SceneError(f"{path}: the first line must be {HM3D_HEADER!r} (habitat-sim's header), got {first[:60]!r}")
    objects: dict[int, SemanticObject] = {}
    ids: set[int] = set()
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        m = _LINE.match(line)
        if m is None:
            raise SceneError(f'{path} line {number}: expected id,RRGGBB,"raw name",region_id, got {line[:80]!r}')
        obj = SemanticObject(int(m.group(1)), int(m.group(2), 16), m.group(3), int(m.group(4)))
        if obj.id in ids or obj.colour in objects:
            what = f"id {obj.id}" if obj.id in ids else f"colour {obj.colour:06X}"
            raise SceneError(f"{path} line {number}: {what} is listed twice; each object has one id and one colour")
        ids.add(obj.id)
        objects[obj.colour] = obj
    return objects


def srgb_bytes(linear: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 sRGB of linear colours in [0, 1] (Magnum's ``Color3::toSrgb<UnsignedByte>``:
    12.92 c below 0.0031308, else 1.055 c^(1/2.4) - 0.055, rounded)."""
    c = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def linear_from_srgb(srgb: np.ndarray) -> np.ndarray:
    """(..., 3) float64 linear colours of sRGB bytes (the inverse of ``srgb_bytes``)."""
    s = np.asarray(srgb, dtype=np.float64) / 255.0
    return np.where(s <= 0.04045, s / 12.92, np.power((s + 0.055) / 1.055, 2.4))


def _colour_ints(rgb: np.ndarray) -> np.ndarray:
    rgb = rgb.astype(np.int64)
    return (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]


def _texture_colours(mesh: GlbMesh, faces: np.ndarray, image: np.ndarray, wrap: tuple[int, int]) -> np.ndarray:
    """(len(faces),) colour ints of the texels under each face (majority of three inner points;
    all differ: the centroid's)."""
    uv = np.einsum("sk,fkc->fsc", _SAMPLE_WEIGHTS, mesh.tri_uv[faces].astype(np.float64))
    h, w = image.shape[:2]
    ix = wrap_texels(uv[..., 0], w, wrap[0])
    iy = wrap_texels(uv[..., 1], h, wrap[1])
    col = _colour_ints(image[iy, ix])                    # (n, 4)
    vote = per_face_majority(col[:, :3].ravel(), np.arange(3 * len(faces)).reshape(-1, 3))
    a, b, c = col[:, 0], col[:, 1], col[:, 2]
    return np.where((a != b) & (a != c) & (b != c), col[:, 3], vote)


def semantic_face_colours(mesh: GlbMesh, use_textures: bool | None) -> tuple[np.ndarray, str]:
    """((F,) int64 colour per semantic-mesh face, -1 where it carries none; how they were read).
    ``use_textures`` False (the config's ``has_semantic_textures``) reads vertex colours only."""
    f = len(mesh.triangles)
    colours = np.full(f, -1, np.int64)
    sources = []
    if use_textures is not False and mesh.tri_uv is not None:
        for m, material in enumerate(mesh.materials):
            faces = np.flatnonzero(mesh.tri_material == m)
            if material.texture is None or not len(faces):
                continue
            tex = mesh.textures[material.texture]
            image = decode_image(tex)
            if image is not None:
                colours[faces] = _texture_colours(mesh, faces, image, tex.wrap)
                sources.append("texture")
    if mesh.vertex_color is not None:
        todo = (colours < 0) & mesh.has_vertex_color
        if todo.any():
            vint = _colour_ints(srgb_bytes(mesh.vertex_color[:, :3]))
            colours[todo] = per_face_majority(vint, mesh.triangles[todo])
            sources.append("vertex colours (linear -> sRGB)")
    return colours, " + ".join(dict.fromkeys(sources)) or "none"


def hm3d_files(path: Path) -> dict[str, Path | None]:
    """The files of the HM3D scene whose ``.glb`` / ``.basis.glb`` is ``path``: ``render`` (the
    ``.glb`` when present beside a ``.basis.glb``), ``semantic_glb``, ``semantic_txt`` (None when absent)."""
    sid = scene_id_of(path)
    plain = path.with_name(f"{sid}.glb")
    render = plain if plain.is_file() else path
    sem_glb, sem_txt = path.with_name(f"{sid}.semantic.glb"), path.with_name(f"{sid}.semantic.txt")
    return {"render": render, "semantic_glb": sem_glb if sem_glb.is_file() else None,
            "semantic_txt": sem_txt if sem_txt.is_file() else None}


def _semantics(files: dict, frame, label_map: dict | None) -> tuple[GlbMesh | None, np.ndarray, np.ndarray, dict]:
    """(semantic mesh or None, per semantic face class (F_s,) and instance (F_s,), meta)."""
    sem_glb, sem_txt = files["semantic_glb"], files["semantic_txt"]
    if sem_glb is None or sem_txt is None:
        missing = [p.name for p, have in ((Path(f"{files['sid']}.semantic.glb"), sem_glb),
                                          (Path(f"{files['sid']}.semantic.txt"), sem_txt)) if have is None]
        why = (f"{files['render'].parent}: {' and '.join(missing)} not found; HM3D-Semantics v0.2 "
               "(hm3d-*-semantic-annots-v0.2) provides the pair")
        return None, np.empty(0, np.int16), np.empty(0, np.int32), {SEMANTICS_UNAVAILABLE: why}
    objects = read_semantic_txt(sem_txt)
    mesh = read_glb(sem_glb)
    colours, how = semantic_face_colours(mesh, frame.has_semantic_textures)
    if (colours < 0).all():
        why = f"{sem_glb}: no decodable semantic texture and no COLOR_0 vertex colours to read its instances from"
        return None, np.empty(0, np.int16), np.empty(0, np.int32), {SEMANTICS_UNAVAILABLE: why}
    values, inverse = np.unique(colours, return_inverse=True)
    unknown = [v for v in values.tolist() if v > 0 and v not in objects]
    if unknown:
        counts = {v: int((colours == v).sum()) for v in unknown[:5]}
        listed = ", ".join(f"{v:06X} ({n} faces)" for v, n in counts.items())
        raise SceneError(f"{sem_glb}: semantic colours {listed}{' ...' if len(unknown) > 5 else ''} are not in "
                         f"{sem_txt}; every annotated colour needs a line there (000000 = unannotated)")
    objs = [objects.get(v) if v > 0 else None for v in values.tolist()]
    names = [o.name if o is not None and o.id != 0 else "" for o in objs]
    cls = np.where([n != "" for n in names], name_classes(names, label_map), VOID).astype(np.int16)
    inst = np.array([o.id if o is not None and o.id != 0 else -1 for o in objs], np.int32)
    tri_class = cls[inverse.ravel()]
    tri_instance = np.where(tri_class != VOID, inst[inverse.ravel()], -1).astype(np.int32)
    return mesh, tri_class, tri_instance, {"semantic_source": how, "semantic_objects": len(objects)}


def load_hm3d_scene(path: str | Path, root: Path | None = None, config: Path | None = None,
                    name: str | None = None) -> Scene:
    """The HM3D scene whose ``<id>.glb`` or ``<id>.basis.glb`` is ``path`` (module docstring).
    root: the scene directory, the highest folder searched for a scene dataset config and a label
    map; config: an explicit ``*.scene_dataset_config.json``. SceneError for unreadable files,
    txt grammar or colours the txt does not list (whether its frame leaves it on its floor is
    ``envs.scene_plausible``'s check, as it loads through ``envs.scene_files``)."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"HM3D scene file not found: {path}")
    files = {**hm3d_files(path), "sid": scene_id_of(path)}
    frame = scene_frame(files["render"], root, config)
    label_map, label_file = label_settings(files["render"], files["sid"], root)
    render = read_glb(files["render"])
    sem_mesh, sem_class, sem_inst, meta = _semantics(files, frame, label_map)
    f = len(render.triangles)
    tri_class, tri_instance = np.full(f, VOID, np.int16), np.full(f, -1, np.int32)
    if sem_mesh is not None:
        match = transfer_faces(render.positions, render.triangles, sem_mesh.positions, sem_mesh.triangles)
        hit = match >= 0
        tri_class[hit], tri_instance[hit] = sem_class[match[hit]], sem_inst[match[hit]]
        meta["unmatched_faces"] = int((~hit).sum())
        if (tri_class == VOID).all():
            meta[SEMANTICS_UNAVAILABLE] = (f"{files['semantic_txt']}: none of its names maps to a calnav class; "
                                           "map them in a labels.json")
    verts, floor_z = place_on_floor(render.positions, render.triangles, tri_class, frame)
    colours = glb_colours(render)
    rgb_reason = colours.pop("rgb_unavailable")
    meta.update({"source": str(path), "format": "hm3d", "render_file": str(files["render"]),
                 "frame": {"up": list(frame.up), "front": list(frame.front), "source": frame.source},
                 "floor_offset_m": floor_z, "closed_solids": WINDING_FACES_VIEWER, "lighting": "baked",
                 **({"label_map_file": str(label_file)} if label_file else {}),
                 **({RGB_UNAVAILABLE: rgb_reason} if rgb_reason else {})})
    return Scene(name=name or files["sid"], vertices=verts, triangles=render.triangles, tri_class=tri_class,
                 tri_instance=tri_instance, tri_texture=np.full(f, Texture.PLAIN), meta=meta, **colours)
