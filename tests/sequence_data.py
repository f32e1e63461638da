"""Small generated recordings for the sequence tests: a labelled box room with a table, seen
by a few cameras, written in ScanNet or 7-Scenes layout (tens of pixels, a few frames)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calnav.agent.segmenters.base import default_class_names

CLASSES = default_class_names()
WALL, FLOOR, CEILING, TABLE = (CLASSES.index(n) for n in ("wall", "floor", "ceiling", "table"))
ROOM = (4.0, 3.0, 2.5)       # x, y, z extent, metres
TABLE_BOX = ((1.6, 1.1, 0.0), (2.4, 1.9, 0.75))


def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (8, 3) and triangles (12, 3) of an axis-aligned box; triangle pairs in the order
    -z, +z, -y, +y, -x, +x."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], np.float64)
    quads = [(0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (3, 2, 6, 7), (0, 3, 7, 4), (1, 2, 6, 5)]
    t = np.array([tri for a, b, c, d in quads for tri in ((a, b, c), (a, c, d))], np.int64)
    return v, t


def room_mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, triangles, tri_class) of the room (floor, ceiling, walls) and a table box."""
    rv, rt = _box((0, 0, 0), ROOM)
    room_cls = np.array([FLOOR] * 2 + [CEILING] * 2 + [WALL] * 8)
    tv, tt = _box(*TABLE_BOX)
    return np.vstack([rv, tv]), np.vstack([rt, tt + len(rv)]), np.concatenate([room_cls, [TABLE] * 12])


def intrinsics(width: int, height: int, f_ratio: float = 0.8) -> np.ndarray:
    f = f_ratio * width
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])


def poses(n: int) -> list[np.ndarray]:
    """Cameras at 1.3 m height turning around the room centre, looking slightly down."""
    from calnav.envs.render import look_at_pose

    out = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.array([2.0 + 0.3 * np.cos(a), 1.5 + 0.3 * np.sin(a), 1.3])
        out.append(look_at_pose(eye, eye + np.array([np.cos(a), np.sin(a), -0.35])))
    return out


def render_frames(n: int, width: int = 40, height: int = 30):
    """[(rgb (H, W, 3) uint8, depth (H, W) float32 m, labels (H, W) int64, pose)] and K."""
    from calnav.mapping.ground_truth import LabelledMesh

    v, t, c = room_mesh()
    mesh = LabelledMesh(v, t, c)
    k = intrinsics(width, height)
    palette = np.random.default_rng(0).integers(40, 216, (len(CLASSES) + 1, 3), dtype=np.uint8)
    frames = []
    for pose in poses(n):
        depth, labels = mesh.render(k, pose, width, height)
        rgb = palette[labels]   # flat colour per class (label -1: the last entry)
        frames.append((rgb, depth, labels, pose))
    return frames, k


def write_scannet(root: Path, n: int = 6, width: int = 40, height: int = 30, max_edge_m: float = 0.1,
                  bad_pose: int | None = None) -> Path:
    """A ScanNet-layout recording of the room under ``root`` (frame ``bad_pose`` gets ScanNet's
    -inf pose); returns root."""
    from calnav.eval.sequence.export import ScanNetWriter, write_ground_truth

    frames, k = render_frames(n, width, height)
    writer = ScanNetWriter(root, k, k)
    for i, (rgb, depth, labels, pose) in enumerate(frames):
        writer.write(i, rgb, depth, np.full((4, 4), -np.inf) if i == bad_pose else pose, labels)
    v, t, c = room_mesh()
    write_ground_truth(root, "scene0000_00", v, t, c, CLASSES, max_edge_m)
    return root
