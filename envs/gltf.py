"""glTF 2.0 binary files (``.glb``): the container, and its triangle meshes flattened into one mesh.

``read_glb(path)`` parses the JSON and binary chunks (buffers, buffer views and accessors read as
numpy views: no Python loop per vertex or face), walks the default scene's node tree applying each
node's matrix or translation / rotation / scale, and concatenates every triangle primitive into a
``GlbMesh``: positions in the file's own axes (the scene's frame is the caller's business), faces,
per-face texture coordinates, ``COLOR_0`` vertex colours, per-face material and the materials'
base colour textures (their images still encoded: ``decode_image`` turns a JPEG / PNG into RGB;
Basis Universal / KTX2 images are flagged ``basis`` and cannot be decoded here).

``pack_glb(document, binary)`` is the inverse container step (writers build the JSON themselves).
Every unreadable input is a one-line ``SceneError`` naming the file.
"""
from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calnav.envs.scene import SceneError

GLB_MAGIC = b"glTF"
CHUNK_JSON, CHUNK_BIN = 0x4E4F534A, 0x004E4942
COMPONENT_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
TRIANGLES = 4                                   # primitive mode: a triangle list (glTF's default)
REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT = 10497, 33071, 33648   # sampler wrap modes
WRAP_MODES = (REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT)
BASIS_EXTENSIONS = ("KHR_texture_basisu", "GOOGLE_texture_basis")
BASIS_MIME_TYPES = ("image/ktx2", "image/x-basis", "image/basis")
_BASIS_MAGICS = (b"\xabKTX 20\xbb", b"sB")      # KTX2 container, .basis file


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


def pack_glb(document: dict, binary: bytes) -> bytes:
    """The GLB file holding the JSON ``document`` and the binary chunk ``binary`` (buffer 0)."""
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary = binary + b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(text) + (8 + len(binary) if binary else 0)
    out = struct.pack("<4sII", GLB_MAGIC, 2, total) + struct.pack("<II", len(text), CHUNK_JSON) + text
    return out + (struct.pack("<II", len(binary), CHUNK_BIN) + binary if binary else b"")


def _chunks(path: Path, data: bytes) -> tuple[dict, bytes]:
    """(JSON document, binary chunk) of the GLB bytes ``data``."""
    if len(data) < 20 or data[:4] != GLB_MAGIC:
        raise SceneError(f"{path}: not a binary glTF file (no 'glTF' magic); a .glb is needed")
    version, total = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise SceneError(f"{path}: glTF version {version}; only glTF 2.0 is read")
    if total > len(data):
        raise SceneError(f"corrupt GLB {path}: the header says {total} bytes, the file has {len(data)} (truncated?)")
    document, binary, offset = None, b"", 12
    while offset + 8 <= total:
        length, kind = struct.unpack_from("<II", data, offset)
        body = data[offset + 8: offset + 8 + length]
        if len(body) != length:
            raise SceneError(f"corrupt GLB {path}: a chunk runs past the end of the file (truncated?)")
        if kind == CHUNK_JSON:
            try:
                document = json.loads(body.decode("utf-8"))
            except (UnicodeDecodeError, ValueError) as exc:
                raise SceneError(f"corrupt GLB {path}: its JSON chunk does not parse ({exc})") from None
        elif kind == CHUNK_BIN and not binary:
            binary = body
        offset += 8 + length
    if not isinstance(document, dict):
        raise SceneError(f"corrupt GLB {path}: no JSON chunk")
    return document, binary


