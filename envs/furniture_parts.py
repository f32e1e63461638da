"""Shared vocabulary of the furniture builders (``envs.furniture``): palettes, the ``Model``
an object instance is, the ``Parts`` collector that builds one, and sub-assemblies several
classes share on purpose (legs, ceramic basins, faucets, door fronts) -- sharing them is what
makes confusable classes look alike. Every length is metres, in the model frame of
``envs.furniture``'s docstring.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calnav.envs.primitives import box_mesh, cone_mesh, cylinder_mesh, sphere_mesh
from calnav.envs.scene import Texture

CYL_SEGMENTS = 14      # sides of round parts (pots, bowls, round tops)
THIN_SEGMENTS = 8      # sides of thin round parts (legs, stems, faucets)
COLOUR_JITTER = 10.0   # std of per-instance colour jitter, uint8 levels

# Palettes (RGB). Upholstery is shared by sofas, armchairs, upholstered beds and bedding.
WOOD = ((196, 160, 112), (160, 112, 70), (110, 72, 45), (70, 48, 34), (228, 224, 214), (45, 45, 47), (150, 130, 110))
UPHOLSTERY = ((130, 130, 135), (90, 95, 110), (180, 170, 150), (150, 60, 60), (70, 100, 80), (205, 198, 185),
              (60, 70, 110), (120, 90, 70), (215, 205, 185))
BEDDING = UPHOLSTERY + ((238, 238, 232), (200, 212, 228), (225, 205, 195))
CERAMIC = ((246, 246, 243), (236, 236, 231), (224, 228, 233), (250, 247, 238))
METAL = ((172, 174, 178), (62, 62, 64), (205, 205, 210))
STONE = ((202, 200, 194), (62, 62, 64), (150, 145, 140), (230, 228, 220), (120, 100, 85))
POT = ((180, 92, 60), (232, 230, 226), (82, 82, 86), (150, 120, 90), (60, 90, 110))
FOLIAGE = ((50, 110, 45), (72, 140, 60), (40, 90, 50), (96, 130, 56), (32, 82, 40))
SCREEN = ((18, 20, 26), (14, 20, 36), (34, 34, 38))
BOOKS = ((150, 40, 40), (40, 70, 140), (200, 180, 60), (40, 110, 60), (222, 220, 210), (90, 60, 120), (30, 30, 30))


def colour(rng: np.random.Generator, palette) -> np.ndarray:
    """A palette entry with Gaussian jitter: (3,) uint8."""
    base = np.asarray(palette[rng.integers(len(palette))], dtype=np.float64)
    return np.clip(base + rng.normal(0.0, COLOUR_JITTER, 3), 0, 255).astype(np.uint8)


def rot(axis: str, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


@dataclass
class Part:
    """One primitive of a model: (n, 3) float64 vertices in the model frame, (m, 3) triangles."""

    verts: np.ndarray
    tris: np.ndarray
    albedo: np.ndarray
    texture: Texture


@dataclass
class Model:
    """One object instance's geometry in its own frame (see module docstring).

    size: (3,) extents (width along x, depth along y, height), metres.
    support_z: height of a top surface other objects can stand on (None: nothing goes on top).
    support_rect: (x0, y0, x1, y1) usable area of that surface in the model frame, metres.
    """

    cls: str
    parts: list[Part]
    size: np.ndarray
    support_z: float | None = None
    support_rect: tuple[float, float, float, float] | None = None


class Parts:
    """Collects parts of one model; ``model()`` recentres them (footprint centre, base z = 0)."""

    def __init__(self, cls: str):
        self.cls, self.parts = cls, []

    def add(self, verts, tris, albedo, texture=Texture.PLAIN) -> None:
        self.parts.append(Part(np.asarray(verts, np.float64), tris, np.asarray(albedo, np.uint8), texture))

    def box(self, center, size, albedo, texture=Texture.PLAIN) -> None:
        self.add(*box_mesh(center, size), albedo, texture)

    def cyl(self, base, r, h, albedo, texture=Texture.PLAIN, r_top=None, seg=CYL_SEGMENTS, stretch_y=1.0) -> None:
        v, t = cylinder_mesh(base, r, h, seg, r_top)
        v[:, 1] = base[1] + (v[:, 1] - base[1]) * stretch_y   # elliptic cross-section (toilet bowls)
        self.add(v, t, albedo, texture)

    def blob(self, center, radii, albedo, texture=Texture.SPECKLE) -> None:
        self.add(*sphere_mesh(center, radii, 8, 5), albedo, texture)

    def cone(self, base, r, h, albedo, texture=Texture.SPECKLE, tilt=(0.0, 0.0)) -> None:
        v, t = cone_mesh((0, 0, 0), r, h, 8)
        v = v @ (rot("z", tilt[1]) @ rot("x", tilt[0])).T + np.asarray(base)
        self.add(v, t, albedo, texture)

    def model(self, support_z=None, support_rect=None) -> Model:
        allv = np.concatenate([p.verts for p in self.parts])
        lo, hi = allv.min(0), allv.max(0)
        shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
        for p in self.parts:
            p.verts = p.verts + shift
        if support_rect is not None:
            support_rect = (support_rect[0] + shift[0], support_rect[1] + shift[1],
                            support_rect[2] + shift[0], support_rect[3] + shift[1])
            support_z = support_z + shift[2]
        return Model(self.cls, self.parts, hi - lo, support_z, support_rect)


def legs(p: Parts, w, d, h, thick, albedo, inset=0.0, z0=0.0, roundlegs=False) -> None:
    """Four legs of height ``h`` under a w x d top, ``inset`` from its edges."""
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * (w / 2 - inset - thick / 2), sy * (d / 2 - inset - thick / 2)
            if roundlegs:
                p.cyl((x, y, z0), thick / 2, h, albedo, Texture.GRAIN, seg=THIN_SEGMENTS)
            else:
                p.box((x, y, z0 + h / 2), (thick, thick, h), albedo, Texture.GRAIN)


def basin(p: Parts, w, d, h, wall, z0, albedo) -> None:
    """An open-topped ceramic tub (sink, bathtub): bottom slab and four rim walls."""
    p.box((0, 0, z0 + wall / 2), (w, d, wall), albedo)
    for sy in (-1, 1):
        p.box((0, sy * (d - wall) / 2, z0 + h / 2), (w, wall, h), albedo)
    for sx in (-1, 1):
        p.box((sx * (w - wall) / 2, 0, z0 + h / 2), (wall, d - 2 * wall, h), albedo)


def faucet(p: Parts, y, z0, albedo) -> None:
    p.cyl((0, y, z0), 0.015, 0.18, albedo, seg=THIN_SEGMENTS)
    p.box((0, y - 0.06, z0 + 0.17), (0.025, 0.13, 0.025), albedo)


def door_fronts(p: Parts, w, y_front, z0, h, alb, handle, ndoor_fronts: int) -> None:
    """Door fronts (slightly proud of the carcass) with handles."""
    dw = w / ndoor_fronts
    for k in range(ndoor_fronts):
        x = -w / 2 + (k + 0.5) * dw
        p.box((x, y_front - 0.008, z0 + h / 2), (dw - 0.008, 0.016, h - 0.008), alb, Texture.GRAIN)
        hx = x + (dw / 2 - 0.05) * (1 if k % 2 == 0 else -1)
        p.box((hx, y_front - 0.025, z0 + h * 0.6), (0.02, 0.02, min(0.15, h / 3)), handle)
