"""Procedural houses: room layout, walls with doorways, floors, ceilings and furniture.

``generate_house(seed)`` is a pure function of ``(seed, HouseSpec)``: all randomness comes from
one ``np.random.default_rng(seed)``. Layout:

1. A rectangular footprint (total area ~ rooms x per-room area) is cut by a recursive BSP
   into axis-aligned room *cells*; bigger houses may first get a corridor strip (a hallway)
   along their long axis. Walls are centred on cell boundaries, so a room's walkable
   interior (``Scene.rooms``) is its cell shrunk by half a wall thickness on every side.
2. Room kinds go by size: living room = largest cell, bathrooms = smallest, bedrooms (which
   must fit a bed) the cells with the longest short side, other kinds shuffled.
3. Doorways join rooms sharing a long enough wall: a random spanning tree (corridor edges
   first, bathroom edges last, so bathrooms tend to be leaves) plus a few extra doors. Some
   doorways carry an open door leaf (class ``door``) swung ~90 degrees into one room (its
   geometry, and the zones in front of doorways kept free, in ``envs.doors``).
4. Each room builds its own half-thickness wall slabs (so its walls have its own paint),
   holes where doorways are, a lintel above each; a floor (+z face) and a ceiling (-z face)
   cover the cell, so doorway thresholds have floor and every view ray hits something.
5. Furniture from ``envs.furnish.ROOM_RECIPES`` is placed against walls or free,
   with rectangle checks that keep rooms traversable (see ``fits``).

Scene.meta holds the seed, the spec, the doorways and one record per object instance.
"""
from __future__ import annotations

import copy
import dataclasses
from dataclasses import asdict

import numpy as np

from calnav.envs.doors import Doorway, add_door_leaf, door_zones, leaf_pose
from calnav.envs.furniture_parts import colour
from calnav.envs.furnish import ROOM_RECIPES, emit_group, find_pose
from calnav.envs.house_layout import Cell, assign_kinds, connect, interior, split_footprint
from calnav.envs.house_spec import GENERATOR_VERSION, MAX_STOREYS, ROOM_KINDS, HouseSpec  # noqa: F401 (importable here)
from calnav.envs.primitives import MeshBuilder
from calnav.envs.scene import Room, Scene, Texture
from calnav.envs.stairs import StairSpec, Staircase, build_staircase, place_staircase, rect_minus

# Surface styles per room kind: (palette, texture) choices for floors and walls.
_FLOORS = {
    "bathroom": (((225, 225, 220), (180, 190, 200), (120, 120, 125)), (Texture.CHECKER, Texture.SPECKLE)),
    "kitchen": (((200, 195, 185), (150, 110, 75), (90, 90, 95)), (Texture.CHECKER, Texture.GRAIN)),
    "bedroom": (((160, 120, 85), (150, 140, 130), (110, 100, 120)), (Texture.SPECKLE, Texture.GRAIN)),
    "living_room": (((170, 125, 80), (120, 85, 55), (160, 150, 140)), (Texture.GRAIN, Texture.SPECKLE)),
    "office": (((110, 110, 115), (160, 120, 85), (90, 100, 110)), (Texture.SPECKLE, Texture.GRAIN)),
    "hallway": (((170, 125, 80), (190, 185, 175)), (Texture.GRAIN, Texture.CHECKER)),
}
_WALL_PAINT = ((236, 232, 222), (222, 210, 190), (200, 215, 225), (205, 220, 200), (210, 210, 210), (235, 220, 215))
_CEILING = ((240, 240, 236), (232, 232, 228))
# Room kinds of a house with storeys (``assign_kinds`` reads them as it reads
# ``HouseSpec.kind_sequence``): living rooms, kitchens and offices downstairs, bedrooms
# upstairs, a bathroom on every storey, so that some goal categories (sofa, bed) are on one
# storey only and their episodes cross storeys. The stair room upstairs is a landing hall.
GROUND_KINDS = ("living_room", "bathroom", "kitchen", "office", "kitchen", "office", "bathroom", "office",
                "living_room", "office")