class _Reader:
    """Buffers, accessors and images of one parsed GLB."""

    def __init__(self, path: Path, document: dict, binary: bytes):
        self.path, self.doc = path, document
        self.buffers = [self._buffer(i, b, binary) for i, b in enumerate(document.get("buffers", []))]

    def fail(self, problem: str) -> SceneError:
        return SceneError(f"{self.path}: {problem}")

    def _uri_bytes(self, uri: str) -> bytes:
        if uri.startswith("data:"):
            return base64.b64decode(uri.split(",", 1)[1])
        target = self.path.parent / uri
        if not target.is_file():
            raise self.fail(f"refers to {uri!r}, which is not beside it")
        return target.read_bytes()

    def _buffer(self, index: int, spec: dict, binary: bytes) -> bytes:
        data = self._uri_bytes(spec["uri"]) if "uri" in spec else binary
        if len(data) < int(spec.get("byteLength", 0)):
            raise self.fail(f"buffer {index} holds {len(data)} bytes, its byteLength says {spec.get('byteLength')}")
        return data

    def view_bytes(self, index: int) -> memoryview:
        view = self.doc["bufferViews"][index]
        start = int(view.get("byteOffset", 0))
        return memoryview(self.buffers[view["buffer"]])[start: start + int(view["byteLength"])]

    def accessor(self, index: int) -> np.ndarray:
        """(count, components) array of accessor ``index`` (normalized integers scaled to [0, 1])."""
        acc = self.doc["accessors"][index]
        if "sparse" in acc:
            raise self.fail(f"accessor {index} is sparse; sparse accessors are not read")
        dtype = np.dtype(COMPONENT_DTYPES[acc["componentType"]]).newbyteorder("<")
        width, count = TYPE_SIZES[acc["type"]], int(acc["count"])
        if "bufferView" not in acc:
            return np.zeros((count, width), dtype)
        view = self.doc["bufferViews"][acc["bufferView"]]
        raw = self.view_bytes(acc["bufferView"])
        stride = int(view.get("byteStride", 0)) or width * dtype.itemsize
        offset = int(acc.get("byteOffset", 0))
        if count and offset + (count - 1) * stride + width * dtype.itemsize > len(raw):
            raise self.fail(f"accessor {index} runs past its buffer view (corrupt file)")
        arr = np.ndarray((count, width), dtype, buffer=raw, offset=offset, strides=(stride, dtype.itemsize))
        if acc.get("normalized") and dtype.kind in "ui":
            return np.maximum(arr.astype(np.float32) / np.float32(np.iinfo(dtype).max), -1.0)
        return np.array(arr)

    def image(self, index: int) -> tuple[bytes, str]:
        spec = self.doc["images"][index]
        if "bufferView" in spec:
            return bytes(self.view_bytes(spec["bufferView"])), str(spec.get("mimeType", ""))
        uri = str(spec.get("uri", ""))
        mime = uri[5:].split(";", 1)[0] if uri.startswith("data:") else str(spec.get("mimeType", ""))
        return self._uri_bytes(uri), mime

    def texture(self, index: int) -> GlbTexture:
        spec = self.doc["textures"][index]
        ext = spec.get("extensions", {})
        basis_ext = next((ext[name] for name in BASIS_EXTENSIONS if name in ext), None)
        source = basis_ext.get("source") if basis_ext is not None else spec.get("source")
        if source is None:
            source = spec.get("source")
        if source is None:
            raise self.fail(f"texture {index} has no image source")
        data, mime = self.image(int(source))
        basis = basis_ext is not None or mime in BASIS_MIME_TYPES or data.startswith(_BASIS_MAGICS)
        sampler = self.doc.get("samplers", [])[spec["sampler"]] if "sampler" in spec else {}
        wrap = (int(sampler.get("wrapS", REPEAT)), int(sampler.get("wrapT", REPEAT)))
        if not set(wrap) <= set(WRAP_MODES):
            raise self.fail(f"texture {index} has wrap modes {wrap}; glTF's are {WRAP_MODES}")
        return GlbTexture(image=data, mime=mime, basis=basis, wrap=wrap)


def _node_matrix(node: dict) -> np.ndarray:
    """(4, 4) local transform of a glTF node (column-major ``matrix``, or T * R * S)."""
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = node.get("rotation", (0.0, 0.0, 0.0, 1.0))
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    out = np.eye(4)
    out[:3, :3] = rot * np.asarray(node.get("scale", (1.0, 1.0, 1.0)), dtype=np.float64)[None, :]
    out[:3, 3] = node.get("translation", (0.0, 0.0, 0.0))
    return out


