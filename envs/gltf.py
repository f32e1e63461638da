"""glTF 2.0 binary files (``.glb``): their triangle meshes flattened into one mesh.

``read_glb(path)`` reads the file with pygltflib (``GLTF2.load_from_bytes``: the JSON chunk as its
document classes, the BIN chunk as ``binary_blob()``) and adds what pygltflib leaves to its
callers: accessors read as numpy views of their buffer views (byteStride, normalized integers; no
Python loop per vertex or face), the default scene's node tree walked applying each node's matrix
or translation / rotation / scale, and every triangle primitive concatenated into a ``GlbMesh``:
positions in the file's own axes (the scene's frame is the caller's business), faces, per-face
texture coordinates, ``COLOR_0`` vertex colours, per-face material and the materials' base colour
textures (their images still encoded: ``decode_image`` turns a JPEG / PNG into RGB; Basis
Universal / KTX2 images are flagged ``basis`` and cannot be decoded here).

Writers build their documents with pygltflib's classes and save them with it. Every unreadable
input is a one-line ``SceneError`` naming the file.
"""
from __future__ import annotations

import base64
import json
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np
import pygltflib
from pygltflib import CLAMP_TO_EDGE, MIRRORED_REPEAT, REPEAT, TRIANGLES

from calnav.envs.scene import SceneError

COMPONENT_DTYPES = {pygltflib.BYTE: np.int8, pygltflib.UNSIGNED_BYTE: np.uint8, pygltflib.SHORT: np.int16,
                    pygltflib.UNSIGNED_SHORT: np.uint16, pygltflib.UNSIGNED_INT: np.uint32, pygltflib.FLOAT: np.float32}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
WRAP_MODES = (REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT)
BASIS_EXTENSIONS = ("KHR_texture_basisu", "GOOGLE_texture_basis")
BASIS_MIME_TYPES = ("image/ktx2", "image/x-basis", "image/basis")
_BASIS_MAGICS = (b"\xabKTX 20\xbb", b"sB")      # KTX2 container, .basis file
# what pygltflib raises on a damaged container or a document of the wrong shape
_PARSE_ERRORS = (struct.error, ValueError, TypeError, AttributeError, KeyError, IndexError)
_T = TypeVar("_T")


@dataclass
class GlbTexture:
    """A base colour texture: ``image`` its encoded bytes, ``mime`` their type, ``basis`` True for
    Basis Universal / KTX2 data, ``wrap`` the sampler's (wrapS, wrapT) glTF codes."""

    image: bytes
    mime: str
    basis: bool
    wrap: tuple[int, int] = (REPEAT, REPEAT)


@dataclass
class GlbMaterial:
    """base_color: (4,) float32 linear RGBA factor; texture: index into ``GlbMesh.textures`` or
    None; tex_coord: which TEXCOORD_n set the texture reads."""

    base_color: np.ndarray
    texture: int | None = None
    tex_coord: int = 0


@dataclass
class GlbMesh:
    """Every triangle primitive of a GLB's default scene in one mesh, in the file's axes.

    positions: (V, 3) float64, node transforms applied. triangles: (F, 3) int64.
    tri_uv: (F, 3, 2) float32 texture coordinates of each face's material's texture set (0 where a
    primitive has none), or None when no primitive has any. vertex_color: (V, 4) float32 ``COLOR_0``
    in [0, 1] as stored (alpha 1 for RGB), or None when no primitive has one (0 where one lacks it).
    has_vertex_color: (F,) bool, the faces whose primitive has ``COLOR_0``. tri_material: (F,) int32
    index into ``materials`` (-1 = none).
    """

    path: Path
    positions: np.ndarray
    triangles: np.ndarray
    tri_uv: np.ndarray | None
    vertex_color: np.ndarray | None
    has_vertex_color: np.ndarray
    tri_material: np.ndarray
    materials: list[GlbMaterial] = field(default_factory=list)
    textures: list[GlbTexture] = field(default_factory=list)