UPPER_KINDS = ("living_room", "bathroom", "bedroom", "bedroom", "office", "bedroom", "bathroom", "bedroom",
               "office", "bedroom")
_STAIR_WOOD = ((150, 110, 75), (120, 85, 55), (170, 125, 80))


# --------------------------------------------------------------------------- structure
def _slab(b: MeshBuilder, c: Cell, z: float, t: float, holes, cls: str, inst: int, albedo, texture, faces: str) -> None:
    """The cell's floor or ceiling slab centred at height ``z``, around ``holes`` ((4,) world
    rects: stair openings, and the floor under a staircase, which would otherwise be open
    floor inside the steps' boxes to the navmesh; None: one box, as a single-storey house has)."""
    if not holes:
        b.add_box(((c.x0 + c.x1) / 2, (c.y0 + c.y1) / 2, z), (c.x1 - c.x0, c.y1 - c.y0, t), cls, inst, albedo, texture,
                  faces=faces)
        return
    pieces = [np.array([c.x0, c.y0, c.x1, c.y1])]
    for hole in holes:
        pieces = [p for q in pieces for p in rect_minus(q, hole)]
    for r in pieces:
        b.add_box(((r[0] + r[2]) / 2, (r[1] + r[3]) / 2, z), (r[2] - r[0], r[3] - r[1], t), cls, inst, albedo, texture,
                  faces=faces)


def _build_room_shell(b: MeshBuilder, ci: int, cells: list[Cell], doors: list[Doorway], footprint, wall_h: float,
                      rng: np.random.Generator, spec: HouseSpec, floor_holes=None, ceiling_holes=None) -> None:
    """Floor, ceiling and this room's own wall slabs (with doorway holes and lintels); the
    floor and ceiling leave out ``floor_holes`` / ``ceiling_holes`` (lists of (4,) world rects
    in this cell: stair openings and footprints; None for none)."""
    c, t = cells[ci], spec.wall_thickness_m
    floor_pal, floor_tex = _FLOORS[c.kind]
    _slab(b, c, -t / 2, t, floor_holes, "floor", b.new_instance(), colour(rng, floor_pal),
          floor_tex[rng.integers(len(floor_tex))], faces="+z")
    _slab(b, c, wall_h + t / 2, t, ceiling_holes, "ceiling", b.new_instance(), colour(rng, _CEILING), Texture.PLAIN,
          faces="-z")
    wall_inst, paint = b.new_instance(), colour(rng, _WALL_PAINT)
    patterned = rng.random() < spec.patterned_wall_prob   # tiles in wet rooms, wallpaper elsewhere
    wall_tex = (Texture.CHECKER if c.kind in ("bathroom", "kitchen") else Texture.STRIPES) if patterned else Texture.PLAIN
    fx0, fy0, fx1, fy1 = footprint
    ext = {"-x": np.isclose(c.x0, fx0), "+x": np.isclose(c.x1, fx1), "-y": np.isclose(c.y0, fy0), "+y": np.isclose(c.y1, fy1)}
    out = {k: t / 2 if v else 0.0 for k, v in ext.items()}   # exterior slabs also extend outward
    sides = {  # side -> (wall axis, plane coord, normal extent (n0, n1), along extent (u0, u1))
        "-x": ("x", c.x0, (c.x0 - out["-x"], c.x0 + t / 2), (c.y0 + t / 2, c.y1 - t / 2)),
        "+x": ("x", c.x1, (c.x1 - t / 2, c.x1 + out["+x"]), (c.y0 + t / 2, c.y1 - t / 2)),
        "-y": ("y", c.y0, (c.y0 - out["-y"], c.y0 + t / 2), (c.x0 - out["-x"], c.x1 + out["+x"])),
        "+y": ("y", c.y1, (c.y1 - t / 2, c.y1 + out["+y"]), (c.x0 - out["-x"], c.x1 + out["+x"])),
    }
    for axis, coord, (n0, n1), (u0, u1) in sides.values():
        holes = sorted((d.lo, d.hi, d.height) for d in doors
                       if ci in (d.a, d.b) and d.axis == axis and np.isclose(d.coord, coord))
        pieces, u = [], u0
        for lo, hi, dh in holes:
            pieces += [(u, lo, 0.0, wall_h), (lo, hi, dh, wall_h)]   # wall up to the hole, lintel over it
            u = hi
        pieces.append((u, u1, 0.0, wall_h))
        for ua, ub, za, zb in pieces:
            if ub - ua < 1e-6:   # a doorway flush with the slab's end leaves an empty piece
                continue
            centre_n, centre_u = (n0 + n1) / 2, (ua + ub) / 2
            center = (centre_n, centre_u, (za + zb) / 2) if axis == "x" else (centre_u, centre_n, (za + zb) / 2)
            size = (n1 - n0, ub - ua, zb - za) if axis == "x" else (ub - ua, n1 - n0, zb - za)
            b.add_box(center, size, "wall", wall_inst, paint, wall_tex, faces="-z -y +y +x -x" if za > 0 else "-y +y +x -x")