def _mesh_instances(doc: dict) -> list[tuple[int, np.ndarray]]:
    """(mesh index, (4, 4) world transform) of every mesh the default scene draws."""
    nodes = doc.get("nodes", [])
    scenes = doc.get("scenes", [])
    if not scenes:   # no scene: every mesh once, untransformed
        return [(i, np.eye(4)) for i in range(len(doc.get("meshes", [])))]
    out: list[tuple[int, np.ndarray]] = []
    stack = [(int(n), np.eye(4)) for n in scenes[int(doc.get("scene", 0))].get("nodes", [])]
    seen = 0
    while stack:
        index, parent = stack.pop()
        seen += 1
        if seen > 10 * max(len(nodes), 1):
            raise SceneError("the node tree has a cycle")
        world = parent @ _node_matrix(nodes[index])
        if "mesh" in nodes[index]:
            out.append((int(nodes[index]["mesh"]), world))
        stack.extend((int(c), world) for c in nodes[index].get("children", []))
    return out


def read_glb(path: str | Path) -> GlbMesh:
    """The triangle mesh of the GLB ``path`` (see ``GlbMesh``). SceneError for a missing,
    truncated or malformed file, a non-triangle primitive, or a file without triangles."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"GLB file not found: {path}")
    document, binary = _chunks(path, path.read_bytes())
    reader = _Reader(path, document, binary)
    try:
        return _flatten(reader)
    except SceneError as exc:
        msg = str(exc)
        raise SceneError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise SceneError(f"corrupt GLB {path}: {type(exc).__name__}: {exc}") from None


def _flatten(reader: _Reader) -> GlbMesh:
    doc = reader.doc
    materials = [GlbMaterial(base_color=np.asarray(m.get("pbrMetallicRoughness", {}).get("baseColorFactor", (1, 1, 1, 1)),
                                                   dtype=np.float32),
                             texture=m.get("pbrMetallicRoughness", {}).get("baseColorTexture", {}).get("index"),
                             tex_coord=int(m.get("pbrMetallicRoughness", {}).get("baseColorTexture", {}).get("texCoord", 0)))
                 for m in doc.get("materials", [])]
    used = sorted({m.texture for m in materials if m.texture is not None})
    textures = [reader.texture(int(t)) for t in used]
    for m in materials:   # material texture indices now point into the decoded list
        m.texture = None if m.texture is None else used.index(m.texture)
    pos, tris, uvs, cols, has_col, mats = [], [], [], [], [], []
    n_verts = 0
    for mesh_index, world in _mesh_instances(doc):
        for p_index, prim in enumerate(doc["meshes"][mesh_index]["primitives"]):
            mode = int(prim.get("mode", TRIANGLES))
            if mode != TRIANGLES:
                raise SceneError(f"mesh {mesh_index} primitive {p_index} has mode {mode}; only triangle lists "
                                 f"(mode {TRIANGLES}) are read")
            attrs = prim["attributes"]
            xyz = reader.accessor(attrs["POSITION"]).astype(np.float64)
            xyz = xyz @ world[:3, :3].T + world[:3, 3]
            idx = (reader.accessor(prim["indices"]).ravel().astype(np.int64) if "indices" in prim
                   else np.arange(len(xyz), dtype=np.int64))
            if len(idx) % 3:
                raise SceneError(f"mesh {mesh_index} primitive {p_index} has {len(idx)} indices, not a multiple of 3")
            if len(idx) and (idx.min() < 0 or idx.max() >= len(xyz)):
                raise SceneError(f"mesh {mesh_index} primitive {p_index}: vertex indices out of range [0, {len(xyz)})")
            face = idx.reshape(-1, 3)
            material = int(prim.get("material", -1))
            tex_set = materials[material].tex_coord if material >= 0 else 0
            uv_key = f"TEXCOORD_{tex_set}"
            uvs.append(reader.accessor(attrs[uv_key]).astype(np.float32)[face] if uv_key in attrs else None)
            if "COLOR_0" in attrs:
                c = reader.accessor(attrs["COLOR_0"]).astype(np.float32)
                cols.append(np.hstack([c, np.ones((len(c), 1), np.float32)]) if c.shape[1] == 3 else c)
            else:
                cols.append(None)
            has_col.append(np.full(len(face), "COLOR_0" in attrs))
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
