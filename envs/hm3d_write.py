"""calnav scenes written in HM3D's layout, for habitat-sim and for calnav's own HM3D reader.

``write_hm3d_scene(scene, folder, scene_id)`` writes, in GLB z-up coordinates (calnav's frame,
which HM3D's ``up [0, 0, 1], front [0, 1, 0]`` maps to habitat's world as calnav's episodes do):

- ``<id>.glb``: the geometry with a baked colour texture: one texel per triangle in a square PNG
  atlas holding the renderer's lit colour of that triangle (``envs.render.lit_albedo``), every
  corner's UV at its texel's centre, nearest filtering. A texture rather than vertex colours:
  it is what HM3D's render meshes are (textured, lighting baked, rendered flat), and habitat-sim
  would otherwise interpolate colours across faces that share vertices.
- ``<id>.semantic.glb``: the same faces with the instance colours in a semantic texture (one
  texel per triangle, PNG: lossless, as texel colours are matched exactly) and the same colours
  as ``COLOR_0`` linear floats (HM3D v0.2's semantic meshes carry both; habitat-sim converts the
  vertex colours linear -> sRGB before matching).
- ``<id>.semantic.txt``: ``HM3D Semantic Annotations``, then ``id,RRGGBB,"name",region`` per
  object: calnav instance i is id i + 1 (0 is HM3D's unannotated), a labelled face without an
  instance joins one object per class, void faces are colour 000000; the name is the calnav
  class, the region the index of the room holding the object's centroid (-1: none).

The GLBs are pygltflib documents (its ``GLTF2``, ``Accessor``, ``Material``, ... classes) saved with
pygltflib. ``write_scene_dataset_config(root)`` writes habitat-sim's scene dataset config for the scenes
under ``root`` with HM3D's semantic stage defaults.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pygltflib as g

from calnav.common.atomic import atomic_path
from calnav.envs.hm3d import HM3D_HEADER, linear_from_srgb
from calnav.envs.render import lit_albedo
from calnav.envs.scene import Scene
from calnav.envs.scene_frame import CONFIG_SUFFIX
from calnav.envs.semantics import VOID

_GOLDEN = 0x9E3779                    # odd: id * _GOLDEN mod 2^24 is a bijection, spreading neighbouring ids
_ID_CHARS = re.compile(r"^[A-Za-z0-9_-]+$")


def _atlas(colours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((s, s, 3) uint8 atlas with texel k = colours[k], (F, 3, 2) float32 corner UVs at each
    triangle's texel centre). colours: (F, 3) uint8."""
    f = len(colours)
    side = max(1, int(np.ceil(np.sqrt(f))))
    atlas = np.zeros((side * side, 3), np.uint8)
    atlas[:f] = colours
    k = np.arange(f)
    uv = np.stack([(k % side + 0.5) / side, (k // side + 0.5) / side], axis=1).astype(np.float32)
    return atlas.reshape(side, side, 3), np.repeat(uv[:, None, :], 3, axis=1)


def _png(image: np.ndarray) -> bytes:
    import cv2

    ok, data = cv2.imencode(".png", np.ascontiguousarray(image[:, :, ::-1]))
    if not ok:
        raise ValueError("PNG encoding failed")
    return data.tobytes()


def _textured_glb(positions: np.ndarray, tri_uv: np.ndarray, image: np.ndarray,
                  vertex_colour: np.ndarray | None = None) -> bytes:
    """A GLB of unshared-vertex triangles: positions (F, 3, 3) float32, tri_uv (F, 3, 2), the base
    colour texture ``image`` (h, w, 3) uint8 and optional COLOR_0 (F, 3, 3) float32 linear."""
    f = len(positions)
    flat = positions.reshape(-1, 3).astype("<f4")
    parts = [(flat.tobytes(), g.ARRAY_BUFFER), (tri_uv.reshape(-1, 2).astype("<f4").tobytes(), g.ARRAY_BUFFER),
             (np.arange(3 * f, dtype="<u4").tobytes(), g.ELEMENT_ARRAY_BUFFER)]
    if vertex_colour is not None:
        parts.append((vertex_colour.reshape(-1, 3).astype("<f4").tobytes(), g.ARRAY_BUFFER))
    parts.append((_png(image), None))   # an image's buffer view has no target
    views, blob = [], bytearray()
    for data, target in parts:
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob.extend(data)
        blob.extend(b"\0" * (-len(data) % 4))
    accessors = [   # POSITION's min / max are required, and are those of the float32 values stored
        g.Accessor(bufferView=0, componentType=g.FLOAT, count=3 * f, type=g.VEC3,
                   min=flat.min(axis=0).tolist(), max=flat.max(axis=0).tolist()),
        g.Accessor(bufferView=1, componentType=g.FLOAT, count=3 * f, type=g.VEC2),
        g.Accessor(bufferView=2, componentType=g.UNSIGNED_INT, count=3 * f, type=g.SCALAR),
    ]
    attributes = g.Attributes(POSITION=0, TEXCOORD_0=1)
    if vertex_colour is not None:
        accessors.append(g.Accessor(bufferView=3, componentType=g.FLOAT, count=3 * f, type=g.VEC3))
        attributes.COLOR_0 = 3
    material = g.Material(pbrMetallicRoughness=g.PbrMetallicRoughness(baseColorTexture=g.TextureInfo(index=0),
                                                                      metallicFactor=0.0),
                          extensions={"KHR_materials_unlit": {}})
    doc = g.GLTF2(
        asset=g.Asset(generator="calnav envs.hm3d_write"), scene=0, scenes=[g.Scene(nodes=[0])],
        nodes=[g.Node(mesh=0)],
        meshes=[g.Mesh(primitives=[g.Primitive(attributes=attributes, indices=2, material=0)])],
        materials=[material], extensionsUsed=["KHR_materials_unlit"],
        textures=[g.Texture(source=0, sampler=0)],
        samplers=[g.Sampler(magFilter=g.NEAREST, minFilter=g.NEAREST, wrapS=g.CLAMP_TO_EDGE, wrapT=g.CLAMP_TO_EDGE)],
        images=[g.Image(bufferView=len(views) - 1, mimeType=g.IMAGEPNG)],
        accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))])
    doc.set_binary_blob(bytes(blob))
    return b"".join(doc.save_to_bytes())


