"""Furnishing rooms: furniture groups, room recipes and free-space placement.

A ``Group`` is one placement unit (bed + nightstands, desk + chair + monitor, table + chairs,
...): members are ``envs.furniture`` models with an offset and a yaw in the group frame, whose
front faces -y and back (the wall side) is +y; every member becomes one object instance.
Objects that stand on another (a TV on a cabinet, a sink on a counter) name their support.
``ROOM_RECIPES`` lists per room kind what to build, how likely, how many and where (against a
wall or free-standing). ``find_pose`` places a group in a room so that the room stays
traversable (see ``fits``); ``emit_group`` adds it to a mesh. Lengths are metres, angles radians.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from calnav.envs.furniture import (bathtub, bed, cabinet, chair, counter, desk, plant, shelf, sink, sofa, stool, table, toilet, tv)
from calnav.envs.furniture_parts import Model
from calnav.envs.primitives import MeshBuilder
from calnav.envs.scene import Room

TOP_TRIES = 10   # positions tried for an object on a support surface


class PlacementSpec(Protocol):
    """The placement constants ``find_pose`` reads. ``envs.house.HouseSpec`` provides them
    (documented there); a Protocol, so that this module does not import ``envs.house``
    (which imports it)."""

    @property
    def walk_gap_m(self) -> float: ...

    @property
    def placement_tries(self) -> int: ...

    @property
    def any_free_prob(self) -> float: ...

    @property
    def corner_prob(self) -> float: ...

    @property
    def scan_step_m(self) -> float: ...


@dataclass
class Member:
    """A model placed in a group frame: offset (x, y, z) metres and yaw radians (about +z)."""

    model: Model
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw: float = 0.0
    support: int | None = None   # index of the member it stands on; None: the floor (or wall)


@dataclass
class Group:
    """A placement unit: members in a frame whose front faces -y and back (wall side) is +y."""

    members: list[Member] = field(default_factory=list)
    on_top: dict[int, list[tuple[float, float, float, float]]] = field(default_factory=dict)  # used top areas per base

    def footprint(self) -> np.ndarray:
        """(x0, y0, x1, y1) axis-aligned bounds of all members in the group frame, metres."""
        boxes = []
        for m in self.members:
            w, d = m.model.size[:2]
            c, s = abs(np.cos(m.yaw)), abs(np.sin(m.yaw))
            hw, hd = (c * w + s * d) / 2, (s * w + c * d) / 2
            boxes.append((m.offset[0] - hw, m.offset[1] - hd, m.offset[0] + hw, m.offset[1] + hd))
        b = np.array(boxes)
        return np.array([b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()])


def _single(model: Model) -> Group:
    return Group([Member(model)])


def _on_top(group: Group, base_idx: int, model: Model, rng: np.random.Generator, back: bool = True) -> bool:
    """Put ``model`` on member ``base_idx``'s support surface (at its back edge if ``back``), clear
    of what already stands there; False if it does not fit."""
    base = group.members[base_idx]
    if base.model.support_rect is None:
        return False
    x0, y0, x1, y1 = base.model.support_rect
    w, d = model.size[:2]
    if w > x1 - x0 or d > y1 - y0:
        return False
    used = group.on_top.setdefault(base_idx, [])
    for _ in range(TOP_TRIES):
        x = rng.uniform(x0 + w / 2, x1 - w / 2)
        y = y1 - d / 2 if back else rng.uniform(y0 + d / 2, y1 - d / 2)
        if not any(x - w / 2 < u1 and u0 < x + w / 2 and y - d / 2 < v1 and v0 < y + d / 2 for u0, v0, u1, v1 in used):
            break
    else:
        return False
    used.append((x - w / 2, y - d / 2, x + w / 2, y + d / 2))
    ox, oy, oz = base.offset
    c, s = np.cos(base.yaw), np.sin(base.yaw)
    group.members.append(Member(model, (ox + c * x - s * y, oy + s * x + c * y, oz + base.model.support_z), base.yaw, base_idx))
    return True


def _in_front(group: Group, model: Model, gap: float, yaw: float = np.pi) -> None:
    """Put ``model`` in front (-y) of member 0, ``gap`` metres away, facing it by default."""
    d0, d = group.members[0].model.size[1], model.size[1]
    group.members.append(Member(model, (0.0, -(d0 / 2 + gap + d / 2), 0.0), yaw))


Rng = np.random.Generator
CHAIR_GAP_M = 0.08   # gap between a dining table's edge and its chairs, metres


def bed_group(rng: Rng) -> Group:
    """A bed, headboard to the wall, with a nightstand (a small cabinet) on either side sometimes."""
    b = bed(rng)
    g = _single(b)
    for sx in (-1, 1):
        if rng.random() < 0.6:
            ns = cabinet(rng, "small")
            g.members.append(Member(ns, (sx * (b.size[0] + ns.size[0]) / 2, (b.size[1] - ns.size[1]) / 2, 0.0)))
            if rng.random() < 0.15:
                _on_top(g, len(g.members) - 1, plant(rng, tabletop=True), rng, back=False)
    return g


def desk_group(rng: Rng, monitor_prob: float = 0.85) -> Group:
    """A desk against the wall with a monitor (``monitor_prob``), a small plant sometimes and
    usually a chair in front of it, facing it."""
    g = _single(desk(rng))
    if rng.random() < monitor_prob:
        _on_top(g, 0, tv(rng, small=True), rng)
    if rng.random() < 0.2:
        _on_top(g, 0, plant(rng, tabletop=True), rng, back=False)
    if rng.random() < 0.9:
        _in_front(g, chair(rng), rng.uniform(0.05, 0.2))
    return g


def sofa_group(rng: Rng) -> Group:
    """A sofa against the wall, often with a coffee table (and maybe a plant on it) in front."""
    g = _single(sofa(rng))
    if rng.random() < 0.6:
        _in_front(g, table(rng, "coffee"), rng.uniform(0.35, 0.5), yaw=0.0)
        if rng.random() < 0.25:
            _on_top(g, 1, plant(rng, tabletop=True), rng, back=False)
    return g


def tv_group(rng: Rng) -> Group:
    """A TV on a low cabinet or side table; sometimes wall-mounted (offset z > 0, no support),
    alone or above a low cabinet."""
    base = cabinet(rng, "low") if rng.random() < 0.7 else table(rng, "side")
    if rng.random() < 0.25:
        screen, mount_z = tv(rng, wall=True), rng.uniform(1.0, 1.3)
        if rng.random() < 0.4:
            return Group([Member(screen, (0.0, 0.0, mount_z))])
        back_y = (base.size[1] - screen.size[1]) / 2   # flush with the cabinet's back, i.e. the wall
        return Group([Member(base), Member(screen, (0.0, back_y, max(base.size[2] + 0.2, mount_z)))])
    g = _single(base)
    if not _on_top(g, 0, tv(rng), rng):
        _on_top(g, 0, tv(rng, small=True), rng)
    return g


def dining_group(rng: Rng, max_chairs: int = 6) -> Group:
    """A dining table with 1-2 chairs on each long side (each facing it), a plant sometimes."""
    t = table(rng, "dining")
    g = _single(t)
    w, d = t.size[:2]
    per_side = 2 if w > 1.3 else 1
    for side in (-1, 1):   # chairs at -y face +y (yaw pi), chairs at +y face -y (yaw 0)
        for k in range(per_side):
            c = chair(rng)
            if rng.random() < 0.85 and len(g.members) <= max_chairs:
                x = (k - (per_side - 1) / 2) * w / per_side
                g.members.append(Member(c, (x, side * (d / 2 + CHAIR_GAP_M + c.size[1] / 2), 0.0), np.pi if side < 0 else 0.0))
    if len(g.members) == 1:   # a dining table always has a chair
        _in_front(g, chair(rng), CHAIR_GAP_M)
    if rng.random() < 0.2:
        _on_top(g, 0, plant(rng, tabletop=True), rng, back=False)
    return g


def counter_group(rng: Rng, with_sink: bool = True) -> Group:
    """A kitchen counter run against the wall, with a sink on it (``with_sink``), a plant sometimes."""
    g = _single(counter(rng))
    if with_sink:
        _on_top(g, 0, sink(rng, pedestal=False), rng)
    if rng.random() < 0.2:
        _on_top(g, 0, plant(rng, tabletop=True), rng)
    return g


def island_group(rng: Rng) -> Group:
    """A free-standing kitchen island with 2-3 bar stools along its front."""
    island = counter(rng, island=True)
    g = _single(island)
    w, n = island.size[0], int(rng.integers(2, 4))
    for k in range(n):
        s = stool(rng, bar=True)
        g.members.append(Member(s, ((k - (n - 1) / 2) * w / n, -(island.size[1] / 2 + 0.05 + s.size[1] / 2), 0.0)))
    return g


def bathroom_sink_group(rng: Rng) -> Group:
    """A pedestal sink, or a basin on a vanity unit (a low cabinet)."""
    if rng.random() < 0.5:
        return _single(sink(rng, pedestal=True))
    g = _single(cabinet(rng, "low"))
    if not _on_top(g, 0, sink(rng, pedestal=False), rng):
        return _single(sink(rng, pedestal=True))
    return g


def _one(make: Callable[..., Model], *args, **kwargs) -> Callable[[np.random.Generator], Group]:
    """A builder of a one-model group: ``_one(cabinet, "tall")(rng)``."""
    return lambda rng: _single(make(rng, *args, **kwargs))


@dataclass(frozen=True)
class RecipeItem:
    """One line of a room recipe: build ``make(rng)`` with probability ``prob``, ``count``
    (min, max) times.

    mode: "wall" (back flush to a wall), "free" (>= walk gap from all walls) or "any".
    required: when random placement fails, keep sampling (from ``fallback``, a smaller
    variant, if given) and scan every wall position exhaustively.
    """

    make: Callable[[np.random.Generator], Group]
    prob: float
    count: tuple[int, int] = (1, 1)
    mode: str = "wall"
    required: bool = False
    fallback: Callable[[np.random.Generator], Group] | None = None


_I = RecipeItem
ROOM_RECIPES: dict[str, tuple[RecipeItem, ...]] = {
    "bathroom": (
        _I(_one(toilet), 1.0, required=True), _I(bathroom_sink_group, 0.9), _I(_one(bathtub), 0.6),
        _I(_one(cabinet, "small"), 0.4), _I(_one(shelf, tall=False), 0.15), _I(_one(plant), 0.2, mode="any")),
    "bedroom": (
        _I(bed_group, 1.0, required=True, fallback=_one(bed)), _I(_one(cabinet, "tall"), 0.7),
        _I(lambda r: desk_group(r, monitor_prob=0.35), 0.3), _I(tv_group, 0.3), _I(_one(shelf), 0.4),
        _I(_one(plant), 0.5, (1, 2), mode="any"), _I(lambda r: _single(chair(r, armchair=r.random() < 0.5)), 0.4, mode="any")),
    "living_room": (
        _I(sofa_group, 0.9, fallback=_one(sofa)), _I(tv_group, 0.85), _I(dining_group, 0.4, mode="free"),
        _I(_one(chair, armchair=True), 0.6, (1, 2), mode="any"), _I(_one(shelf), 0.5, (1, 2)),
        _I(_one(plant), 0.8, (1, 3), mode="any"), _I(_one(cabinet, "low"), 0.3), _I(_one(table, "side"), 0.3, mode="any")),
    "kitchen": (
        _I(counter_group, 1.0, required=True), _I(lambda r: counter_group(r, with_sink=False), 0.4),
        _I(island_group, 0.25, mode="free"), _I(lambda r: dining_group(r, max_chairs=4), 0.6, mode="free"),
        _I(lambda r: _single(stool(r, bar=r.random() < 0.5)), 0.4, (1, 2), mode="any"),
        _I(_one(cabinet, "tall"), 0.4), _I(_one(plant), 0.3, mode="any")),
    "office": (
        _I(desk_group, 1.0, required=True), _I(_one(shelf), 0.7, (1, 2)), _I(_one(cabinet), 0.4),
        _I(_one(plant), 0.6, (1, 2), mode="any"), _I(_one(chair), 0.3, mode="any"), _I(_one(stool), 0.1, mode="any")),
    "hallway": (
        _I(_one(plant), 0.5, (1, 2)), _I(_one(cabinet, "low"), 0.4), _I(_one(shelf, tall=False), 0.3),
        _I(_one(stool), 0.1)),
}


# --------------------------------------------------------------------------- placement
def fits(rect: np.ndarray, room: Room, obstacles: list[np.ndarray], zones: list[np.ndarray], gap: float) -> bool:
    """Whether a footprint keeps the room traversable.

    It must lie inside the room; against each wall it is either flush or >= ``gap`` away, and
    never flush with two opposite walls (it would cut the room in two); it stays >= ``gap``
    from every placed footprint and out of doorway zones. With every obstacle an island or a
    wall peninsula >= ``gap`` apart, the free floor stays one connected region.
    """
    eps = 1e-6
    x0, y0, x1, y1 = rect
    for g_lo, g_hi in ((x0 - room.xmin, room.xmax - x1), (y0 - room.ymin, room.ymax - y1)):
        if g_lo < -eps or g_hi < -eps or (g_lo < eps and g_hi < eps):
            return False
        if eps <= g_lo < gap or eps <= g_hi < gap:
            return False
    for o in obstacles:
        if x0 < o[2] + gap and o[0] < x1 + gap and y0 < o[3] + gap and o[1] < y1 + gap:
            return False
    return not any(x0 < z[2] and z[0] < x1 and y0 < z[3] and z[1] < y1 for z in zones)


def wall_poses(room: Room, w: float, d: float, side: int, us) -> list[tuple[np.ndarray, float]]:
    """Footprints (x0, y0, x1, y1) of a w x d unit with its back on wall ``side`` (0:+y 1:-y 2:+x 3:-x)
    centred at along-wall positions ``us``, and the yaw that turns its back to the wall."""
    r = room
    out = []
    for u in us:
        out.append(((np.array([u - w / 2, r.ymax - d, u + w / 2, r.ymax]), 0.0),
                    (np.array([u - w / 2, r.ymin, u + w / 2, r.ymin + d]), np.pi),
                    (np.array([r.xmax - d, u - w / 2, r.xmax, u + w / 2]), -np.pi / 2),
                    (np.array([r.xmin, u - w / 2, r.xmin + d, u + w / 2]), np.pi / 2))[side])
    return out


def find_pose(group: Group, room: Room, obstacles, zones, mode: str, rng: np.random.Generator, spec: PlacementSpec,
               exhaustive: bool) -> tuple[np.ndarray, float] | None:
    """A footprint rect and yaw for ``group`` in ``room``, or None."""
    fx0, fy0, fx1, fy1 = group.footprint()
    w, d, gap = fx1 - fx0, fy1 - fy0, spec.walk_gap_m
    for _ in range(spec.placement_tries):
        free = mode == "free" or (mode == "any" and rng.random() < spec.any_free_prob)
        if free:
            yaw = float(rng.integers(4)) * np.pi / 2
            ew, ed = (w, d) if np.isclose(np.cos(yaw) ** 2, 1.0) else (d, w)
            xs, ys = (room.xmin + gap + ew / 2, room.xmax - gap - ew / 2), (room.ymin + gap + ed / 2, room.ymax - gap - ed / 2)
            if xs[0] > xs[1] or ys[0] > ys[1]:
                continue
            x, y = rng.uniform(*xs), rng.uniform(*ys)
            rect = np.array([x - ew / 2, y - ed / 2, x + ew / 2, y + ed / 2])
        else:
            side = int(rng.integers(4))
            lo, hi = (room.xmin, room.xmax) if side < 2 else (room.ymin, room.ymax)
            if hi - lo < w:
                continue
            if rng.random() < spec.corner_prob or hi - lo - 2 * gap < w:
                u = lo + w / 2 if rng.random() < 0.5 else hi - w / 2
            else:
                u = rng.uniform(lo + gap + w / 2, hi - gap - w / 2)
            rect, yaw = wall_poses(room, w, d, side, [u])[0]
        if fits(rect, room, obstacles, zones, gap):
            return rect, yaw
    if exhaustive and mode != "free":   # required items: scan every wall position before giving up
        for side in rng.permutation(4):
            lo, hi = (room.xmin, room.xmax) if side < 2 else (room.ymin, room.ymax)
            us = np.arange(lo + w / 2, hi - w / 2 + 1e-9, spec.scan_step_m).tolist() + [hi - w / 2]
            for rect, yaw in wall_poses(room, w, d, int(side), us):
                if fits(rect, room, obstacles, zones, gap):
                    return rect, yaw
    return None


def emit_group(b: MeshBuilder, group: Group, rect: np.ndarray, yaw: float, room_idx: int) -> list[dict]:
    """Add the group's members as instances; the group's footprint centre lands on ``rect``'s centre."""
    fp = group.footprint()
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    origin = (rect[:2] + rect[2:]) / 2 - rot @ ((fp[:2] + fp[2:]) / 2)
    records, inst_of = [], []
    for m in group.members:
        wy = yaw + m.yaw
        r3 = np.array([[np.cos(wy), -np.sin(wy), 0], [np.sin(wy), np.cos(wy), 0], [0, 0, 1]])
        pos = np.append(origin + rot @ np.asarray(m.offset[:2]), m.offset[2])
        inst = b.new_instance()
        inst_of.append(inst)
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for p in m.model.parts:
            v = p.verts @ r3.T + pos
            lo, hi = np.minimum(lo, v.min(0)), np.maximum(hi, v.max(0))
            b.add_mesh(v, p.tris, m.model.cls, inst, p.albedo, p.texture)
        support = inst_of[m.support] if m.support is not None else ("wall" if m.offset[2] > 0 else "floor")
        records.append({"instance": inst, "class": m.model.cls, "room": room_idx, "support": support,
                        "bbox": [round(float(x), 4) for x in (*lo, *hi)]})
    return records
