"""The Scene type: a labelled triangle mesh, the simulator's single source of truth.

Conventions (used everywhere in calnav):
- World frame is z-up, metres; procedural houses have their floor at z = 0.
- Every triangle carries a class id (``envs.semantics``; ``VOID`` = -1 for unlabelled), an
  instance id (-1 = none), an albedo (RGB uint8) and a procedural texture id (``Texture``).
- Scenes read from textured meshes (``envs.scene_files``) also carry per-triangle texture
  coordinates and an image texture per triangle (``tri_uv``, ``tri_material`` into ``textures``,
  -1 = untextured); the renderer then colours a hit from its texel instead of the procedural
  pattern. Scenes without them are unchanged.
- A scene whose source has no semantic annotation says why in ``meta["semantics_unavailable"]``
  (it may then be all void); one whose colours cannot be decoded says why in
  ``meta["rgb_unavailable"]``.
- Scenes save to a single compressed ``.npz`` (arrays + a JSON metadata string) and load back
  bit-identically; the texture arrays are optional entries, absent for untextured scenes.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path

import numpy as np

from calnav.common.npz import load_versioned_npz, save_versioned_npz
from calnav.envs.semantics import CLASS_NAMES, VOID

FORMAT_VERSION = 1
SEMANTICS_UNAVAILABLE = "semantics_unavailable"   # meta key: why a scene has no labels (may be all void)
RGB_UNAVAILABLE = "rgb_unavailable"               # meta key: why a scene's colours are not the source's
WRAP_REPEAT, WRAP_CLAMP, WRAP_MIRROR = 10497, 33071, 33648   # glTF sampler wrap codes (texture_wrap)
_REQUIRED = ("vertices", "triangles", "tri_class", "tri_instance", "tri_albedo", "tri_texture")


class Texture(IntEnum):
    """Procedural surface patterns the renderer modulates albedo with."""

    PLAIN = 0
    STRIPES = 1   # e.g. wallpaper, upholstery
    CHECKER = 2   # e.g. tiles
    GRAIN = 3     # e.g. wood
    SPECKLE = 4   # e.g. carpet, stone
    FABRIC = 5    # fine cross-hatch, e.g. bedding


@dataclass(frozen=True)
class Room:
    """An axis-aligned room of a procedural house: kind and floor bounds in metres."""

    kind: str
    xmin: float
    ymin: float
    xmax: float
    ymax: float

    @property
    def area(self) -> float:
        return (self.xmax - self.xmin) * (self.ymax - self.ymin)

    def contains(self, x: float, y: float) -> bool:
        return self.xmin <= x <= self.xmax and self.ymin <= y <= self.ymax


class SceneError(ValueError):
    """A scene file or mesh is unusable (corrupt, unlabelled, no floor, ...)."""


@dataclass
class Scene:
    """A labelled triangle mesh.

    vertices: (V, 3) float32 metres, world z-up.
    triangles: (F, 3) int32 vertex indices.
    tri_class: (F,) int16 class id into ``class_names`` (-1 = void).
    tri_instance: (F,) int32 instance id (-1 = none); an instance has one class.
    tri_albedo: (F, 3) uint8 base colour.
    tri_texture: (F,) uint8 ``Texture`` id.
    tri_uv: (F, 3, 2) float32 texture coordinates of each triangle's corners (glTF's: (0, 0) the
      image's top-left corner, v down), or None for an untextured scene.
    tri_material: (F,) int16 index into ``textures`` (-1 = untextured), or None.
    textures: list of (h, w, 3) uint8 RGB images.
    texture_wrap: (T, 2) int32 glTF wrap codes (wrapS, wrapT) per texture (``WRAP_*``).
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    tri_class: np.ndarray
    tri_instance: np.ndarray
    tri_albedo: np.ndarray
    tri_texture: np.ndarray
    class_names: tuple[str, ...] = CLASS_NAMES
    rooms: list[Room] = field(default_factory=list)
    floor_z: float = 0.0
    meta: dict = field(default_factory=dict)
    tri_uv: np.ndarray | None = None
    tri_material: np.ndarray | None = None
    textures: list[np.ndarray] = field(default_factory=list)
    texture_wrap: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int32)
        self.tri_class = np.ascontiguousarray(self.tri_class, dtype=np.int16)
        self.tri_instance = np.ascontiguousarray(self.tri_instance, dtype=np.int32)
        self.tri_albedo = np.ascontiguousarray(self.tri_albedo, dtype=np.uint8)
        self.tri_texture = np.ascontiguousarray(self.tri_texture, dtype=np.uint8)
        self.class_names = tuple(self.class_names)
        if self.tri_uv is not None:
            self.tri_uv = np.ascontiguousarray(self.tri_uv, dtype=np.float32)
        if self.tri_material is not None:
            self.tri_material = np.ascontiguousarray(self.tri_material, dtype=np.int16)
        self.textures = [np.ascontiguousarray(t, dtype=np.uint8) for t in self.textures]
        if self.texture_wrap is None:
            self.texture_wrap = np.full((len(self.textures), 2), WRAP_REPEAT, dtype=np.int32)
        self.texture_wrap = np.ascontiguousarray(self.texture_wrap, dtype=np.int32).reshape(-1, 2)
        self.validate()

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        f = len(self.triangles)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3 or len(self.vertices) == 0:
            raise SceneError(f"scene {self.name!r}: vertices must be (V, 3), got {self.vertices.shape}")
        if self.triangles.ndim != 2 or self.triangles.shape[1] != 3 or f == 0:
            raise SceneError(f"scene {self.name!r}: triangles must be (F, 3), got {self.triangles.shape}")
        if self.triangles.min() < 0 or self.triangles.max() >= len(self.vertices):
            raise SceneError(f"scene {self.name!r}: triangle indices out of range [0, {len(self.vertices)})")
        for name, arr, shape in (
            ("tri_class", self.tri_class, (f,)),
            ("tri_instance", self.tri_instance, (f,)),
            ("tri_albedo", self.tri_albedo, (f, 3)),
            ("tri_texture", self.tri_texture, (f,)),
        ):
            if arr.shape != shape:
                raise SceneError(f"scene {self.name!r}: {name} must have shape {shape}, got {arr.shape}")
        if not np.isfinite(self.vertices).all():
            raise SceneError(f"scene {self.name!r}: vertices contain NaN or inf")
        k = len(self.class_names)
        bad = (self.tri_class < VOID) | (self.tri_class >= k)
        if bad.any():
            raise SceneError(f"scene {self.name!r}: class ids must be in [-1, {k}), got {self.tri_class[bad][:5]}")
        # only a scene that says its source has no annotation may be unlabelled (a geometry /
        # RGB-only scene a `gt` run refuses by that reason); any other all-void mesh is a mistake
        if (self.tri_class == VOID).all() and not self.meta.get(SEMANTICS_UNAVAILABLE):
            raise SceneError(f"scene {self.name!r}: the mesh carries no semantic labels (every face is void)")
        self._validate_textures()

    def _validate_textures(self) -> None:
        f, n_tex = len(self.triangles), len(self.textures)
        if (self.tri_uv is None) != (self.tri_material is None):
            raise SceneError(f"scene {self.name!r}: tri_uv and tri_material come together (one is missing)")
        if self.tri_uv is None:
            if n_tex:
                raise SceneError(f"scene {self.name!r}: {n_tex} textures but no tri_uv / tri_material")
            return
        if self.tri_uv.shape != (f, 3, 2) or self.tri_material.shape != (f,):
            raise SceneError(f"scene {self.name!r}: tri_uv must be ({f}, 3, 2) and tri_material ({f},), got "
                             f"{self.tri_uv.shape} and {self.tri_material.shape}")
        if not np.isfinite(self.tri_uv).all():
            raise SceneError(f"scene {self.name!r}: tri_uv contains NaN or inf")
        bad = (self.tri_material < -1) | (self.tri_material >= n_tex)
        if bad.any():
            raise SceneError(f"scene {self.name!r}: tri_material must be in [-1, {n_tex}), got {self.tri_material[bad][:5]}")
        for k, tex in enumerate(self.textures):
            if tex.ndim != 3 or tex.shape[2] != 3 or tex.shape[0] < 1 or tex.shape[1] < 1:
                raise SceneError(f"scene {self.name!r}: texture {k} must be (h, w, 3) uint8, got {tex.shape}")
        if self.texture_wrap.shape != (n_tex, 2) or not np.isin(self.texture_wrap, (WRAP_REPEAT, WRAP_CLAMP,
                                                                                      WRAP_MIRROR)).all():
            raise SceneError(f"scene {self.name!r}: texture_wrap must be ({n_tex}, 2) glTF wrap codes "
                             f"({WRAP_REPEAT}, {WRAP_CLAMP}, {WRAP_MIRROR})")

    @property
    def textured(self) -> bool:
        """Whether any triangle takes its colour from an image texture."""
        return self.tri_material is not None and bool((self.tri_material >= 0).any())

    # ------------------------------------------------------------- accessors
    @property
    def num_classes(self) -> int:
        return len(self.class_names)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min xyz, max xyz) of the mesh, metres."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def instance_ids(self, class_id: int | None = None) -> np.ndarray:
        """Sorted instance ids, optionally only those of class ``class_id``."""
        mask = self.tri_instance >= 0
        if class_id is not None:
            mask &= self.tri_class == class_id
        return np.unique(self.tri_instance[mask])

    def instance_class(self, instance_id: int) -> int:
        classes = np.unique(self.tri_class[self.tri_instance == instance_id])
        if len(classes) != 1:
            raise SceneError(f"instance {instance_id} has classes {classes.tolist()}, expected exactly one")
        return int(classes[0])

    def instance_triangles(self, instance_id: int) -> np.ndarray:
        """(n, 3, 3) float32 vertex positions of the instance's triangles."""
        tris = self.triangles[self.tri_instance == instance_id]
        return self.vertices[tris]

    def classes_present(self) -> set[int]:
        return set(int(c) for c in np.unique(self.tri_class) if c != VOID)

    # -------------------------------------------------------------- file io
    def save(self, path: str | os.PathLike) -> Path:
        meta = {
            "name": self.name,
            "class_names": list(self.class_names),
            "rooms": [r.__dict__ for r in self.rooms],
            "floor_z": self.floor_z,
            "meta": self.meta,
        }
        arrays = {
            "vertices": self.vertices, "triangles": self.triangles, "tri_class": self.tri_class,
            "tri_instance": self.tri_instance, "tri_albedo": self.tri_albedo, "tri_texture": self.tri_texture,
        }
        if self.tri_uv is not None:   # optional entries: untextured scenes write exactly the arrays above
            arrays.update(tri_uv=self.tri_uv, tri_material=self.tri_material, texture_wrap=self.texture_wrap)
            arrays.update({f"texture_{k}": tex for k, tex in enumerate(self.textures)})
        # atomic: a crash never leaves a half-written cache entry
        return save_versioned_npz(path, arrays, meta, FORMAT_VERSION)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Scene":
        path = Path(path)
        arrays, meta = load_versioned_npz(path, FORMAT_VERSION, what="scene file", error=SceneError)
        missing = set(_REQUIRED) - set(arrays)
        if missing:
            raise SceneError(f"corrupt scene file {path}: missing arrays {sorted(missing)}")
        n_tex = sum(1 for k in arrays if k.startswith("texture_") and k[8:].isdigit())
        textures = [arrays.pop(f"texture_{k}") for k in range(n_tex) if f"texture_{k}" in arrays]
        if len(textures) != n_tex:
            raise SceneError(f"corrupt scene file {path}: texture arrays are not numbered 0..{n_tex - 1}")
        return cls(
            name=meta["name"], class_names=tuple(meta["class_names"]),
            rooms=[Room(**r) for r in meta["rooms"]], floor_z=float(meta["floor_z"]),
            meta=meta.get("meta", {}), textures=textures, **arrays,
        )


