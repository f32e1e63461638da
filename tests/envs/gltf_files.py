"""Small GLB files built per the glTF 2.0 spec with pygltflib (independent of calnav's own writer),
and the HM3D / MP3D companions (semantic txt, .house, semantic PLY), for the scene-file tests."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calnav.envs.primitives import box_mesh

FLOAT, UBYTE, UINT32 = 5126, 5121, 5125


@dataclass
class Prim:
    """One primitive: positions (V, 3), triangles (F, 3), optional uv (V, 2), COLOR_0 (V, 3)
    (float linear, or uint8 stored normalized), the index of its material's texture image."""

    positions: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray | None = None
    colour: np.ndarray | None = None
    image: int | None = None
    factor: tuple = (1.0, 1.0, 1.0, 1.0)


@dataclass
class Image:
    """An embedded image: encoded ``data`` and its mime type; ``basis`` puts it behind
    ``extension`` (KHR_texture_basisu / GOOGLE_texture_basis) as Basis textures are."""

    data: bytes
    mime: str = "image/png"
    wrap: tuple[int, int] = (10497, 10497)
    extension: str | None = None
    extras: dict = field(default_factory=dict)


def png(rgb: np.ndarray) -> bytes:
    import io

    from PIL import Image as PILImage

    buf = io.BytesIO()
    PILImage.fromarray(np.asarray(rgb, np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def jpeg(rgb: np.ndarray, quality: int = 95) -> bytes:
    import io

    from PIL import Image as PILImage

    buf = io.BytesIO()
    PILImage.fromarray(np.asarray(rgb, np.uint8)).save(buf, format="JPEG", quality=quality)
    return buf.getvalue()


def write_glb(path: Path, prims: list[Prim], images: list[Image] = (), matrix=None) -> Path:
    """A GLB with one mesh of ``prims`` under one node (column-major ``matrix`` when given)."""
    import pygltflib as g

    blob = bytearray()
    views, accessors = [], []

    def add(arr: np.ndarray, ctype: int, kind: str, normalized: bool = False, minmax: bool = False) -> int:
        data = np.ascontiguousarray(arr).tobytes()
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data)))
        blob.extend(data + b"\0" * (-len(data) % 4))
        acc = g.Accessor(bufferView=len(views) - 1, componentType=ctype, count=len(arr), type=kind,
                         normalized=normalized or None)
        if minmax:
            acc.min, acc.max = arr.min(axis=0).tolist(), arr.max(axis=0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    gl_images, textures, samplers, materials, primitives, used_ext = [], [], [], [], [], set()
    for im in images:
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(im.data)))
        blob.extend(im.data + b"\0" * (-len(im.data) % 4))
        gl_images.append(g.Image(bufferView=len(views) - 1, mimeType=im.mime))
        samplers.append(g.Sampler(wrapS=im.wrap[0], wrapT=im.wrap[1]))
        k = len(gl_images) - 1
        if im.extension:
            used_ext.add(im.extension)
            textures.append(g.Texture(sampler=k, extensions={im.extension: {"source": k}}))
        else:
            textures.append(g.Texture(sampler=k, source=k))
    for p in prims:
        attrs = g.Attributes(POSITION=add(np.asarray(p.positions, "<f4"), FLOAT, "VEC3", minmax=True))
        if p.uv is not None:
            attrs.TEXCOORD_0 = add(np.asarray(p.uv, "<f4"), FLOAT, "VEC2")
        if p.colour is not None:
            c = np.asarray(p.colour)
            attrs.COLOR_0 = (add(c.astype(np.uint8), UBYTE, "VEC3", normalized=True) if c.dtype == np.uint8
                             else add(c.astype("<f4"), FLOAT, "VEC3"))
        idx = add(np.asarray(p.triangles, "<u4").ravel(), UINT32, "SCALAR")
        pbr = g.PbrMetallicRoughness(baseColorFactor=list(p.factor))
        if p.image is not None:
            pbr.baseColorTexture = g.TextureInfo(index=p.image)
        materials.append(g.Material(pbrMetallicRoughness=pbr))
        primitives.append(g.Primitive(attributes=attrs, indices=idx, material=len(materials) - 1))
    node = g.Node(mesh=0, matrix=list(np.asarray(matrix, float).T.ravel()) if matrix is not None else None)
    doc = g.GLTF2(scene=0, scenes=[g.Scene(nodes=[0])], nodes=[node], meshes=[g.Mesh(primitives=primitives)],
                  accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))],
                  images=gl_images, textures=textures, samplers=samplers, materials=materials,
                  extensionsUsed=sorted(used_ext), extensionsRequired=sorted(used_ext))
    doc.set_binary_blob(bytes(blob))
    doc.save_binary(str(path))
    return path


def floor_quad(half: float = 2.0, z: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A (2 half)^2 m floor quad at height z: positions (4, 3), triangles (2, 3), uv (4, 2) over the
    whole image (u along +x, v along -y: the image's top row at +y)."""
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], float)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]]), uv


