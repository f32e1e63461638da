"""Procedural furniture: parametric object models built from primitives.

Every length is metres. A ``Model`` lives in its own frame: footprint centred on the origin,
base at z = 0, *front* facing -y and back (the side that goes against a wall) at +y. Each
builder samples size, proportions, a shape variant and colours from ``rng``, so two draws of a
class differ; confusable classes share parts and palettes on purpose (sofa/bed upholstery,
chair/stool legs, table/desk/counter tops, cabinet/shelf carcasses, white ceramics) so that
segmentation is learnable but not trivial. ``envs.furnish`` combines models into
placement units and room recipes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from envs.primitives import box_mesh, cone_mesh, cylinder_mesh, sphere_mesh
from envs.scene import Texture

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


def _rot(axis: str, angle: float) -> np.ndarray:
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


class _Parts:
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
        v = v @ (_rot("z", tilt[1]) @ _rot("x", tilt[0])).T + np.asarray(base)
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


def _legs(p: _Parts, w, d, h, thick, albedo, inset=0.0, z0=0.0, round_legs=False) -> None:
    """Four legs of height ``h`` under a w x d top, ``inset`` from its edges."""
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * (w / 2 - inset - thick / 2), sy * (d / 2 - inset - thick / 2)
            if round_legs:
                p.cyl((x, y, z0), thick / 2, h, albedo, Texture.GRAIN, seg=THIN_SEGMENTS)
            else:
                p.box((x, y, z0 + h / 2), (thick, thick, h), albedo, Texture.GRAIN)


def _basin(p: _Parts, w, d, h, wall, z0, albedo) -> None:
    """An open-topped ceramic tub (sink, bathtub): bottom slab and four rim walls."""
    p.box((0, 0, z0 + wall / 2), (w, d, wall), albedo)
    for sy in (-1, 1):
        p.box((0, sy * (d - wall) / 2, z0 + h / 2), (w, wall, h), albedo)
    for sx in (-1, 1):
        p.box((sx * (w - wall) / 2, 0, z0 + h / 2), (wall, d - 2 * wall, h), albedo)


def _faucet(p: _Parts, y, z0, albedo) -> None:
    p.cyl((0, y, z0), 0.015, 0.18, albedo, seg=THIN_SEGMENTS)
    p.box((0, y - 0.06, z0 + 0.17), (0.025, 0.13, 0.025), albedo)


# --------------------------------------------------------------------------- seating
def chair(rng: np.random.Generator, armchair: bool = False) -> Model:
    """Dining/desk chair (legs, seat, back; armrests sometimes) or an upholstered armchair."""
    p, wood, fabric = _Parts("chair"), colour(rng, WOOD), colour(rng, UPHOLSTERY)
    if armchair:   # a one-seat sofa: the chair/sofa confusion
        w, d, seat_h, arm_w = rng.uniform(0.7, 0.9), rng.uniform(0.7, 0.85), rng.uniform(0.4, 0.46), rng.uniform(0.1, 0.18)
        leg_h, back_t, back_h = rng.uniform(0.04, 0.1), rng.uniform(0.14, 0.22), rng.uniform(0.75, 1.0)
        _legs(p, w, d, leg_h, 0.04, wood, inset=0.03)
        p.box((0, 0, leg_h + (seat_h - leg_h) / 2), (w - 2 * arm_w, d, seat_h - leg_h), fabric, Texture.FABRIC)
        p.box((0, d / 2 - back_t / 2, (leg_h + back_h) / 2), (w - 2 * arm_w, back_t, back_h - leg_h), fabric, Texture.FABRIC)
        arm_h = rng.uniform(0.55, 0.66)
        for sx in (-1, 1):
            p.box((sx * (w - arm_w) / 2, 0, (leg_h + arm_h) / 2), (arm_w, d, arm_h - leg_h), fabric, Texture.FABRIC)
        return p.model()
    w, d, seat_h = rng.uniform(0.42, 0.56), rng.uniform(0.42, 0.54), rng.uniform(0.42, 0.5)
    seat_t, leg = rng.uniform(0.03, 0.07), rng.uniform(0.03, 0.05)
    _legs(p, w, d, seat_h - seat_t, leg, wood, round_legs=rng.random() < 0.3)
    p.box((0, 0, seat_h - seat_t / 2), (w, d, seat_t), wood, Texture.GRAIN)
    if rng.random() < 0.5:
        p.box((0, 0, seat_h + 0.025), (w - 0.04, d - 0.04, 0.05), fabric, Texture.FABRIC)
    back_h, back_t = rng.uniform(0.3, 0.55), rng.uniform(0.02, 0.05)
    if rng.random() < 0.5:   # solid (maybe upholstered) back panel
        tex, alb = (Texture.FABRIC, fabric) if rng.random() < 0.4 else (Texture.GRAIN, wood)
        p.box((0, d / 2 - back_t / 2, seat_h + back_h / 2), (w, back_t, back_h), alb, tex)
    else:                    # two posts and a top rail
        for sx in (-1, 1):
            p.box((sx * (w / 2 - leg / 2), d / 2 - leg / 2, seat_h + back_h / 2), (leg, leg, back_h), wood, Texture.GRAIN)
        p.box((0, d / 2 - leg / 2, seat_h + back_h - 0.06), (w, leg, 0.12), wood, Texture.GRAIN)
    if rng.random() < 0.3:   # armrests on posts
        for sx in (-1, 1):
            p.box((sx * (w / 2 - 0.02), 0, seat_h + 0.21), (0.04, d, 0.03), wood, Texture.GRAIN)
            p.box((sx * (w / 2 - 0.02), -d / 2 + 0.03, seat_h + 0.1), (0.03, 0.03, 0.2), wood, Texture.GRAIN)
    return p.model()


def stool(rng: np.random.Generator, bar: bool = False) -> Model:
    """Seat on 3-4 legs, no backrest; bar stools are taller and often have a foot rail."""
    p, wood = _Parts("stool"), colour(rng, WOOD + METAL)
    seat_h = rng.uniform(0.62, 0.76) if bar else rng.uniform(0.42, 0.5)
    seat_t, leg, r = rng.uniform(0.03, 0.06), rng.uniform(0.025, 0.045), rng.uniform(0.15, 0.21)
    if rng.random() < 0.5:
        p.cyl((0, 0, seat_h - seat_t), r, seat_t, wood, Texture.GRAIN)
    else:
        p.box((0, 0, seat_h - seat_t / 2), (2 * r, 2 * r, seat_t), wood, Texture.GRAIN)
    _legs(p, 2 * r, 2 * r, seat_h - seat_t, leg, wood, inset=0.02, round_legs=rng.random() < 0.5)
    if bar and rng.random() < 0.7:
        for sy in (-1, 1):
            p.box((0, sy * (r - 0.02 - leg / 2), seat_h * 0.35), (2 * r - 0.04, 0.02, 0.02), wood, Texture.GRAIN)
    if rng.random() < 0.3:
        p.cyl((0, 0, seat_h), r * 0.95, 0.04, colour(rng, UPHOLSTERY), Texture.FABRIC)
    return p.model()


def sofa(rng: np.random.Generator) -> Model:
    """2-3 seat sofa: base, seat cushions, back, usually arms, short legs sometimes."""
    p, fabric, wood = _Parts("sofa"), colour(rng, UPHOLSTERY), colour(rng, WOOD)
    seats, seat_w = int(rng.integers(2, 4)), rng.uniform(0.55, 0.7)
    arm_w = rng.uniform(0.1, 0.22) if rng.random() < 0.85 else 0.0
    w, d, seat_h = seats * seat_w + 2 * arm_w, rng.uniform(0.8, 0.98), rng.uniform(0.38, 0.46)
    back_h, back_t, cush_t = rng.uniform(0.72, 0.95), rng.uniform(0.15, 0.25), rng.uniform(0.1, 0.16)
    leg_h = rng.uniform(0.04, 0.12) if rng.random() < 0.6 else 0.0
    if leg_h:
        _legs(p, w, d, leg_h, 0.04, wood, inset=0.04)
    base_top = seat_h - cush_t
    p.box((0, 0, (leg_h + base_top) / 2), (w, d, base_top - leg_h), fabric, Texture.FABRIC)
    for k in range(seats):
        x = -w / 2 + arm_w + (k + 0.5) * seat_w
        p.box((x, -back_t / 2, base_top + cush_t / 2), (seat_w - 0.01, d - back_t, cush_t), fabric, Texture.FABRIC)
    p.box((0, d / 2 - back_t / 2, (base_top + back_h) / 2), (w - 2 * arm_w, back_t, back_h - base_top), fabric, Texture.FABRIC)
    arm_h = rng.uniform(0.55, 0.68)
    for sx in ((-1, 1) if arm_w else ()):
        p.box((sx * (w - arm_w) / 2, 0, (leg_h + arm_h) / 2), (arm_w, d, arm_h - leg_h), fabric, Texture.FABRIC)
    for k in range(int(rng.integers(0, 3))):   # throw pillows
        x = (-1) ** k * (w / 2 - arm_w - 0.25)
        p.box((x, d / 2 - back_t - 0.07, seat_h + 0.2), (0.4, 0.12, 0.38), colour(rng, BEDDING), Texture.FABRIC)
    return p.model()


def bed(rng: np.random.Generator) -> Model:
    """Bed: frame, mattress, blanket, pillows, usually a headboard (at +y, against the wall)."""
    p, wood = _Parts("bed"), colour(rng, WOOD)
    fabric, sheet = colour(rng, UPHOLSTERY), colour(rng, BEDDING)
    w = (rng.uniform(0.9, 1.0), rng.uniform(1.35, 1.45), rng.uniform(1.55, 1.85))[rng.integers(3)]
    length, frame_h, matt_t = rng.uniform(1.95, 2.15), rng.uniform(0.2, 0.35), rng.uniform(0.18, 0.26)
    frame_alb, frame_tex = (fabric, Texture.FABRIC) if rng.random() < 0.4 else (wood, Texture.GRAIN)
    leg_h = rng.uniform(0.05, 0.15) if rng.random() < 0.5 else 0.0
    if leg_h:
        _legs(p, w, length, leg_h, 0.05, wood, inset=0.03)
    p.box((0, 0, (leg_h + frame_h) / 2), (w, length, frame_h - leg_h), frame_alb, frame_tex)
    top = frame_h + matt_t
    p.box((0, 0, frame_h + matt_t / 2), (w - 0.04, length - 0.04, matt_t), colour(rng, BEDDING[-3:]), Texture.FABRIC)
    blanket_len = length * rng.uniform(0.55, 0.75)
    p.box((0, -length / 2 + blanket_len / 2, top + 0.03), (w, blanket_len, 0.06), sheet, Texture.FABRIC)
    n_pillows = 1 if w < 1.2 else 2
    for k in range(n_pillows):
        x = 0.0 if n_pillows == 1 else (k - 0.5) * w / 2
        p.box((x, length / 2 - 0.25, top + 0.06), (w / n_pillows - 0.08, 0.35, 0.12), colour(rng, BEDDING), Texture.FABRIC)
    if rng.random() < 0.9:
        head_t, head_h = rng.uniform(0.04, 0.1), rng.uniform(0.85, 1.2)
        p.box((0, length / 2 + head_t / 2, head_h / 2), (w + 0.04, head_t, head_h), frame_alb, frame_tex)
    if rng.random() < 0.25:
        p.box((0, -length / 2 - 0.03, (top + 0.1) / 2), (w + 0.04, 0.05, top + 0.1), frame_alb, frame_tex)
    return p.model()


# ------------------------------------------------------------------------- bathroom
def toilet(rng: np.random.Generator) -> Model:
    """Elliptic bowl on a pedestal, seat (lid up sometimes), cistern tank or a concealed panel."""
    p, white = _Parts("toilet"), colour(rng, CERAMIC)
    bowl_h, r, stretch = rng.uniform(0.37, 0.42), rng.uniform(0.17, 0.2), rng.uniform(1.2, 1.4)
    p.cyl((0, 0, 0), r * 0.7, bowl_h, white, r_top=r, stretch_y=stretch)
    seat = white if rng.random() < 0.8 else colour(rng, WOOD)
    p.cyl((0, 0, bowl_h), r * 1.02, 0.03, seat, stretch_y=stretch)
    back_y = r * stretch
    if rng.random() < 0.75:   # close-coupled cistern
        tw, td, th = rng.uniform(0.34, 0.46), rng.uniform(0.15, 0.22), rng.uniform(0.32, 0.42)
        p.box((0, back_y + td / 2 - 0.04, bowl_h + th / 2 - 0.05), (tw, td, th), white)
        p.box((0, back_y + td / 2 - 0.04, bowl_h - 0.05 + th + 0.015), (tw + 0.02, td + 0.02, 0.03), white)
    else:                     # wall-hung look: a panel behind the bowl
        p.box((0, back_y + 0.05, 0.5), (rng.uniform(0.45, 0.6), 0.1, 1.0), white)
    if rng.random() < 0.5:    # raised lid
        p.box((0, back_y - 0.03, bowl_h + 0.22), (2 * r * 0.9, 0.025, 0.4), seat)
    return p.model()


def sink(rng: np.random.Generator, pedestal: bool = True) -> Model:
    """A basin with a faucet; on a pedestal column (floor-standing) or bare (goes on a counter)."""
    p, white, metal = _Parts("sink"), colour(rng, CERAMIC if pedestal or rng.random() < 0.4 else METAL), colour(rng, METAL)
    w, d, h = rng.uniform(0.45, 0.65), rng.uniform(0.35, 0.48), rng.uniform(0.12, 0.18)
    z0 = rng.uniform(0.68, 0.75) if pedestal else 0.0
    if pedestal:
        p.cyl((0, 0, 0), rng.uniform(0.09, 0.13), z0, white, r_top=rng.uniform(0.07, 0.1))
    _basin(p, w, d, h, 0.03, z0, white)
    _faucet(p, d / 2 - 0.02, z0 + h, metal)
    return p.model()


def bathtub(rng: np.random.Generator) -> Model:
    """Tub with its long side along x: built-in (panelled to the floor) or on four short feet."""
    p, white = _Parts("bathtub"), colour(rng, CERAMIC)
    length, w, h, wall = rng.uniform(1.5, 1.8), rng.uniform(0.7, 0.82), rng.uniform(0.5, 0.6), rng.uniform(0.06, 0.1)
    feet = rng.uniform(0.08, 0.14) if rng.random() < 0.35 else 0.0
    if feet:
        for sx in (-1, 1):
            for sy in (-1, 1):
                p.cyl((sx * (length / 2 - 0.15), sy * (w / 2 - 0.12), 0), 0.04, feet, white, seg=THIN_SEGMENTS)
    _basin(p, length, w, h - feet, wall, feet, white)
    _faucet(p, w / 2 - wall / 2, h, colour(rng, METAL))
    return p.model()


# ---------------------------------------------------------------------- surfaces & storage
def table(rng: np.random.Generator, kind: str = "dining") -> Model:
    """Table top on four legs (or a round top on a pedestal). kind: dining | coffee | side."""
    p, wood = _Parts("table"), colour(rng, WOOD)
    h, w, d = {"dining": (rng.uniform(0.72, 0.78), rng.uniform(0.9, 1.8), rng.uniform(0.75, 1.0)),
               "coffee": (rng.uniform(0.38, 0.48), rng.uniform(0.8, 1.3), rng.uniform(0.45, 0.7)),
               "side": (rng.uniform(0.5, 0.65), rng.uniform(0.4, 0.55), rng.uniform(0.4, 0.55))}[kind]
    top_t = rng.uniform(0.025, 0.05)
    if kind != "coffee" and rng.random() < 0.25:   # round top on a pedestal
        r = min(w, d) / 2 if kind == "side" else rng.uniform(0.45, 0.6)
        p.cyl((0, 0, h - top_t), r, top_t, wood, Texture.GRAIN)
        p.cyl((0, 0, 0), 0.05, h - top_t, wood, Texture.GRAIN, seg=THIN_SEGMENTS)
        p.cyl((0, 0, 0), r * 0.5, 0.03, wood, Texture.GRAIN)
        return p.model(h, (-r * 0.7, -r * 0.7, r * 0.7, r * 0.7))
    p.box((0, 0, h - top_t / 2), (w, d, top_t), wood, Texture.GRAIN)
    _legs(p, w, d, h - top_t, rng.uniform(0.04, 0.07), wood, inset=rng.uniform(0.0, 0.06), round_legs=rng.random() < 0.4)
    if kind == "coffee" and rng.random() < 0.5:    # lower shelf
        p.box((0, 0, 0.12), (w - 0.1, d - 0.1, 0.02), wood, Texture.GRAIN)
    return p.model(h, (-w / 2, -d / 2, w / 2, d / 2))


def desk(rng: np.random.Generator) -> Model:
    """Desk: a table-like top on legs, drawer pedestals or side panels, often a modesty panel."""
    p, wood = _Parts("desk"), colour(rng, WOOD)
    w, d, h, top_t = rng.uniform(1.0, 1.6), rng.uniform(0.55, 0.75), rng.uniform(0.72, 0.76), rng.uniform(0.025, 0.04)
    p.box((0, 0, h - top_t / 2), (w, d, top_t), wood, Texture.GRAIN)
    variant = rng.integers(3)
    if variant == 0:
        _legs(p, w, d, h - top_t, 0.05, colour(rng, WOOD + METAL), inset=0.02)
    else:
        ped_w = rng.uniform(0.38, 0.45)
        sides = (-1, 1) if variant == 2 else (-1,)
        for sx in sides:   # drawer pedestal with three drawer fronts
            x = sx * (w / 2 - ped_w / 2)
            p.box((x, 0, (h - top_t) / 2), (ped_w, d - 0.02, h - top_t), wood, Texture.GRAIN)
            for k in range(3):
                p.box((x, -d / 2 + 0.005, (k + 0.5) * (h - top_t) / 3), (ped_w - 0.04, 0.01, (h - top_t) / 3 - 0.03), wood, Texture.GRAIN)
        if variant == 1:
            p.box((w / 2 - 0.015, 0, (h - top_t) / 2), (0.03, d - 0.02, h - top_t), wood, Texture.GRAIN)
    if rng.random() < 0.6:
        p.box((0, d / 2 - 0.05, h * 0.6), (w - 0.1, 0.02, h * 0.5), wood, Texture.GRAIN)
    return p.model(h, (-w / 2 + 0.05, -d / 2 + 0.05, w / 2 - 0.05, d / 2 - 0.02))


def _doors(p: _Parts, w, y_front, z0, h, alb, handle, n_doors: int) -> None:
    """Door fronts (slightly proud of the carcass) with handles."""
    dw = w / n_doors
    for k in range(n_doors):
        x = -w / 2 + (k + 0.5) * dw
        p.box((x, y_front - 0.008, z0 + h / 2), (dw - 0.008, 0.016, h - 0.008), alb, Texture.GRAIN)
        hx = x + (dw / 2 - 0.05) * (1 if k % 2 == 0 else -1)
        p.box((hx, y_front - 0.025, z0 + h * 0.6), (0.02, 0.02, min(0.15, h / 3)), handle)


def counter(rng: np.random.Generator, island: bool = False) -> Model:
    """Kitchen counter run: recessed plinth, carcass with doors, stone or wood top."""
    p, body, top = _Parts("counter"), colour(rng, WOOD), colour(rng, STONE)
    w = rng.uniform(1.2, 1.8) if island else rng.uniform(1.2, 2.8)
    d, h = rng.uniform(0.58, 0.64), rng.uniform(0.86, 0.92)
    top_t, plinth = rng.uniform(0.03, 0.045), rng.uniform(0.08, 0.12)
    p.box((0, 0.03, plinth / 2), (w - 0.02, d - 0.08, plinth), colour(rng, METAL[1:2] + WOOD))
    p.box((0, 0.01, (plinth + h - top_t) / 2), (w - 0.02, d - 0.04, h - top_t - plinth), body, Texture.GRAIN)
    _doors(p, w - 0.02, -d / 2 + 0.03, plinth, h - top_t - plinth, body, colour(rng, METAL), max(1, int(round(w / 0.55))))
    p.box((0, 0, h - top_t / 2), (w, d, top_t), top, Texture.SPECKLE if rng.random() < 0.7 else Texture.GRAIN)
    return p.model(h, (-w / 2, -d / 2 + 0.02, w / 2, d / 2 - 0.02))


def cabinet(rng: np.random.Generator, kind: str = "tall") -> Model:
    """Closed carcass with doors or drawers. kind: tall (wardrobe) | low (sideboard) | small (nightstand)."""
    p, body = _Parts("cabinet"), colour(rng, WOOD)
    w, d, h = {"tall": (rng.uniform(0.8, 1.5), rng.uniform(0.45, 0.62), rng.uniform(1.7, 2.2)),
               "low": (rng.uniform(0.8, 1.8), rng.uniform(0.38, 0.5), rng.uniform(0.45, 0.8)),
               "small": (rng.uniform(0.4, 0.55), rng.uniform(0.35, 0.45), rng.uniform(0.45, 0.6))}[kind]
    leg_h = rng.uniform(0.06, 0.15) if rng.random() < 0.4 else 0.0
    if leg_h:
        _legs(p, w, d, leg_h, 0.04, body, inset=0.02)
    p.box((0, 0, (leg_h + h) / 2), (w, d, h - leg_h), body, Texture.GRAIN)
    front_alb, handle = (body if rng.random() < 0.6 else colour(rng, WOOD)), colour(rng, METAL)
    if kind == "small" or rng.random() < 0.3:   # a stack of drawers
        n = int(rng.integers(2, 5))
        for k in range(n):
            dh = (h - leg_h) / n
            _doors(p, w, -d / 2, leg_h + k * dh, dh, front_alb, handle, 1)
    else:
        _doors(p, w, -d / 2, leg_h, h - leg_h, front_alb, handle, max(1, int(round(w / 0.5))))
    return p.model(h, (-w / 2 + 0.02, -d / 2 + 0.02, w / 2 - 0.02, d / 2 - 0.02))


def shelf(rng: np.random.Generator, tall: bool | None = None) -> Model:
    """Open bookcase: sides, back, boards; books on some boards."""
    p, wood = _Parts("shelf"), colour(rng, WOOD)
    tall = rng.random() < 0.6 if tall is None else tall
    w, d = rng.uniform(0.6, 1.2), rng.uniform(0.25, 0.4)
    h, t = (rng.uniform(1.5, 2.0) if tall else rng.uniform(0.75, 1.1)), rng.uniform(0.018, 0.03)
    n_boards = max(2, int(h / rng.uniform(0.3, 0.4)))
    for sx in (-1, 1):
        p.box((sx * (w / 2 - t / 2), 0, h / 2), (t, d, h), wood, Texture.GRAIN)
    p.box((0, d / 2 - t / 2, h / 2), (w - 2 * t, t, h), wood, Texture.GRAIN)
    for k in range(n_boards + 1):
        z = 0.05 + k * (h - 0.05 - t) / n_boards
        p.box((0, 0, z + t / 2), (w - 2 * t, d - t, t), wood, Texture.GRAIN)
        if k < n_boards and rng.random() < 0.7:   # a run of books on this board
            x, x_end = -w / 2 + t + rng.uniform(0, 0.15), w / 2 - t - rng.uniform(0, 0.3)
            for _ in range(int(rng.integers(2, 6))):
                bw, bh = rng.uniform(0.03, 0.08), rng.uniform(0.18, 0.28)
                if x + bw > x_end:
                    break
                p.box((x + bw / 2, 0, z + t + bh / 2), (bw, d * 0.75, bh), colour(rng, BOOKS))
                x += bw
    return p.model()


# ------------------------------------------------------------------------------ decor
def plant(rng: np.random.Generator, tabletop: bool = False) -> Model:
    """Pot plus foliage: a bush of blobs, a small tree (stem + cones/blobs) or spiky leaves."""
    p, pot, green = _Parts("plant"), colour(rng, POT), colour(rng, FOLIAGE)
    scale = rng.uniform(0.35, 0.5) if tabletop else 1.0
    r, h = rng.uniform(0.12, 0.24) * scale, rng.uniform(0.18, 0.45) * scale
    p.cyl((0, 0, 0), r * rng.uniform(0.7, 0.9), h, pot, r_top=r, seg=12)
    variant = rng.integers(3)
    if variant == 0:     # bush: overlapping blobs
        for _ in range(int(rng.integers(3, 7))):
            br = rng.uniform(0.12, 0.28) * scale
            off = rng.uniform(-1, 1, 2) * r * 0.8
            p.blob((off[0], off[1], h + br * rng.uniform(0.5, 1.6)), (br, br, br * 0.8), colour(rng, FOLIAGE))
    elif variant == 1:   # tree: stem and a crown of cones or blobs
        stem = rng.uniform(0.5, 1.2) * scale
        p.cyl((0, 0, h), 0.02 * scale + 0.005, stem, colour(rng, WOOD[1:4]), seg=THIN_SEGMENTS)
        for k in range(int(rng.integers(2, 5))):
            cr = rng.uniform(0.18, 0.32) * scale * (1 - 0.15 * k)
            if rng.random() < 0.5:
                p.cone((0, 0, h + stem * (0.45 + 0.2 * k)), cr, cr * 1.6, green)
            else:
                p.blob((0, 0, h + stem * (0.65 + 0.2 * k)), (cr, cr, cr), green)
    else:                # spiky leaves fanning out
        n = int(rng.integers(5, 10))
        for k in range(n):
            tilt = rng.uniform(0.15, 0.6)
            p.cone((0, 0, h * 0.9), rng.uniform(0.03, 0.06) * scale + 0.01, rng.uniform(0.4, 0.9) * scale, green,
                   tilt=(tilt, 2 * np.pi * k / n))
    return p.model()


def tv(rng: np.random.Generator, small: bool = False, wall: bool = False) -> Model:
    """Flat panel with a screen face; on a stand (feet or neck + plate) unless wall-mounted."""
    p, frame, screen = _Parts("tv_monitor"), colour(rng, SCREEN), colour(rng, SCREEN)
    w = rng.uniform(0.45, 0.7) if small else rng.uniform(0.8, 1.4)
    h, t = w * rng.uniform(0.5, 0.62), rng.uniform(0.025, 0.06)
    z0 = 0.0 if wall else rng.uniform(0.08, 0.18)
    p.box((0, 0, z0 + h / 2), (w, t, h), frame)
    p.box((0, -t / 2 - 0.002, z0 + h / 2), (w - 0.03, 0.004, h - 0.03), screen)
    if not wall:
        base_d = max(t + 0.04, rng.uniform(0.15, 0.25))
        if rng.random() < 0.5:   # neck and plate
            p.box((0, t / 2 + 0.02, z0 / 2 + 0.05), (0.05, 0.03, z0 + 0.1), frame)
            p.box((0, 0.02, 0.01), (rng.uniform(0.2, 0.35), base_d, 0.02), frame)
        else:                    # two feet
            for sx in (-1, 1):
                p.box((sx * w * 0.35, 0.0, z0 / 2), (0.04, base_d, z0), frame)
    return p.model()
