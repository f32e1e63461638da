"""The layout of a procedural house: room cells, their kinds and the doorways joining them.

Steps 1-3 of ``envs.house``'s recipe (see its docstring): a BSP cut of a rectangular footprint
into axis-aligned room *cells* (with an optional corridor strip), room kinds by size, and a
connected doorway graph with some open door leaves. Every function draws from the caller's
``rng`` in a fixed order, so ``generate_house`` stays a pure function of ``(seed, HouseSpec)``.
"""
from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from calnav.envs.doors import Doorway, door_zones, leaf_pose, overlap
from calnav.envs.house_spec import HouseSpec
from calnav.envs.scene import Room


@dataclass
class Cell:
    x0: float
    y0: float
    x1: float
    y1: float
    hallway: bool = False
    kind: str = ""

    @property
    def area(self) -> float:
        return (self.x1 - self.x0) * (self.y1 - self.y0)


def split_footprint(rng: np.random.Generator, spec: HouseSpec) -> list[Cell]:
    """Cells tiling a rectangular footprint with its corner at the origin (see module docstring)."""
    n_target = int(rng.integers(spec.min_rooms, spec.max_rooms + 1))
    lo, hi = spec.min_floor_area_m2 * (1 + spec.area_margin), spec.max_floor_area_m2 * (1 - spec.area_margin)
    area = float(np.clip(n_target * rng.uniform(*spec.room_area_m2), lo, hi))
    aspect = rng.uniform(*spec.footprint_aspect)
    long, short = float(np.sqrt(area * aspect)), float(np.sqrt(area / aspect))
    along_x = rng.random() < 0.5   # which world axis the footprint's long side follows
    w, h = (long, short) if along_x else (short, long)
    cells = [Cell(0.0, 0.0, w, h)]
    hall_w = rng.uniform(*spec.hallway_width_m)
    if (n_target >= spec.hallway_min_rooms and rng.random() < spec.hallway_prob
            and short >= 2 * spec.min_room_side_m + hall_w):
        c0 = rng.uniform(spec.min_room_side_m, short - spec.min_room_side_m - hall_w)  # corridor along the long axis
        c1 = c0 + hall_w
        cells = ([Cell(0, 0, w, c0), Cell(0, c0, w, c1, hallway=True), Cell(0, c1, w, h)] if along_x else
                 [Cell(0, 0, c0, h), Cell(c0, 0, c1, h, hallway=True), Cell(c1, 0, w, h)])
    while len(cells) < n_target:
        cands = [i for i, c in enumerate(cells)
                 if not c.hallway and max(c.x1 - c.x0, c.y1 - c.y0) >= 2 * spec.min_room_side_m]
        if not cands:
            break
        areas = np.array([cells[i].area for i in cands])
        c = cells.pop(cands[int(rng.choice(len(cands), p=areas / areas.sum()))])
        cut_x = (c.x1 - c.x0) >= (c.y1 - c.y0)
        a, b = (c.x0, c.x1) if cut_x else (c.y0, c.y1)
        t = float(np.clip(a + rng.uniform(*spec.split_fraction) * (b - a), a + spec.min_room_side_m, b - spec.min_room_side_m))
        cells += ([Cell(c.x0, c.y0, t, c.y1), Cell(t, c.y0, c.x1, c.y1)] if cut_x else
                  [Cell(c.x0, c.y0, c.x1, t), Cell(c.x0, t, c.x1, c.y1)])
    return cells


def interior(c: Cell, t: float) -> Room:
    """The walkable floor of a cell: inside its walls (half a wall thickness on every side)."""
    return Room(c.kind, float(c.x0 + t / 2), float(c.y0 + t / 2), float(c.x1 - t / 2), float(c.y1 - t / 2))


def assign_kinds(cells: list[Cell], rng: np.random.Generator, spec: HouseSpec) -> None:
    """Living room to the largest cell, bathrooms to the smallest; of the others, bedrooms
    (which must fit a bed) get the cells with the longest short side, the rest is shuffled."""
    for c in cells:
        c.kind = "hallway" if c.hallway else ""
    rooms = sorted((i for i, c in enumerate(cells) if not c.hallway), key=lambda i: -cells[i].area)
    kinds = list(spec.kind_sequence[:len(rooms)])
    kinds += ["bedroom"] * (len(rooms) - len(kinds))
    n_bath = kinds.count("bathroom")
    first = [kinds.pop(kinds.index("living_room"))]
    middle = [k for k in kinds if k not in ("bathroom", "bedroom")]
    rng.shuffle(middle)
    middle = ["bedroom"] * kinds.count("bedroom") + middle
    n_mid = len(middle)
    mid_cells = sorted(rooms[1:1 + n_mid], key=lambda i: -min(cells[i].x1 - cells[i].x0, cells[i].y1 - cells[i].y0))
    for i, kind in zip([rooms[0]] + mid_cells + rooms[1 + n_mid:], first + middle + ["bathroom"] * n_bath):
        cells[i].kind = kind


