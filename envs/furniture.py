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

import numpy as np

from calnav.envs.furniture_parts import (BEDDING, BOOKS, CERAMIC, FOLIAGE, METAL, POT, SCREEN, STONE, THIN_SEGMENTS,
                                  UPHOLSTERY, WOOD, Model, Parts, basin, colour, door_fronts, faucet, legs)
from calnav.envs.scene import Texture

# --------------------------------------------------------------------------- seating
def chair(rng: np.random.Generator, armchair: bool = False) -> Model:
    """Dining/desk chair (legs, seat, back; armrests sometimes) or an upholstered armchair."""
    p, wood, fabric = Parts("chair"), colour(rng, WOOD), colour(rng, UPHOLSTERY)
    if armchair:   # a one-seat sofa: the chair/sofa confusion
        w, d, seat_h, arm_w = rng.uniform(0.7, 0.9), rng.uniform(0.7, 0.85), rng.uniform(0.4, 0.46), rng.uniform(0.1, 0.18)
        leg_h, back_t, back_h = rng.uniform(0.04, 0.1), rng.uniform(0.14, 0.22), rng.uniform(0.75, 1.0)
        legs(p, w, d, leg_h, 0.04, wood, inset=0.03)
        p.box((0, 0, leg_h + (seat_h - leg_h) / 2), (w - 2 * arm_w, d, seat_h - leg_h), fabric, Texture.FABRIC)
        p.box((0, d / 2 - back_t / 2, (leg_h + back_h) / 2), (w - 2 * arm_w, back_t, back_h - leg_h), fabric, Texture.FABRIC)
        arm_h = rng.uniform(0.55, 0.66)
        for sx in (-1, 1):
            p.box((sx * (w - arm_w) / 2, 0, (leg_h + arm_h) / 2), (arm_w, d, arm_h - leg_h), fabric, Texture.FABRIC)
        return p.model()
    w, d, seat_h = rng.uniform(0.42, 0.56), rng.uniform(0.42, 0.54), rng.uniform(0.42, 0.5)
    seat_t, leg = rng.uniform(0.03, 0.07), rng.uniform(0.03, 0.05)
    legs(p, w, d, seat_h - seat_t, leg, wood, roundlegs=rng.random() < 0.3)
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
    p, wood = Parts("stool"), colour(rng, WOOD + METAL)
    seat_h = rng.uniform(0.62, 0.76) if bar else rng.uniform(0.42, 0.5)
    seat_t, leg, r = rng.uniform(0.03, 0.06), rng.uniform(0.025, 0.045), rng.uniform(0.15, 0.21)
    if rng.random() < 0.5:
        p.cyl((0, 0, seat_h - seat_t), r, seat_t, wood, Texture.GRAIN)
    else:
        p.box((0, 0, seat_h - seat_t / 2), (2 * r, 2 * r, seat_t), wood, Texture.GRAIN)
    legs(p, 2 * r, 2 * r, seat_h - seat_t, leg, wood, inset=0.02, roundlegs=rng.random() < 0.5)
    if bar and rng.random() < 0.7:
        for sy in (-1, 1):
            p.box((0, sy * (r - 0.02 - leg / 2), seat_h * 0.35), (2 * r - 0.04, 0.02, 0.02), wood, Texture.GRAIN)
    if rng.random() < 0.3:
        p.cyl((0, 0, seat_h), r * 0.95, 0.04, colour(rng, UPHOLSTERY), Texture.FABRIC)
    return p.model()