def _load(path: Path, data: bytes) -> pygltflib.GLTF2:
    """The pygltflib document of the GLB bytes ``data`` (its BIN chunk as ``binary_blob()``)."""
    # pygltflib only warns on another container version and reads a truncated file's chunks short,
    # so the 12-byte header is checked first
    if len(data) < 12 or data[:4] != pygltflib.MAGIC:
        raise SceneError(f"{path}: not a binary glTF file (no 'glTF' magic); a .glb is needed")
    version, total = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise SceneError(f"{path}: glTF version {version}; only glTF 2.0 is read")
    if total > len(data):
        raise SceneError(f"corrupt GLB {path}: the header says {total} bytes, the file has {len(data)} (truncated?)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # chunks of unknown type are skipped, as the spec says
            gltf = pygltflib.GLTF2.load_from_bytes(data)
    except json.JSONDecodeError as exc:
        raise SceneError(f"corrupt GLB {path}: its JSON chunk does not parse ({exc})") from None
    except _PARSE_ERRORS as exc:
        raise SceneError(f"corrupt GLB {path}: pygltflib cannot read it ({type(exc).__name__}: {exc})") from None
    if gltf is None:
        raise SceneError(f"corrupt GLB {path}: no JSON chunk")
    return gltf


class _Reader:
    """Buffers, accessors, images and node tree of one loaded GLB."""

    def __init__(self, path: Path, gltf: pygltflib.GLTF2):
        self.path, self.gltf = path, gltf
        self.buffers = [self._buffer(i, b) for i, b in enumerate(gltf.buffers)]

    def fail(self, problem: str) -> SceneError:
        return SceneError(f"{self.path}: {problem}")

    def item(self, items: list[_T], index: object, what: str) -> _T:
        """``items[index]``, refusing an index the file has no entry for (negative ones included)."""
        if not isinstance(index, int) or not 0 <= index < len(items):
            plural = what + ("es" if what.endswith("sh") else "s")
            raise self.fail(f"refers to {what} {index!r}, but it has {len(items)} {plural}")
        return items[index]

    def _uri_bytes(self, uri: str) -> bytes:
        # pygltflib's decode_data_uri knows only application/octet-stream; images are data:image/...
        if uri.startswith("data:"):
            return base64.b64decode(uri.split(",", 1)[1])
        target = self.path.parent / uri
        if not target.is_file():
            raise self.fail(f"refers to {uri!r}, which is not beside it")
        return target.read_bytes()

    def _buffer(self, index: int, buffer: pygltflib.Buffer) -> bytes:
        data = self._uri_bytes(buffer.uri) if buffer.uri is not None else (self.gltf.binary_blob() or b"")
        if len(data) < int(buffer.byteLength or 0):
            raise self.fail(f"buffer {index} holds {len(data)} bytes, its byteLength says {buffer.byteLength}")
        return data

    def view_bytes(self, index: int) -> memoryview:
        view = self.item(self.gltf.bufferViews, index, "buffer view")
        start = int(view.byteOffset or 0)
        return memoryview(self.item(self.buffers, view.buffer, "buffer"))[start: start + int(view.byteLength)]

    def accessor(self, index: int) -> np.ndarray:
        """(count, components) array of accessor ``index`` (normalized integers scaled to [0, 1])."""
        acc = self.item(self.gltf.accessors, index, "accessor")
        if acc.sparse is not None:
            raise self.fail(f"accessor {index} is sparse; sparse accessors are not read")
        if acc.componentType not in COMPONENT_DTYPES or acc.type not in TYPE_SIZES:
            raise self.fail(f"accessor {index} has component type {acc.componentType!r}, type {acc.type!r}; "
                            f"glTF's are {sorted(COMPONENT_DTYPES)}, {list(TYPE_SIZES)}")
        dtype = np.dtype(COMPONENT_DTYPES[acc.componentType]).newbyteorder("<")
        width, count = TYPE_SIZES[acc.type], int(acc.count)
        if acc.bufferView is None:
            return np.zeros((count, width), dtype)
        raw = self.view_bytes(acc.bufferView)
        stride = int(self.gltf.bufferViews[acc.bufferView].byteStride or 0) or width * dtype.itemsize
        offset = int(acc.byteOffset or 0)
        if count and offset + (count - 1) * stride + width * dtype.itemsize > len(raw):
            raise self.fail(f"accessor {index} runs past its buffer view (corrupt file)")
        arr = np.ndarray((count, width), dtype, buffer=raw, offset=offset, strides=(stride, dtype.itemsize))
        if acc.normalized and dtype.kind in "ui":
            return np.maximum(arr.astype(np.float32) / np.float32(np.iinfo(dtype).max), -1.0)
        return np.array(arr)

    def image(self, index: int) -> tuple[bytes, str]:
        spec = self.item(self.gltf.images, index, "image")
        if spec.bufferView is not None:
            return bytes(self.view_bytes(spec.bufferView)), str(spec.mimeType or "")
        uri = str(spec.uri or "")
        mime = uri[5:].split(";", 1)[0] if uri.startswith("data:") else str(spec.mimeType or "")
        return self._uri_bytes(uri), mime

    def texture(self, index: int) -> GlbTexture:
        spec = self.item(self.gltf.textures, index, "texture")
        ext = spec.extensions or {}
        basis_ext = next((ext[name] for name in BASIS_EXTENSIONS if name in ext), None)
        source = basis_ext.get("source") if basis_ext is not None else spec.source
        if source is None:
            source = spec.source
        if source is None:
            raise self.fail(f"texture {index} has no image source")
        data, mime = self.image(int(source))
        basis = basis_ext is not None or mime in BASIS_MIME_TYPES or data.startswith(_BASIS_MAGICS)
        wrap = (REPEAT, REPEAT)
        if spec.sampler is not None:
            sampler = self.item(self.gltf.samplers, spec.sampler, "sampler")
            wrap = (int(sampler.wrapS), int(sampler.wrapT))
        if not set(wrap) <= set(WRAP_MODES):
            raise self.fail(f"texture {index} has wrap modes {wrap}; glTF's are {WRAP_MODES}")
        return GlbTexture(image=data, mime=mime, basis=basis, wrap=wrap)

    def mesh_instances(self) -> list[tuple[int, np.ndarray]]:
        """(mesh index, (4, 4) world transform) of every mesh the default scene draws."""
        gltf = self.gltf
        if not gltf.scenes:   # no scene: every mesh once, untransformed
            return [(i, np.eye(4)) for i in range(len(gltf.meshes))]
        scene = self.item(gltf.scenes, 0 if gltf.scene is None else gltf.scene, "scene")
        out: list[tuple[int, np.ndarray]] = []
        stack = [(n, np.eye(4)) for n in scene.nodes or []]
        seen = 0
        while stack:
            index, parent = stack.pop()
            seen += 1
            if seen > 10 * max(len(gltf.nodes), 1):
                raise self.fail("the node tree has a cycle")
            node = self.item(gltf.nodes, index, "node")
            world = parent @ _node_matrix(node)
            if node.mesh is not None:
                out.append((node.mesh, world))
            stack.extend((c, world) for c in node.children or [])
        return out


def _node_matrix(node: pygltflib.Node) -> np.ndarray:
    """(4, 4) local transform of a glTF node (column-major ``matrix``, or T * R * S)."""
    if node.matrix is not None:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T
    x, y, z, w = node.rotation if node.rotation is not None else (0.0, 0.0, 0.0, 1.0)
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    out = np.eye(4)
    scale = node.scale if node.scale is not None else (1.0, 1.0, 1.0)
    out[:3, :3] = rot * np.asarray(scale, dtype=np.float64)[None, :]
    out[:3, 3] = node.translation if node.translation is not None else (0.0, 0.0, 0.0)
    return out


def read_glb(path: str | Path) -> GlbMesh:
    """The triangle mesh of the GLB ``path`` (see ``GlbMesh``). SceneError for a missing,
    truncated or malformed file, a non-triangle primitive, or a file without triangles."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"GLB file not found: {path}")
    gltf = _load(path, path.read_bytes())
    try:
        return _flatten(_Reader(path, gltf))
    except SceneError as exc:
        msg = str(exc)
        raise SceneError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
    except _PARSE_ERRORS as exc:
        raise SceneError(f"corrupt GLB {path}: {type(exc).__name__}: {exc}") from None


def _material(spec: pygltflib.Material) -> GlbMaterial:
    """The base colour factor and texture of a material (glTF's defaults where it has none)."""
    pbr = spec.pbrMetallicRoughness or pygltflib.PbrMetallicRoughness()
    tex = pbr.baseColorTexture
    if tex is None:
        return GlbMaterial(base_color=np.asarray(pbr.baseColorFactor, dtype=np.float32))
    return GlbMaterial(base_color=np.asarray(pbr.baseColorFactor, dtype=np.float32), texture=tex.index,
                       tex_coord=int(tex.texCoord or 0))


def _flatten(reader: _Reader) -> GlbMesh:
    gltf = reader.gltf
    materials = [_material(m) for m in gltf.materials]
    used = sorted({m.texture for m in materials if m.texture is not None})
    textures = [reader.texture(int(t)) for t in used]
    for m in materials:   # material texture indices now point into the decoded list
        m.texture = None if m.texture is None else used.index(m.texture)
    pos, tris, uvs, cols, has_col, mats = [], [], [], [], [], []
    n_verts = 0
    for mesh_index, world in reader.mesh_instances():
        for p_index, prim in enumerate(reader.item(gltf.meshes, mesh_index, "mesh").primitives):
            mode = TRIANGLES if prim.mode is None else int(prim.mode)
            if mode != TRIANGLES:
                raise SceneError(f"mesh {mesh_index} primitive {p_index} has mode {mode}; only triangle lists "
                                 f"(mode {TRIANGLES}) are read")
            attrs = prim.attributes
            if getattr(attrs, "POSITION", None) is None:
                raise SceneError(f"mesh {mesh_index} primitive {p_index} has no POSITION accessor")
            xyz = reader.accessor(attrs.POSITION).astype(np.float64)
            xyz = xyz @ world[:3, :3].T + world[:3, 3]
            idx = (reader.accessor(prim.indices).ravel().astype(np.int64) if prim.indices is not None
                   else np.arange(len(xyz), dtype=np.int64))
            if len(idx) % 3:
                raise SceneError(f"mesh {mesh_index} primitive {p_index} has {len(idx)} indices, not a multiple of 3")
            if len(idx) and (idx.min() < 0 or idx.max() >= len(xyz)):
                raise SceneError(f"mesh {mesh_index} primitive {p_index}: vertex indices out of range [0, {len(xyz)})")
            face = idx.reshape(-1, 3)
            material = -1 if prim.material is None else prim.material
            tex_set = reader.item(materials, material, "material").tex_coord if material != -1 else 0
            uv_accessor = getattr(attrs, f"TEXCOORD_{tex_set}", None)
            uvs.append(reader.accessor(uv_accessor).astype(np.float32)[face] if uv_accessor is not None else None)
            if attrs.COLOR_0 is not None:
                c = reader.accessor(attrs.COLOR_0).astype(np.float32)
                cols.append(np.hstack([c, np.ones((len(c), 1), np.float32)]) if c.shape[1] == 3 else c)
            else:
                cols.append(None)
            has_col.append(np.full(len(face), attrs.COLOR_0 is not None))
            pos.append(xyz)
            tris.append(face + n_verts)
            mats.append(np.full(len(face), material, np.int32))
            n_verts += len(xyz)
    if not tris or sum(len(t) for t in tris) == 0:
        raise SceneError("the GLB holds no triangles")
    tri_uv = None
    if any(u is not None for u in uvs):
        tri_uv = np.concatenate([u if u is not None else np.zeros((len(t), 3, 2), np.float32)
                                 for u, t in zip(uvs, tris)])
    vertex_color = None
    if any(c is not None for c in cols):
        vertex_color = np.concatenate([c if c is not None else np.zeros((len(p), 4), np.float32)
                                       for c, p in zip(cols, pos)])
    return GlbMesh(path=reader.path, positions=np.concatenate(pos), triangles=np.concatenate(tris), tri_uv=tri_uv,
                   vertex_color=vertex_color, has_vertex_color=np.concatenate(has_col),
                   tri_material=np.concatenate(mats), materials=materials, textures=textures)


def decode_image(texture: GlbTexture) -> np.ndarray | None:
    """(h, w, 3) uint8 RGB of a JPEG / PNG texture; None for Basis Universal / KTX2 data or bytes
    no decoder here reads."""
    import cv2

    if texture.basis:
        return None
    img = cv2.imdecode(np.frombuffer(texture.image, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None
    if img.dtype == np.uint16:   # 16-bit PNG: keep the high byte
        img = (img >> 8).astype(np.uint8)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    img = img[:, :, :3] if img.shape[2] >= 3 else np.repeat(img[:, :, :1], 3, axis=2)
    return np.ascontiguousarray(img[:, :, ::-1])   # OpenCV's BGR -> RGB


def wrap_texels(coord: np.ndarray, size, mode) -> np.ndarray:
    """int64 texel indices along one image axis of texture coordinates ``coord`` (any shape; 0..1
    spans the image, glTF's nearest texel: floor(coord x size)) under the glTF wrap ``mode``
    (REPEAT, CLAMP_TO_EDGE or MIRRORED_REPEAT). ``size`` and ``mode`` are scalars or arrays
    broadcasting with ``coord`` (one texture per element); a scalar mode computes only its rule."""
    size = np.asarray(size, dtype=np.int64)
    x = np.floor(np.asarray(coord) * size).astype(np.int64)
    modes = np.unique(mode)
    if len(modes) == 1:
        return _wrap(x, size, int(modes[0]))
    mode = np.asarray(mode)
    return np.where(mode == REPEAT, _wrap(x, size, REPEAT),
                    np.where(mode == CLAMP_TO_EDGE, _wrap(x, size, CLAMP_TO_EDGE), _wrap(x, size, MIRRORED_REPEAT)))


def _wrap(x: np.ndarray, size: np.ndarray, mode: int) -> np.ndarray:
    if mode == REPEAT:
        return np.mod(x, size)
    if mode == CLAMP_TO_EDGE:
        return np.clip(x, 0, size - 1)
    m = np.mod(x, 2 * size)
    return np.where(m >= size, 2 * size - 1 - m, m)