def connect(cells: list[Cell], rng: np.random.Generator, spec: HouseSpec) -> list[Doorway] | None:
    """Doorways forming a connected room graph, or None if some room cannot get a door."""
    t, need = spec.wall_thickness_m, spec.door_width_m[1] + 2 * (spec.wall_thickness_m / 2 + spec.door_jamb_m)
    edges = []
    for i, ci in enumerate(cells):
        for j in range(i + 1, len(cells)):
            cj = cells[j]
            for axis, (a0, a1, b0, b1), (ilo, ihi, jlo, jhi) in (
                    ("x", (ci.x0, ci.x1, cj.x0, cj.x1), (ci.y0, ci.y1, cj.y0, cj.y1)),
                    ("y", (ci.y0, ci.y1, cj.y0, cj.y1), (ci.x0, ci.x1, cj.x0, cj.x1))):
                coord = a1 if np.isclose(a1, b0) else a0 if np.isclose(a0, b1) else None
                lo, hi = max(ilo, jlo), min(ihi, jhi)
                if coord is not None and hi - lo >= need:
                    edges.append((i, j, axis, coord, lo, hi))
    # Randomised Prim: corridor edges first, bathroom edges last (bathrooms end up as leaves).
    keys = [rng.random() - any(cells[k].hallway for k in e[:2]) + any(cells[k].kind == "bathroom" for k in e[:2])
            for e in edges]
    start = next((i for i, c in enumerate(cells) if c.hallway), int(np.argmax([c.area for c in cells])))
    tree, chosen = {start}, []
    while len(tree) < len(cells):
        frontier = [k for k, e in enumerate(edges) if (e[0] in tree) != (e[1] in tree)]
        if not frontier:
            return None
        k = min(frontier, key=lambda k: keys[k])
        chosen.append(k)
        tree.update(edges[k][:2])
    chosen += [k for k, e in enumerate(edges) if k not in chosen and rng.random() < spec.extra_door_prob
               and all(cells[i].kind != "bathroom" for i in e[:2])]
    doors = []
    for k in chosen:
        i, j, axis, coord, lo, hi = edges[k]
        width, margin = rng.uniform(*spec.door_width_m), t / 2 + spec.door_jamb_m
        lo_mid, hi_mid = lo + margin + width / 2, hi - margin - width / 2
        mid = ((lo_mid, hi_mid)[rng.integers(2)] if rng.random() < spec.door_corner_prob  # near a corner frees wall space
               else rng.uniform(lo_mid, hi_mid))
        doors.append(Doorway(i, j, axis, float(coord), mid - width / 2, mid + width / 2,
                             rng.uniform(*spec.door_height_m), open_deg=rng.uniform(*spec.door_open_deg)))
    choose_leaves(doors, cells, rng, spec)
    return doors


def choose_leaves(doors: list[Doorway], cells: list[Cell], rng: np.random.Generator, spec: HouseSpec) -> None:
    """Hang open leaves in some doorways (at least one per house), each swung into a room where it
    stays inside the room, off the other doorways' clear zones and off other leaves."""
    taken: list[np.ndarray] = []

    def try_leaf(d: Doorway) -> bool:
        for k in rng.permutation(4):   # (room, hinge side) options in random order
            d.leaf_room, d.hinge_lo = (d.a, d.b)[k // 2], bool(k % 2)
            rect, room = leaf_pose(d, cells, spec)[-1], interior(cells[d.leaf_room], spec.wall_thickness_m)
            inside = room.xmin <= rect[0] and rect[2] <= room.xmax and room.ymin <= rect[1] and rect[3] <= room.ymax
            # across the room from the leaf, a walkable gap must remain (narrow hallways)
            across = (room.xmax - rect[2], rect[0] - room.xmin) if d.axis == "x" else (room.ymax - rect[3], rect[1] - room.ymin)
            inside = inside and max(across) >= spec.walk_gap_m
            zones = door_zones([o for o in doors if o is not d], cells, d.leaf_room, spec)
            grown = rect + spec.walk_gap_m * np.array([-1, -1, 1, 1])   # two leaves could seal a corner
            if inside and not any(overlap(rect, z) for z in zones) and not any(overlap(grown, o) for o in taken):
                taken.append(rect)
                return True
        d.leaf_room = None
        return False

    wanted = [rng.random() < spec.door_leaf_prob for _ in doors]
    placed = [try_leaf(d) for d, w in zip(doors, wanted) if w]
    if not any(placed):   # the house must show the door class
        any(try_leaf(d) for d in doors)