def _furnish(b: MeshBuilder, rooms: list[Room], cells: list[Cell], doors: list[Doorway], rng: np.random.Generator,
             spec: HouseSpec, blocked: dict[int, tuple[list, list]] | None = None) -> list[dict]:
    """Place each room's recipe items in order; returns one meta record per object instance.
    ``blocked``: room index -> (obstacle rects, zone rects) of its stairs (None: no stairs)."""
    objects = []
    for ri, room in enumerate(rooms):
        # Door leaves are obstacles (kept >= walk gap away); the rest of a doorway's zone stays free.
        obstacles = [leaf_pose(d, cells, spec)[-1] for d in doors if d.leaf_room == ri]
        zones = door_zones(doors, cells, ri, spec)
        if blocked and ri in blocked:
            obstacles, zones = obstacles + list(blocked[ri][0]), zones + list(blocked[ri][1])
        for item in ROOM_RECIPES[room.kind]:
            if rng.random() >= item.prob:
                continue
            samples = spec.group_samples + (spec.required_samples if item.required else 0)
            for _ in range(int(rng.integers(item.count[0], item.count[1] + 1))):
                for sample in range(samples):
                    harder = sample >= spec.group_samples   # required items only
                    group = (item.fallback or item.make)(rng) if harder else item.make(rng)
                    pose = find_pose(group, room, obstacles, zones, item.mode, rng, spec, exhaustive=harder)
                    if pose is not None:
                        obstacles.append(pose[0])
                        objects += emit_group(b, group, pose[0], pose[1], ri)
                        break
    return objects


# ------------------------------------------------------------------------------ storeys
def _stair_keep_clear(ci: int, cells: list[Cell], doors: list[Doorway], spec: HouseSpec) -> list[np.ndarray]:
    """Rects of room ``ci`` a staircase must stay off: its doorway zones and door leaves (every
    storey has the same doorways)."""
    return door_zones(doors, cells, ci, spec) + [leaf_pose(d, cells, spec)[-1] for d in doors if d.leaf_room == ci]


def _place_stairs(cells: list[Cell], doors: list[Doorway], wall_h: float, storeys: int, rng: np.random.Generator,
                  spec: HouseSpec, stair_spec: StairSpec) -> list[tuple[int, Staircase]] | None:
    """(cell index, staircase) from each storey to the next, larger rooms tried first, each
    off the previous staircase (whose opening and arrival lie on the storey it starts from);
    None when some storey has no room for one (the caller draws another layout)."""
    t = spec.wall_thickness_m
    storey_h = wall_h + t
    out: list[tuple[int, Staircase]] = []
    for k in range(storeys - 1):
        placed = None
        for ci in sorted(range(len(cells)), key=lambda i: -cells[i].area):
            keep = _stair_keep_clear(ci, cells, doors, spec)
            if out and out[-1][0] == ci:
                prev = out[-1][1]
                grown = prev.rect + spec.walk_gap_m * np.array([-1, -1, 1, 1])
                keep = keep + [grown, prev.entry(stair_spec.entry_clearance_m)]
            st = place_staircase(interior(cells[ci], t), k, k * storey_h, storey_h, keep, rng, stair_spec)
            if st is not None:
                placed = (ci, st)
                break
        if placed is None:
            return None
        out.append(placed)
    return out


