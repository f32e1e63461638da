"""Mesh primitives for building scenes: boxes and cylinders with a class, an instance, an
albedo and a texture per part. ``MeshBuilder`` accumulates parts into one ``Scene``.

All sizes are metres; ``yaw`` is a rotation about +z in radians around the part's centre.
"""
from __future__ import annotations

import numpy as np

from calnav.envs.scene import Room, Scene, Texture
from calnav.envs.semantics import CLASS_NAMES, VOID

# Unit cube corners and its 12 outward-facing triangles (counter-clockwise seen from outside).
_CUBE_CORNERS = np.array(
    [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
    dtype=np.float64,
) - 0.5
_CUBE_FACES = np.array(
    [
        [0, 2, 1], [0, 3, 2],  # bottom (-z)
        [4, 5, 6], [4, 6, 7],  # top (+z)
        [0, 1, 5], [0, 5, 4],  # -y
        [2, 3, 7], [2, 7, 6],  # +y
        [1, 2, 6], [1, 6, 5],  # +x
        [3, 0, 4], [3, 4, 7],  # -x
    ],
    dtype=np.int32,
)


def _rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def box_mesh(center, size, yaw: float = 0.0, faces: str = "all") -> tuple[np.ndarray, np.ndarray]:
    """Vertices (8, 3) and triangles of a box.

    center: (3,) metres; size: (3,) full extents in metres; faces: "all", or a subset of
    "-z +z -y +y +x -x" separated by spaces (e.g. floors need only "+z").
    """
    verts = _CUBE_CORNERS * np.asarray(size, dtype=np.float64)
    verts = verts @ _rot_z(yaw).T + np.asarray(center, dtype=np.float64)
    tris = _CUBE_FACES
    if faces != "all":
        order = ["-z", "+z", "-y", "+y", "+x", "-x"]
        keep = [i for i, name in enumerate(order) if name in faces.split()]
        if not keep:
            raise ValueError(f"faces={faces!r} selects nothing; use 'all' or names from {order}")
        tris = tris.reshape(6, 2, 3)[keep].reshape(-1, 3)
    return verts, tris


def cylinder_mesh(center, radius: float, height: float, segments: int = 16,
                  radius_top: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed (truncated-cone) cylinder along z; ``center`` is the centre of its bottom disc."""
    if segments < 3:
        raise ValueError(f"a cylinder needs >= 3 segments, got {segments}")
    r_top = radius if radius_top is None else radius_top
    ang = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    cx, cy, cz = (float(v) for v in center)
    bottom = np.column_stack([cx + radius * ring[:, 0], cy + radius * ring[:, 1], np.full(segments, cz)])
    top = np.column_stack([cx + r_top * ring[:, 0], cy + r_top * ring[:, 1], np.full(segments, cz + height)])
    verts = np.vstack([bottom, top, [[cx, cy, cz]], [[cx, cy, cz + height]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    b_c, t_c = 2 * segments, 2 * segments + 1
    side = np.concatenate([np.stack([i, j, j + segments], 1), np.stack([i, j + segments, i + segments], 1)])
    caps = np.concatenate([np.stack([np.full(segments, b_c), j, i], 1),
                           np.stack([np.full(segments, t_c), i + segments, j + segments], 1)])
    return verts, np.concatenate([side, caps]).astype(np.int32)


class MeshBuilder:
    """Accumulates labelled parts; ``build()`` returns a ``Scene``.

    >>> b = MeshBuilder("demo")
    >>> inst = b.new_instance()
    >>> b.add_box((0, 0, 0.2), (0.4, 0.4, 0.4), "chair", inst, (200, 30, 30))
    """

    def __init__(self, name: str, class_names: tuple[str, ...] = CLASS_NAMES):
        self.name = name
        self.class_names = tuple(class_names)
        self._class_id = {n: i for i, n in enumerate(self.class_names)}
        self._verts: list[np.ndarray] = []
        self._tris: list[np.ndarray] = []
        self._cls: list[np.ndarray] = []
        self._inst: list[np.ndarray] = []
        self._alb: list[np.ndarray] = []
        self._tex: list[np.ndarray] = []
        self._n_verts = 0
        self._next_instance = 0
        self.rooms: list[Room] = []
        self.meta: dict = {}

    def new_instance(self) -> int:
        """A fresh instance id (consecutive from 0)."""
        self._next_instance += 1
        return self._next_instance - 1

    def add_mesh(self, verts: np.ndarray, tris: np.ndarray, cls: str | None, instance: int,
                 albedo, texture: Texture = Texture.PLAIN) -> None:
        """Add a raw mesh part; ``cls`` None means void (unlabelled)."""
        if cls is not None and cls not in self._class_id:
            raise ValueError(f"unknown class {cls!r}; valid classes: {', '.join(self.class_names)}")
        n = len(tris)
        self._verts.append(np.asarray(verts, dtype=np.float32))
        self._tris.append(np.asarray(tris, dtype=np.int32) + self._n_verts)
        self._cls.append(np.full(n, VOID if cls is None else self._class_id[cls], dtype=np.int16))
        self._inst.append(np.full(n, instance, dtype=np.int32))
        self._alb.append(np.tile(np.clip(np.asarray(albedo), 0, 255).astype(np.uint8), (n, 1)))
        self._tex.append(np.full(n, int(texture), dtype=np.uint8))
        self._n_verts += len(verts)

    def mark(self) -> int:
        """How many parts were added so far (``lift`` moves the parts added after a mark)."""
        return len(self._verts)

    def lift(self, mark: int, dz: float) -> None:
        """Raise every part added since ``mark`` by ``dz`` metres (an upper storey is built at
        floor level, then lifted onto its slab)."""
        for i in range(mark, len(self._verts)):
            v = self._verts[i].copy()   # parts may share arrays with the furniture models
            v[:, 2] += np.float32(dz)
            self._verts[i] = v

    def add_box(self, center, size, cls: str | None, instance: int, albedo,
                texture: Texture = Texture.PLAIN, yaw: float = 0.0, faces: str = "all") -> None:
        self.add_mesh(*box_mesh(center, size, yaw, faces), cls, instance, albedo, texture)

    def add_cylinder(self, center, radius: float, height: float, cls: str | None, instance: int,
                     albedo, texture: Texture = Texture.PLAIN, segments: int = 16,
                     radius_top: float | None = None) -> None:
        self.add_mesh(*cylinder_mesh(center, radius, height, segments, radius_top), cls, instance,
                      albedo, texture)

    def arrays(self) -> dict[str, np.ndarray]:
        """The parts so far as Scene arrays (vertices, triangles, tri_class, tri_instance,
        tri_albedo, tri_texture), without building (or validating) a Scene: additions to
        another scene may be all unlabelled."""
        if not self._tris:
            return {"vertices": np.zeros((0, 3), np.float32), "triangles": np.zeros((0, 3), np.int32),
                    "tri_class": np.zeros(0, np.int16), "tri_instance": np.zeros(0, np.int32),
                    "tri_albedo": np.zeros((0, 3), np.uint8), "tri_texture": np.zeros(0, np.uint8)}
        return {"vertices": np.concatenate(self._verts), "triangles": np.concatenate(self._tris),
                "tri_class": np.concatenate(self._cls), "tri_instance": np.concatenate(self._inst),
                "tri_albedo": np.concatenate(self._alb), "tri_texture": np.concatenate(self._tex)}

    def build(self, floor_z: float = 0.0) -> Scene:
        if not self._tris:
            raise ValueError(f"scene {self.name!r} has no parts")
        return Scene(name=self.name, **self.arrays(), class_names=self.class_names, rooms=list(self.rooms),
                     floor_z=floor_z, meta=dict(self.meta))


def box_room_scene(size_x: float = 6.0, size_y: float = 4.0, wall_height: float = 2.6,
                   objects: tuple[tuple[str, tuple[float, float], tuple[float, float, float]], ...] = (
                       ("chair", (1.5, 1.0), (0.5, 0.5, 0.9)),
                       ("sofa", (-1.8, -1.2), (1.8, 0.8, 0.8)),
                       ("table", (0.5, -0.5), (1.0, 0.6, 0.75)),
                   ),
                   name: str = "box_room") -> Scene:
    """A single rectangular room centred on the origin with floor, walls, ceiling and a few box
    objects ``(class, (x, y) centre, (sx, sy, sz) size)``. Small and fast.

    Test / reference helper: no calnav code path builds it; the tests (rendering, navigation,
    episodes, voxel map, ground truth, scene loading, fusion bench) use it as a known scene."""
    b = MeshBuilder(name)
    t = 0.1
    b.add_box((0, 0, -t / 2), (size_x, size_y, t), "floor", b.new_instance(), (150, 120, 90), Texture.GRAIN, faces="+z")
    b.add_box((0, 0, wall_height + t / 2), (size_x, size_y, t), "ceiling", b.new_instance(), (235, 235, 230), faces="-z")
    for cx, cy, sx, sy in ((0, size_y / 2 + t / 2, size_x + 2 * t, t), (0, -size_y / 2 - t / 2, size_x + 2 * t, t),
                           (size_x / 2 + t / 2, 0, t, size_y), (-size_x / 2 - t / 2, 0, t, size_y)):
        b.add_box((cx, cy, wall_height / 2), (sx, sy, wall_height), "wall", b.new_instance(), (200, 190, 170), Texture.STRIPES)
    rng = np.random.default_rng(0)
    for cls, (x, y), (sx, sy, sz) in objects:
        b.add_box((x, y, sz / 2), (sx, sy, sz), cls, b.new_instance(), rng.integers(40, 220, 3), Texture.FABRIC)
    b.rooms.append(Room("living_room", -size_x / 2, -size_y / 2, size_x / 2, size_y / 2))
    return b.build()


# ---------------------------------------------------------------------------------------------
# Extra shapes for procedural furniture (appended; the functions above keep their signatures).
def sphere_mesh(center, radii, segments: int = 10, rings: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Closed UV ellipsoid: ``center`` (3,) metres, ``radii`` a scalar or (3,) semi-axes in metres.

    ``segments`` points per latitude ring, ``rings`` latitude bands (>= 2); the mesh has
    ``segments * (rings - 1) + 2`` vertices and ``2 * segments * (rings - 1)`` triangles.
    """
    if segments < 3 or rings < 2:
        raise ValueError(f"a sphere needs >= 3 segments and >= 2 rings, got {segments}, {rings}")
    radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (3,))
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]           # polar angle of each inner ring
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring_pts = np.stack([st * np.cos(phi), st * np.sin(phi), np.repeat(ct, segments, axis=1)], axis=-1).reshape(-1, 3)
    unit = np.vstack([ring_pts, [[0, 0, 1]], [[0, 0, -1]]])
    verts = unit * radii + np.asarray(center, dtype=np.float64)
    top, bottom = len(unit) - 2, len(unit) - 1
    i = np.arange(segments)
    j = (i + 1) % segments
    tris = [np.stack([np.full(segments, top), i, j], 1)]
    for r in range(rings - 2):
        a, b = r * segments, (r + 1) * segments
        tris += [np.stack([a + i, b + i, b + j], 1), np.stack([a + i, b + j, a + j], 1)]
    last = (rings - 2) * segments
    tris.append(np.stack([np.full(segments, bottom), last + j, last + i], 1))
    return verts, np.concatenate(tris).astype(np.int32)


def cone_mesh(center, radius: float, height: float, segments: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Closed cone along +z; ``center`` is the centre of its base disc, apex ``height`` above."""
    if segments < 3:
        raise ValueError(f"a cone needs >= 3 segments, got {segments}")
    ang = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    cx, cy, cz = (float(v) for v in center)
    ring = np.column_stack([cx + radius * np.cos(ang), cy + radius * np.sin(ang), np.full(segments, cz)])
    verts = np.vstack([ring, [[cx, cy, cz + height]], [[cx, cy, cz]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    apex, base = segments, segments + 1
    tris = np.concatenate([np.stack([i, j, np.full(segments, apex)], 1), np.stack([np.full(segments, base), j, i], 1)])
    return verts, tris.astype(np.int32)