def semantic_objects(scene: Scene) -> tuple[np.ndarray, list[tuple[int, int, str, int]]]:
    """((F,) int64 HM3D object id per face, 0 = unannotated; [(id, colour, name, region)] in id
    order), as the module docstring describes."""
    labelled = scene.tri_class != VOID
    ids = np.where(labelled & (scene.tri_instance >= 0), scene.tri_instance.astype(np.int64) + 1, 0)
    loose = labelled & (scene.tri_instance < 0)
    if loose.any():   # one object per class for labelled faces without an instance
        _, which = np.unique(scene.tri_class[loose], return_inverse=True)
        ids[loose] = int(ids.max()) + 1 + which.ravel()
    annotated = np.flatnonzero(ids > 0)
    oids, first, inverse = np.unique(ids[annotated], return_index=True, return_inverse=True)
    sums = np.zeros((len(oids), 3))
    np.add.at(sums, inverse.ravel(), scene.vertices[scene.triangles[annotated]].mean(axis=1))
    centre = sums / np.bincount(inverse.ravel(), minlength=len(oids))[:, None]
    objects = []
    for k, oid in enumerate(oids.tolist()):
        cls = int(scene.tri_class[annotated[first[k]]])
        region = next((r for r, room in enumerate(scene.rooms) if room.contains(*centre[k, :2].tolist())), -1)
        objects.append((oid, (oid * _GOLDEN) % (1 << 24), scene.class_names[cls], region))
    return ids, objects


def write_hm3d_scene(scene: Scene, folder: str | Path, scene_id: str) -> dict[str, Path]:
    """Write ``scene`` as HM3D scene ``scene_id`` into ``folder`` (created): returns the paths
    {"glb", "semantic_glb", "semantic_txt"}. ValueError for a scene id that is not a plain file
    name (letters, digits, '_', '-'), before anything is written."""
    if not _ID_CHARS.match(str(scene_id)):
        raise ValueError(f"scene id {scene_id!r} must be letters, digits, '_' or '-' (it names the files "
                         f"<id>.glb, <id>.semantic.glb, <id>.semantic.txt)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    positions = scene.vertices[scene.triangles]
    atlas, tri_uv = _atlas(lit_albedo(scene))
    ids, objects = semantic_objects(scene)
    colour_of = np.zeros(int(ids.max()) + 1, np.int64)
    for oid, colour, _, _ in objects:
        colour_of[oid] = colour
    face_colour = colour_of[ids]
    rgb = np.stack([(face_colour >> 16) & 255, (face_colour >> 8) & 255, face_colour & 255], axis=1).astype(np.uint8)
    sem_atlas, sem_uv = _atlas(rgb)
    vertex_colour = np.repeat(linear_from_srgb(rgb)[:, None, :], 3, axis=1)
    lines = [HM3D_HEADER] + [f'{oid},{colour:06X},"{name}",{region}' for oid, colour, name, region in objects]
    out = {"glb": folder / f"{scene_id}.glb", "semantic_glb": folder / f"{scene_id}.semantic.glb",
           "semantic_txt": folder / f"{scene_id}.semantic.txt"}
    payloads = {"glb": _textured_glb(positions, tri_uv, atlas),
                "semantic_glb": _textured_glb(positions, sem_uv, sem_atlas, vertex_colour),
                "semantic_txt": ("\n".join(lines) + "\n").encode()}
    for key, path in out.items():
        with atomic_path(path) as tmp:
            Path(tmp).write_bytes(payloads[key])
    return out


def write_scene_dataset_config(root: str | Path, name: str = "calnav_hm3d", up=(0.0, 0.0, 1.0),
                               front=(0.0, 1.0, 0.0)) -> Path:
    """Write ``<root>/<name>.scene_dataset_config.json``: habitat-sim's schema with HM3D's stage
    defaults (``up``, ``front``, origin 0, flat shading, the semantic descriptor and asset named
    after each stage, ``has_semantic_textures``), listing every ``<id>.glb`` scene under ``root``
    by its relative path. Returns the path."""
    from calnav.envs.scene_files import scene_files_in

    root = Path(root)
    stages = sorted(str(p.relative_to(root)) for p in scene_files_in(root).values() if p.suffix == ".glb")
    doc = {
        "stages": {
            "default_attributes": {
                "origin": [0.0, 0.0, 0.0], "up": [float(x) for x in up], "front": [float(x) for x in front],
                "shader_type": "flat",
                "semantic_descriptor_filename": "%%CONFIG_NAME_AS_ASSET_FILENAME%%.semantic.txt",
                "semantic_asset": "%%CONFIG_NAME_AS_ASSET_FILENAME%%.semantic.glb",
                "has_semantic_textures": True,
            },
            "paths": {".glb": stages},
        },
        "objects": {}, "light_setups": {},
        "scene_instances": {"default_attributes": {"default_lighting": "no_lights"}, "paths": {".json": []}},
    }
    path = root / f"{name}{CONFIG_SUFFIX}"
    root.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=2) + "\n")
    return path