def sofa(rng: np.random.Generator) -> Model:
    """2-3 seat sofa: base, seat cushions, back, usually arms, short legs sometimes."""
    p, fabric, wood = Parts("sofa"), colour(rng, UPHOLSTERY), colour(rng, WOOD)
    seats, seat_w = int(rng.integers(2, 4)), rng.uniform(0.55, 0.7)
    arm_w = rng.uniform(0.1, 0.22) if rng.random() < 0.85 else 0.0
    w, d, seat_h = seats * seat_w + 2 * arm_w, rng.uniform(0.8, 0.98), rng.uniform(0.38, 0.46)
    back_h, back_t, cush_t = rng.uniform(0.72, 0.95), rng.uniform(0.15, 0.25), rng.uniform(0.1, 0.16)
    leg_h = rng.uniform(0.04, 0.12) if rng.random() < 0.6 else 0.0
    if leg_h:
        legs(p, w, d, leg_h, 0.04, wood, inset=0.04)
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
    p, wood = Parts("bed"), colour(rng, WOOD)
    fabric, sheet = colour(rng, UPHOLSTERY), colour(rng, BEDDING)
    w = (rng.uniform(0.9, 1.0), rng.uniform(1.35, 1.45), rng.uniform(1.55, 1.85))[rng.integers(3)]
    length, frame_h, matt_t = rng.uniform(1.95, 2.15), rng.uniform(0.2, 0.35), rng.uniform(0.18, 0.26)
    frame_alb, frame_tex = (fabric, Texture.FABRIC) if rng.random() < 0.4 else (wood, Texture.GRAIN)
    leg_h = rng.uniform(0.05, 0.15) if rng.random() < 0.5 else 0.0
    if leg_h:
        legs(p, w, length, leg_h, 0.05, wood, inset=0.03)
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
    p, white = Parts("toilet"), colour(rng, CERAMIC)
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
    p, white, metal = Parts("sink"), colour(rng, CERAMIC if pedestal or rng.random() < 0.4 else METAL), colour(rng, METAL)
    w, d, h = rng.uniform(0.45, 0.65), rng.uniform(0.35, 0.48), rng.uniform(0.12, 0.18)
    z0 = rng.uniform(0.68, 0.75) if pedestal else 0.0
    if pedestal:
        p.cyl((0, 0, 0), rng.uniform(0.09, 0.13), z0, white, r_top=rng.uniform(0.07, 0.1))
    basin(p, w, d, h, 0.03, z0, white)
    faucet(p, d / 2 - 0.02, z0 + h, metal)
    return p.model()


def bathtub(rng: np.random.Generator) -> Model:
    """Tub with its long side along x: built-in (panelled to the floor) or on four short feet."""
    p, white = Parts("bathtub"), colour(rng, CERAMIC)
    length, w, h, wall = rng.uniform(1.5, 1.8), rng.uniform(0.7, 0.82), rng.uniform(0.5, 0.6), rng.uniform(0.06, 0.1)
    feet = rng.uniform(0.08, 0.14) if rng.random() < 0.35 else 0.0
    if feet:
        for sx in (-1, 1):
            for sy in (-1, 1):
                p.cyl((sx * (length / 2 - 0.15), sy * (w / 2 - 0.12), 0), 0.04, feet, white, seg=THIN_SEGMENTS)
    basin(p, length, w, h - feet, wall, feet, white)
    faucet(p, w / 2 - wall / 2, h, colour(rng, METAL))
    return p.model()


# ---------------------------------------------------------------------- surfaces & storage
def table(rng: np.random.Generator, kind: str = "dining") -> Model:
    """Table top on four legs (or a round top on a pedestal). kind: dining | coffee | side."""
    p, wood = Parts("table"), colour(rng, WOOD)
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
    legs(p, w, d, h - top_t, rng.uniform(0.04, 0.07), wood, inset=rng.uniform(0.0, 0.06), roundlegs=rng.random() < 0.4)
    if kind == "coffee" and rng.random() < 0.5:    # lower shelf
        p.box((0, 0, 0.12), (w - 0.1, d - 0.1, 0.02), wood, Texture.GRAIN)
    return p.model(h, (-w / 2, -d / 2, w / 2, d / 2))