def _storey_cells(cells: list[Cell], storey: int, stairs: list[tuple[int, Staircase]], rng: np.random.Generator,
                  spec: HouseSpec) -> list[Cell]:
    """The cells of ``storey`` (same walls as the ground floor, its own room kinds): bedrooms
    and a bathroom upstairs (``UPPER_KINDS``), a landing hall where a staircase arrives."""
    if storey == 0:
        return cells
    out = [copy.copy(c) for c in cells]   # (a shallow copy each: their kinds change, the walls stay shared)
    assign_kinds(out, rng, dataclasses.replace(spec, kind_sequence=UPPER_KINDS))
    for ci, st in stairs:
        if st.lower == storey - 1:
            out[ci].kind = "hallway"
    for c in out:
        if c.kind == "living_room":
            c.kind = "bedroom"
    return out


def _stair_blocks(storey: int, stairs: list[tuple[int, Staircase]], stair_spec: StairSpec) -> dict[int, tuple[list, list]]:
    """Room index -> (obstacles, zones) that the furniture of ``storey`` keeps off: a staircase
    starting here (its body, and its entry zone free), one arriving here (its opening and
    railings, and its arrival zone free)."""
    out: dict[int, tuple[list, list]] = {}
    for ci, st in stairs:
        if st.lower in (storey, storey - 1):
            rail = stair_spec.railing_m * np.array([-1, -1, 1, 1])
            obstacles, zones = out.setdefault(ci, ([], []))
            obstacles.append(st.rect + rail)
            zones.append(st.entry(stair_spec.entry_clearance_m))
    return out


def _build_storeys(b: MeshBuilder, cells: list[Cell], doors: list[Doorway], stairs: list[tuple[int, Staircase]],
                   footprint, wall_h: float, storeys: int, rng: np.random.Generator, spec: HouseSpec,
                   stair_spec: StairSpec) -> tuple[list[dict], list[list[str]]]:
    """Every storey's shells, door leaves and furniture, each built at floor level and lifted
    onto its slab, then the staircases: (object records with their ``storey``, room kinds per
    storey)."""
    t = spec.wall_thickness_m
    objects, kinds = [], []
    for s in range(storeys):
        mark = b.mark()
        cells_s = _storey_cells(cells, s, stairs, rng, spec)
        # the floor is open over the stairs arriving and under those leaving; the ceiling over them
        floor_holes = {ci: [st.rect for cj, st in stairs if cj == ci and st.lower in (s - 1, s)] for ci in range(len(cells))}
        ceiling_holes = {ci: [st.rect for cj, st in stairs if cj == ci and st.lower == s] for ci in range(len(cells))}
        for ci in range(len(cells_s)):
            _build_room_shell(b, ci, cells_s, doors, footprint, wall_h, rng, spec,
                              floor_holes=floor_holes[ci], ceiling_holes=ceiling_holes[ci])
        for d in doors:
            if d.leaf_room is not None:
                add_door_leaf(b, d, cells_s, rng, spec)
        rooms = [interior(c, t) for c in cells_s]
        records = _furnish(b, rooms, cells_s, doors, rng, spec, blocked=_stair_blocks(s, stairs, stair_spec))
        dz = s * (wall_h + t)
        b.lift(mark, dz)
        for r in records:
            r["storey"] = s
            r["bbox"] = [round(v + (dz if i % 3 == 2 else 0.0), 4) for i, v in enumerate(r["bbox"])]
        objects += records
        kinds.append([c.kind for c in cells_s])
    for _, st in stairs:
        build_staircase(b, st, colour(rng, _STAIR_WOOD), colour(rng, _WALL_PAINT), stair_spec)
    return objects, kinds