def box_chair(center=(0.5, 0.5, 0.25), size=(0.5, 0.5, 0.5)) -> tuple[np.ndarray, np.ndarray]:
    """A box (8 vertices, 12 triangles) standing on z = 0."""
    return box_mesh(center, size)


def semantic_txt(path: Path, rows: list[tuple[int, str, str, int]], header: str = "HM3D Semantic Annotations") -> Path:
    """rows: (id, RRGGBB, raw name, region)."""
    lines = [header] + [f'{i},{c},"{n}",{r}' for i, c, n, r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def to_y_up(v: np.ndarray) -> np.ndarray:
    """z-up coordinates as a y-up (glTF) file stores them: (x, y, z) -> (x, z, -y)."""
    return np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)


def hm3d_config(path: Path, up=(0, 0, 1), front=(0, 1, 0), textures: bool = True) -> Path:
    """A scene dataset config with HM3D's stage defaults (habitat-sim's schema)."""
    import json

    path.write_text(json.dumps({"stages": {"default_attributes": {
        "origin": [0, 0, 0], "up": list(up), "front": list(front), "shader_type": "flat",
        "semantic_descriptor_filename": "%%CONFIG_NAME_AS_ASSET_FILENAME%%.semantic.txt",
        "semantic_asset": "%%CONFIG_NAME_AS_ASSET_FILENAME%%.semantic.glb",
        "has_semantic_textures": textures}, "paths": {".glb": ["*/*.glb"]}}}))
    return path


def large_hm3d_scene(folder: Path, n_tris: int = 1_000_000, texture_side: int = 2048, sid: str = "big",
                     seed: int = 0) -> Path:
    """An HM3D scene folder of HM3D's size: a 12 x 10 x 3 m room whose floor, four walls and
    ceiling are grids of ``n_tris`` triangles in all (shared vertices), each surface with its own
    ``texture_side``^2 JPEG colour texture (noise: JPEG's worst case), and a semantic GLB of the
    same faces whose instance colours (floor, wall, ceiling) come from small PNG textures."""
    rng = np.random.default_rng(seed)
    w, d, h = 12.0, 10.0, 3.0
    # (origin, edge u, edge v, area share) per surface: floor, ceiling, walls at y = 0 / d, x = 0 / w
    surfaces = [((0, 0, 0), (w, 0, 0), (0, d, 0)), ((0, 0, h), (w, 0, 0), (0, d, 0)),
                ((0, 0, 0), (w, 0, 0), (0, 0, h)), ((0, d, 0), (w, 0, 0), (0, 0, h)),
                ((0, 0, 0), (0, d, 0), (0, 0, h)), ((w, 0, 0), (0, d, 0), (0, 0, h))]
    areas = np.array([np.linalg.norm(np.cross(u, v)) for _, u, v in surfaces])
    prims, sem_prims, images, sem_images = [], [], [], []
    names = ["floor", "ceiling", "wall", "wall", "wall", "wall"]
    ids = {"floor": (1, "1E90FF"), "ceiling": (2, "FFD700"), "wall": (3, "32CD32")}
    for k, ((o, u, v), share) in enumerate(zip(surfaces, areas / areas.sum())):
        cells = max(1, int(np.sqrt(n_tris * share / 2)))
        gu, gv = np.meshgrid(np.linspace(0, 1, cells + 1), np.linspace(0, 1, cells + 1))
        pos = np.asarray(o) + gu.reshape(-1, 1) * np.asarray(u) + gv.reshape(-1, 1) * np.asarray(v)
        i = np.arange(cells)[None, :] + (cells + 1) * np.arange(cells)[:, None]
        quads = np.stack([i, i + 1, i + cells + 2, i + cells + 1], axis=-1).reshape(-1, 4)
        tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        uv = np.stack([gu.ravel(), gv.ravel()], axis=1) * 4.0           # each texture repeats 4 x 4 times
        prims.append(Prim(pos, tris, uv=uv, image=k))
        images.append(Image(jpeg(rng.integers(0, 255, (texture_side, texture_side, 3), dtype=np.uint8), 90),
                            mime="image/jpeg"))
        colour = ids[names[k]][1]
        sem_images.append(Image(png(np.tile(np.array([int(colour[j:j + 2], 16) for j in (0, 2, 4)], np.uint8),
                                            (8, 8, 1)))))
        sem_prims.append(Prim(pos, tris, uv=uv, image=k))
    folder.mkdir(parents=True, exist_ok=True)
    write_glb(folder / f"{sid}.glb", prims, images)
    write_glb(folder / f"{sid}.semantic.glb", sem_prims, sem_images)
    semantic_txt(folder / f"{sid}.semantic.txt", [(i, c, n, 0) for n, (i, c) in ids.items()])
    return folder / f"{sid}.glb"
