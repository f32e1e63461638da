"""Test worlds that reproduce what real scans do to navigation: uneven and unlabelled floors,
steps, holes, a sofa behind a floor step (tests build them; no third-party data)."""
from __future__ import annotations

import numpy as np

from calnav.envs.primitives import MeshBuilder
from calnav.envs.scene import Room, Scene, Texture

WALL_T, WALL_H = 0.1, 2.5


def walls(b: MeshBuilder, x0: float, y0: float, x1: float, y1: float, gaps=()) -> None:
    """Walls around [x0, x1] x [y0, y1] (inner faces on the rectangle); ``gaps``: (side, lo, hi)
    doorways, side one of '-x' '+x' '-y' '+y', lo/hi along the wall."""
    t = WALL_T
    sides = {"-y": (x0 - t, x1 + t, y0 - t, y0), "+y": (x0 - t, x1 + t, y1, y1 + t),
             "-x": (x0 - t, x0, y0, y1), "+x": (x1, x1 + t, y0, y1)}
    for side, (a0, a1, b0, b1) in sides.items():
        along_x = side in ("-y", "+y")
        lo, hi = (a0, a1) if along_x else (b0, b1)
        cuts = sorted((g[1], g[2]) for g in gaps if g[0] == side)
        pieces, u = [], lo
        for g0, g1 in cuts:
            pieces.append((u, g0))
            u = g1
        pieces.append((u, hi))
        for u0, u1 in pieces:
            if u1 - u0 < 1e-6:
                continue
            if along_x:
                centre, size = ((u0 + u1) / 2, (b0 + b1) / 2, WALL_H / 2), (u1 - u0, b1 - b0, WALL_H)
            else:
                centre, size = ((a0 + a1) / 2, (u0 + u1) / 2, WALL_H / 2), (a1 - a0, u1 - u0, WALL_H)
            b.add_box(centre, size, "wall", b.new_instance(), (200, 195, 185), Texture.STRIPES)


def floor_patch(b: MeshBuilder, x0: float, y0: float, x1: float, y1: float, z: float = 0.0,
                cls: str | None = "floor", n: int = 1, warp=None) -> None:
    """A floor sheet over [x0, x1] x [y0, y1] at height z (+ warp(x, y) metres), split into
    n x n quads; ``cls`` None leaves it unlabelled."""
    xs, ys = np.linspace(x0, x1, n + 1), np.linspace(y0, y1, n + 1)
    gx, gy = np.meshgrid(xs, ys)
    gz = np.full_like(gx, z) + (warp(gx, gy) if warp is not None else 0.0)
    verts = np.stack([gx, gy, gz], axis=-1).reshape(-1, 3)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, bb, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    tris = np.concatenate([np.stack([a, bb, c], 1), np.stack([a, c, d], 1)])   # counter-clockwise from above
    b.add_mesh(verts, tris, cls, b.new_instance() if cls else -1, (150, 120, 90), Texture.GRAIN)


def scan_like(b: MeshBuilder, name: str, rooms=()) -> Scene:
    """The builder's scene flagged as an open scan surface (``closed_solids`` False)."""
    b.rooms = list(rooms)
    scene = b.build()
    scene.name = name
    scene.meta["closed_solids"] = False
    return scene


def sofa(b: MeshBuilder, x: float, y: float, width: float = 2.0, depth: float = 0.9) -> None:
    """A sofa centred at (x, y), its back along +y: seat 0.45 m, back 0.85 m."""
    inst = b.new_instance()
    b.add_box((x, y - 0.1, 0.225), (width, depth - 0.2, 0.45), "sofa", inst, (120, 60, 50), Texture.FABRIC)
    b.add_box((x, y + depth / 2 - 0.1, 0.425), (width, 0.2, 0.85), "sofa", inst, (120, 60, 50), Texture.FABRIC)


def sofa_step_house() -> Scene:
    """The real scan's failure in miniature: a 6 x 5 m room, a sofa against the +y wall, a
    coffee table in front of it, a hole in the floor on the sofa's left and a cabinet on its
    right, so that the only spots the sofa can be seen from within 1.0 m lie 0.75-1.0 m in
    front of it -- right on a 3.5 cm floor step 0.8 m in front of the sofa (the floor nearer
    the sofa is higher; part of it unlabelled). A chair in the far corner is a second goal."""
    b = MeshBuilder("sofa_step_house")
    x0, y0, x1, y1 = 0.0, 0.0, 6.0, 5.0
    sofa_front = y1 - 0.9
    step_y = sofa_front - 0.8
    hole = (1.6, 2.3, step_y, y1)
    floor_patch(b, x0, y0, x1, step_y, 0.0, cls="floor", n=4)
    floor_patch(b, x0, step_y, hole[0], y1, 0.035, cls=None, n=2)              # unlabelled
    floor_patch(b, hole[1], step_y, x1, y1, 0.035, cls="floor", n=4)
    walls(b, x0, y0, x1, y1)
    sofa(b, 3.4, y1 - 0.45)
    table = b.new_instance()
    b.add_box((3.4, sofa_front - 0.35, 0.225), (2.2, 0.4, 0.45), "table", table, (110, 80, 50), Texture.GRAIN)
    cabinet = b.new_instance()
    b.add_box((4.85, 4.2, 0.4), (0.7, 1.6, 0.8), "cabinet", cabinet, (90, 70, 60), Texture.GRAIN)
    chair = b.new_instance()
    b.add_box((0.6, 0.6, 0.45), (0.5, 0.5, 0.9), "chair", chair, (60, 90, 160), Texture.GRAIN)
    return scan_like(b, "sofa_step_house", [Room("living_room", x0, y0, x1, y1)])


def warped_floor_house(amplitude_m: float = 0.06) -> Scene:
    """A 7 x 5 m two-room flat whose floor is bent by a smooth 0-``amplitude_m`` warp, half of
    it unlabelled, with a bed and a chair (scan-like surfaces)."""
    def warp(x, y):
        return amplitude_m * 0.5 * (1 + np.sin(2 * np.pi * x / 5.0) * np.cos(2 * np.pi * y / 7.0))

    b = MeshBuilder("warped_floor_house")
    floor_patch(b, 0.0, 0.0, 3.5, 5.0, cls=None, n=14, warp=warp)
    floor_patch(b, 3.5, 0.0, 7.0, 5.0, cls="floor", n=14, warp=warp)
    walls(b, 0.0, 0.0, 7.0, 5.0)
    b.add_box((3.5, 1.25, WALL_H / 2), (WALL_T, 2.5, WALL_H), "wall", b.new_instance(), (200, 195, 185))
    b.add_box((3.5, 4.5, WALL_H / 2), (WALL_T, 1.0, WALL_H), "wall", b.new_instance(), (200, 195, 185))
    bed = b.new_instance()
    b.add_box((5.8, 3.6, 0.3), (1.4, 2.0, 0.6), "bed", bed, (200, 200, 220), Texture.FABRIC)
    chair = b.new_instance()
    b.add_box((0.8, 0.8, 0.45), (0.5, 0.5, 0.9), "chair", chair, (60, 90, 160), Texture.GRAIN)
    return scan_like(b, "warped_floor_house", [Room("bedroom", 3.5, 0.0, 7.0, 5.0), Room("office", 0.0, 0.0, 3.5, 5.0)])