def desk(rng: np.random.Generator) -> Model:
    """Desk: a table-like top on legs, drawer pedestals or side panels, often a modesty panel."""
    p, wood = Parts("desk"), colour(rng, WOOD)
    w, d, h, top_t = rng.uniform(1.0, 1.6), rng.uniform(0.55, 0.75), rng.uniform(0.72, 0.76), rng.uniform(0.025, 0.04)
    p.box((0, 0, h - top_t / 2), (w, d, top_t), wood, Texture.GRAIN)
    variant = rng.integers(3)
    if variant == 0:
        legs(p, w, d, h - top_t, 0.05, colour(rng, WOOD + METAL), inset=0.02)
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


def counter(rng: np.random.Generator, island: bool = False) -> Model:
    """Kitchen counter run: recessed plinth, carcass with doors, stone or wood top."""
    p, body, top = Parts("counter"), colour(rng, WOOD), colour(rng, STONE)
    w = rng.uniform(1.2, 1.8) if island else rng.uniform(1.2, 2.8)
    d, h = rng.uniform(0.58, 0.64), rng.uniform(0.86, 0.92)
    top_t, plinth = rng.uniform(0.03, 0.045), rng.uniform(0.08, 0.12)
    p.box((0, 0.03, plinth / 2), (w - 0.02, d - 0.08, plinth), colour(rng, METAL[1:2] + WOOD))
    p.box((0, 0.01, (plinth + h - top_t) / 2), (w - 0.02, d - 0.04, h - top_t - plinth), body, Texture.GRAIN)
    door_fronts(p, w - 0.02, -d / 2 + 0.03, plinth, h - top_t - plinth, body, colour(rng, METAL), max(1, int(round(w / 0.55))))
    p.box((0, 0, h - top_t / 2), (w, d, top_t), top, Texture.SPECKLE if rng.random() < 0.7 else Texture.GRAIN)
    return p.model(h, (-w / 2, -d / 2 + 0.02, w / 2, d / 2 - 0.02))


def cabinet(rng: np.random.Generator, kind: str = "tall") -> Model:
    """Closed carcass with doors or drawers. kind: tall (wardrobe) | low (sideboard) | small (nightstand)."""
    p, body = Parts("cabinet"), colour(rng, WOOD)
    w, d, h = {"tall": (rng.uniform(0.8, 1.5), rng.uniform(0.45, 0.62), rng.uniform(1.7, 2.2)),
               "low": (rng.uniform(0.8, 1.8), rng.uniform(0.38, 0.5), rng.uniform(0.45, 0.8)),
               "small": (rng.uniform(0.4, 0.55), rng.uniform(0.35, 0.45), rng.uniform(0.45, 0.6))}[kind]
    leg_h = rng.uniform(0.06, 0.15) if rng.random() < 0.4 else 0.0
    if leg_h:
        legs(p, w, d, leg_h, 0.04, body, inset=0.02)
    p.box((0, 0, (leg_h + h) / 2), (w, d, h - leg_h), body, Texture.GRAIN)
    front_alb, handle = (body if rng.random() < 0.6 else colour(rng, WOOD)), colour(rng, METAL)
    if kind == "small" or rng.random() < 0.3:   # a stack of drawers
        n = int(rng.integers(2, 5))
        for k in range(n):
            dh = (h - leg_h) / n
            door_fronts(p, w, -d / 2, leg_h + k * dh, dh, front_alb, handle, 1)
    else:
        door_fronts(p, w, -d / 2, leg_h, h - leg_h, front_alb, handle, max(1, int(round(w / 0.5))))
    return p.model(h, (-w / 2 + 0.02, -d / 2 + 0.02, w / 2 - 0.02, d / 2 - 0.02))


def shelf(rng: np.random.Generator, tall: bool | None = None) -> Model:
    """Open bookcase: sides, back, boards; books on some boards."""
    p, wood = Parts("shelf"), colour(rng, WOOD)
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
    p, pot, green = Parts("plant"), colour(rng, POT), colour(rng, FOLIAGE)
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
    p, frame, screen = Parts("tv_monitor"), colour(rng, SCREEN), colour(rng, SCREEN)
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