# ---------------------------------------------------------------------------------- api
def generate_house(seed: int, spec: HouseSpec | None = None, storeys: int = 1,
                   stair_spec: StairSpec | None = None) -> Scene:
    """A furnished procedural house, a pure function of ``(seed, spec, storeys, stair_spec)``;
    see the module docstring. ``storeys`` 1 builds the single-storey house exactly as before
    storeys existed (the same random draws, the same mesh); above 1, storeys of the same walls
    stack on floor slabs, joined by staircases (``envs.stairs``)."""
    spec = spec or HouseSpec()
    stair_spec = stair_spec or StairSpec()
    if not 1 <= int(storeys) <= MAX_STOREYS:
        raise ValueError(f"storeys must be in [1, {MAX_STOREYS}], got {storeys}")
    rng = np.random.default_rng(seed)
    t = spec.wall_thickness_m
    kind_spec = spec if storeys == 1 else dataclasses.replace(spec, kind_sequence=GROUND_KINDS)
    stairs: list[tuple[int, Staircase]] = []
    for _ in range(spec.max_layout_tries):
        cells = split_footprint(rng, spec)
        area = sum((c.x1 - c.x0 - t) * (c.y1 - c.y0 - t) for c in cells)
        if not (spec.min_rooms <= len(cells) <= spec.max_rooms
                and spec.min_floor_area_m2 <= area <= spec.max_floor_area_m2):
            continue
        assign_kinds(cells, rng, kind_spec)
        doors = connect(cells, rng, spec)
        if doors is None:
            continue
        if storeys == 1:
            break
        wall_h = float(rng.uniform(*spec.wall_height_m))
        placed = _place_stairs(cells, doors, wall_h, storeys, rng, spec, stair_spec)
        if placed is not None:
            stairs = placed
            break
    else:
        raise RuntimeError(f"seed {seed}: no valid layout in {spec.max_layout_tries} tries; loosen the HouseSpec")
    if storeys == 1:
        wall_h = float(rng.uniform(*spec.wall_height_m))
    footprint = (min(c.x0 for c in cells), min(c.y0 for c in cells), max(c.x1 for c in cells), max(c.y1 for c in cells))
    b = MeshBuilder(f"house_{seed}")
    rooms = [interior(c, t) for c in cells]
    if storeys == 1:
        for ci in range(len(cells)):
            _build_room_shell(b, ci, cells, doors, footprint, wall_h, rng, spec)
        for d in doors:
            if d.leaf_room is not None:
                add_door_leaf(b, d, cells, rng, spec)
        b.rooms = rooms
        objects = _furnish(b, rooms, cells, doors, rng, spec)
    else:
        b.rooms = rooms
        objects, kinds = _build_storeys(b, cells, doors, stairs, footprint, wall_h, storeys, rng, spec, stair_spec)
    b.meta = {
        "generator": "envs.house", "generator_version": GENERATOR_VERSION, "seed": int(seed),
        "spec_digest": spec.digest(), "spec": asdict(spec), "wall_height_m": wall_h, "floor_area_m2": float(area),
        "doors": [{"rooms": [d.a, d.b], "axis": d.axis, "coord": float(d.coord), "span": [float(d.lo), float(d.hi)],
                   "height": float(d.height), "leaf_room": d.leaf_room} for d in doors],
        "objects": objects,
    }
    if storeys > 1:
        storey_h = wall_h + t
        b.meta.update(storeys=int(storeys), storey_height_m=storey_h,
                      storey_z=[s * storey_h for s in range(storeys)], room_kinds=kinds,
                      stairs=[st.record() for _, st in stairs], stair_spec=stair_spec.digest_items())
    return b.build()