def sample_surface(tri_verts: np.ndarray, spacing: float, rng: np.random.Generator,
                   return_index: bool = False):
    """Uniform random points on triangles (n, 3, 3) at about one per ``spacing``^2 of area
    (at least one per triangle) -> (m, 3) float64, and with ``return_index`` also the (m,)
    index of each point's triangle."""
    tri_verts = np.asarray(tri_verts, dtype=np.float64)
    a, b, c = tri_verts[:, 0], tri_verts[:, 1], tri_verts[:, 2]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    counts = np.maximum(1, np.ceil(area / spacing**2)).astype(np.int64)
    idx = np.repeat(np.arange(len(tri_verts)), counts)
    u, v = rng.random((2, len(idx)))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    points = a[idx] + u[:, None] * (b - a)[idx] + v[:, None] * (c - a)[idx]
    return (points, idx) if return_index else points


def cache_dir() -> Path:
    """Root of calnav's on-disk cache: ``$CALNAV_CACHE`` or ``~/.cache/calnav``."""
    root = os.environ.get("CALNAV_CACHE")
    return Path(root) if root else Path.home() / ".cache" / "calnav"


def check_cache_dir() -> Path:
    """The cache root, created if missing; ValueError in one line when it is a file or cannot
    be written (``$CALNAV_CACHE`` set to the wrong place), before any command writes."""
    root = cache_dir()
    where = "CALNAV_CACHE" if os.environ.get("CALNAV_CACHE") else "the default cache"
    if root.exists() and not root.is_dir():
        raise ValueError(f"{where} {root} is a file, not a directory; point CALNAV_CACHE at a writable directory")
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"cannot create {where} {root} ({exc.strerror or exc}); point CALNAV_CACHE at a "
                         "writable directory") from None
    if not os.access(root, os.W_OK | os.X_OK):
        raise ValueError(f"{where} {root} is not writable; point CALNAV_CACHE at a writable directory")
    return root
