"""Staircases between the storeys of a procedural house (``envs.house``, ``storeys > 1``).

A staircase is a switchback (U-shaped) stair in one room, against a wall corner, in a local
frame (u, v): u runs from the entry end (u = 0, open to the room) to the back wall (u =
length), v from the side wall (v = 0) to the open side (v = width).

    flight 1 (v in the open-side strip) climbs from the lower floor along +u to a landing at
    half the storey height that spans the whole width at the back; flight 2 (the wall-side
    strip) climbs back along -u and arrives at the entry end on the upper floor. A divider
    wall between the flights rises to railing height above the upper floor.

Every step is a solid box from the lower floor to its tread (no overhang, nothing to walk
under), its rise ``storey height / n`` below the navmesh's climb (``StairSpec.max_rise_m``:
Recast rounds span tops up to whole cell heights, so a rise at the climb itself could
quantise to one unit more). The upper floor slab has an opening over the whole stair
rectangle; railings close its edges except where flight 2 arrives; a side railing runs along
flight 1's and the landing's open side. Treads are class ``floor`` (the renderer and the
segmenters see stairs as floor to walk on), sides, divider and railings ``wall``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calnav.envs.doors import overlap
from calnav.envs.primitives import MeshBuilder
from calnav.envs.scene import Room, Texture


@dataclass(frozen=True)
class StairSpec:
    """Constants of the staircases. Not part of ``HouseSpec`` (whose digest keys every cached
    single-storey house); ``StairSpec.digest_items`` joins the cache key only when a house has
    more than one storey."""

    max_rise_m: float = 0.17          # highest step, metres: below the navmesh climb (0.2 m) by a cell height's rounding
    tread_m: float = 0.3              # depth of a step, metres (6 navigation cells at 5 cm)
    flight_width_m: float = 1.1       # clear width of each flight, metres: 0.7 m navigable after the 0.2 m erosion
    landing_depth_m: float = 1.2      # depth of the half-way landing, metres (room for a 0.18 m agent to turn)
    divider_m: float = 0.1            # wall between the two flights, metres
    railing_height_m: float = 0.95    # railings above the floor they guard, metres
    railing_m: float = 0.05           # railing thickness, metres
    entry_clearance_m: float = 1.3    # free depth kept in front of the stair's entry end, metres

    def digest_items(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass
class Staircase:
    """One placed staircase from storey ``lower`` (floor at ``z0``) to the storey above
    (floor at ``z0 + rise_total_m``). ``rect`` (4,) world (x0, y0, x1, y1) of its footprint
    (the slab opening above); ``entry`` (4,) the free zone in front of it; the frame: ``axis``
    ("x" | "y") the u axis, ``u_sign`` / ``v_sign`` +-1 and ``origin`` (2,) world xy of (u, v)
    = (0, 0)."""

    lower: int
    z0: float
    rise_total_m: float
    n_steps: int
    length_m: float
    width_m: float
    axis: str
    origin: tuple[float, float]
    u_sign: int
    v_sign: int

    def world(self, u: float, v: float) -> tuple[float, float]:
        """World xy of stair-frame point (u, v), metres."""
        du, dv = self.u_sign * u, self.v_sign * v
        return (self.origin[0] + du, self.origin[1] + dv) if self.axis == "x" else (self.origin[0] + dv,
                                                                                   self.origin[1] + du)

    def world_rect(self, u0: float, u1: float, v0: float, v1: float) -> np.ndarray:
        """(4,) world (x0, y0, x1, y1) of the stair-frame rectangle [u0, u1] x [v0, v1]."""
        (ax, ay), (bx, by) = self.world(u0, v0), self.world(u1, v1)
        return np.array([min(ax, bx), min(ay, by), max(ax, bx), max(ay, by)])

    @property
    def rect(self) -> np.ndarray:
        return self.world_rect(0.0, self.length_m, 0.0, self.width_m)

    def entry(self, clearance_m: float) -> np.ndarray:
        return self.world_rect(-clearance_m, 0.0, 0.0, self.width_m)

    def record(self) -> dict:
        """The staircase as ``Scene.meta["stairs"]`` keeps it (JSON)."""
        return {"lower": self.lower, "z0": self.z0, "rise_total_m": self.rise_total_m, "n_steps": self.n_steps,
                "rect": [round(float(x), 4) for x in self.rect], "axis": self.axis}


def step_count(rise_total_m: float, spec: StairSpec) -> int:
    """Steps (an even number: both flights have as many) whose rise stays <= ``max_rise_m``."""
    return 2 * int(math.ceil(rise_total_m / (2 * spec.max_rise_m) - 1e-9))


def place_staircase(room: Room, lower: int, z0: float, rise_total_m: float, keep_clear: list[np.ndarray],
                    rng: np.random.Generator, spec: StairSpec) -> Staircase | None:
    """A staircase in a corner of ``room`` whose footprint and entry zone overlap none of
    ``keep_clear`` ((4,) world rects: doorway zones, door leaves, other stairs), or None. The
    eight corner / direction choices are tried in a random order."""
    n = step_count(rise_total_m, spec)
    length = (n // 2 - 1) * spec.tread_m + spec.landing_depth_m
    width = 2 * spec.flight_width_m + spec.divider_m
    for k in rng.permutation(8):
        axis = "x" if k & 4 else "y"
        u_sign, v_sign = (1 if k & 1 else -1), (1 if k & 2 else -1)
        # the back wall is at the u end: u runs towards it, so u = 0 lies `length` before it
        lo_u, hi_u = (room.xmin, room.xmax) if axis == "x" else (room.ymin, room.ymax)
        lo_v, hi_v = (room.ymin, room.ymax) if axis == "x" else (room.xmin, room.xmax)
        if hi_u - lo_u < length + spec.entry_clearance_m or hi_v - lo_v < width + 0.6:
            continue
        ou = hi_u - length if u_sign > 0 else lo_u + length
        ov = lo_v if v_sign > 0 else hi_v
        origin = (ou, ov) if axis == "x" else (ov, ou)
        st = Staircase(lower, z0, rise_total_m, n, length, width, axis, origin, u_sign, v_sign)
        if not any(overlap(st.rect, r) or overlap(st.entry(spec.entry_clearance_m), r) for r in keep_clear):
            return st
    return None


def build_staircase(b: MeshBuilder, st: Staircase, albedo_tread, albedo_wall, spec: StairSpec) -> None:
    """Add ``st``'s steps, landing, divider and railings to ``b`` (world coordinates)."""
    n1 = st.n_steps // 2
    rise, tread, fw, dv = st.rise_total_m / st.n_steps, spec.tread_m, spec.flight_width_m, spec.divider_m
    run = (n1 - 1) * tread                         # length of each flight, metres
    inst_steps, inst_walls = b.new_instance(), b.new_instance()
    z0, top = st.z0, st.z0 + st.rise_total_m

    def solid(rect: np.ndarray, za: float, zb: float, cls: str, inst: int, albedo, texture=Texture.PLAIN) -> None:
        b.add_box(((rect[0] + rect[2]) / 2, (rect[1] + rect[3]) / 2, (za + zb) / 2),
                  (rect[2] - rect[0], rect[3] - rect[1], zb - za), cls, inst, albedo, texture)

    v_open = (fw + dv, st.width_m)                 # flight 1: the open-side strip
    v_wall = (0.0, fw)                             # flight 2: the wall-side strip
    for i in range(1, n1):                         # flight 1, up along +u
        solid(st.world_rect((i - 1) * tread, i * tread, *v_open), z0, z0 + i * rise, "floor", inst_steps,
              albedo_tread, Texture.GRAIN)
    solid(st.world_rect(run, st.length_m, 0.0, st.width_m), z0, z0 + n1 * rise, "floor", inst_steps, albedo_tread,
          Texture.GRAIN)
    for j in range(1, n1):                         # flight 2, up along -u
        solid(st.world_rect(run - j * tread, run - (j - 1) * tread, *v_wall), z0, z0 + (n1 + j) * rise, "floor",
              inst_steps, albedo_tread, Texture.GRAIN)
    rail = spec.railing_height_m
    solid(st.world_rect(0.0, run, fw, fw + dv), z0, top + rail, "wall", inst_walls, albedo_wall)   # divider
    # the open side of flight 1 and the landing: one railing per step, from the floor up
    for i in range(1, n1):
        solid(st.world_rect((i - 1) * tread, i * tread, st.width_m - spec.railing_m, st.width_m), z0,
              z0 + i * rise + rail, "wall", inst_walls, albedo_wall)
    solid(st.world_rect(run, st.length_m, st.width_m - spec.railing_m, st.width_m), z0, z0 + n1 * rise + rail,
          "wall", inst_walls, albedo_wall)
    # the upper floor's edges around the opening: the open side and the entry end over flight 1
    solid(st.world_rect(-spec.railing_m, st.length_m, st.width_m, st.width_m + spec.railing_m), top, top + rail,
          "wall", inst_walls, albedo_wall)
    solid(st.world_rect(-spec.railing_m, 0.0, fw, st.width_m + spec.railing_m), top, top + rail, "wall",
          inst_walls, albedo_wall)


def rect_minus(outer: np.ndarray, hole: np.ndarray) -> list[np.ndarray]:
    """(4,) rects covering ``outer`` but not ``hole`` (both (x0, y0, x1, y1)): up to four
    slabs (below, above, left and right of the hole); ``[outer]`` when they do not overlap."""
    if not overlap(outer, hole):
        return [outer]
    x0, y0, x1, y1 = outer
    hx0, hy0, hx1, hy1 = max(hole[0], x0), max(hole[1], y0), min(hole[2], x1), min(hole[3], y1)
    pieces = [np.array(r) for r in ((x0, y0, x1, hy0), (x0, hy1, x1, y1), (x0, hy0, hx0, hy1), (hx1, hy0, x1, hy1))]
    return [p for p in pieces if p[2] - p[0] > 1e-6 and p[3] - p[1] > 1e-6]
