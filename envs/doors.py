"""Doorways of the procedural houses: the opening record, an open door leaf's pose and mesh, and
the clear zones in front of a doorway that furniture must leave free.

Geometry only: ``cells`` are the house's room cells (anything with ``x0, y0, x1, y1`` in metres)
and ``spec`` its ``envs.house.HouseSpec``; the layout decisions (which doorway gets a leaf) stay
in ``envs.house``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np

from calnav.envs.furniture_parts import METAL, WOOD, colour
from calnav.envs.primitives import MeshBuilder, box_mesh
from calnav.envs.scene import Texture


class Cell(Protocol):
    """A room cell of the house layout (``envs.house_layout.Cell``), metres."""
    x0: float
    y0: float


class DoorSpec(Protocol):
    """The fields of ``envs.house.HouseSpec`` that door geometry reads, metres."""
    wall_thickness_m: float
    door_leaf_thickness_m: float
    door_clearance_m: float
    door_zone_side_m: float


LEAF_GAP_M = 0.01        # clearance around a door leaf in its frame, metres
HANDLE_INSET_M = 0.08    # door handle distance from the leaf's free edge, metres
HANDLE_Z_M = 1.0         # door handle height, metres
HANDLE_SIZE_M = (0.03, 0.1, 0.03)   # door handle box (along the leaf, through it, height), metres


@dataclass
class Doorway:
    """An opening between cells ``a`` and ``b`` in the wall plane ``axis`` = ``coord`` (metres);
    it spans ``[lo, hi]`` along the wall and ``[0, height]`` in z. ``leaf_room`` is the cell a
    door leaf swings into (None: no leaf), hinged at ``lo`` if ``hinge_lo`` else at ``hi``."""

    a: int
    b: int
    axis: str
    coord: float
    lo: float
    hi: float
    height: float
    leaf_room: int | None = None
    hinge_lo: bool = True
    open_deg: float = 90.0


def overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two (x0, y0, x1, y1) rectangles share interior area."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def door_frame(d: Doorway, cells: Sequence[Cell], room: int, t: float):
    """(to_world, sign): maps (n, u) = (depth into ``room`` from its wall face, along-wall) to world xy."""
    c = cells[room]
    sign = 1.0 if np.isclose(c.x0 if d.axis == "x" else c.y0, d.coord) else -1.0
    def to_world(n, u):
        w = d.coord + sign * (t / 2 + np.asarray(n))
        return (w, np.asarray(u)) if d.axis == "x" else (np.asarray(u), w)
    return to_world, sign


def leaf_pose(d: Doorway, cells: Sequence[Cell], spec: DoorSpec):
    """Open leaf of doorway ``d``: centre (x, y), yaw, length, handle (x, y) and footprint rect, metres."""
    to_world, sign = door_frame(d, cells, d.leaf_room, spec.wall_thickness_m)
    th, length = spec.door_leaf_thickness_m, d.hi - d.lo - LEAF_GAP_M
    ang, s = np.deg2rad(d.open_deg), (1.0 if d.hinge_lo else -1.0)
    dir_n, dir_u = np.sin(ang), s * np.cos(ang)   # leaf direction from its hinge in the (n, u) frame;
    hinge_n, hinge_u = th / 2, (d.lo if d.hinge_lo else d.hi) - s * th / 2   # past 90 deg it turns off the passage
    centre = to_world(hinge_n + dir_n * length / 2, hinge_u + dir_u * length / 2)
    handle = to_world(hinge_n + dir_n * (length - HANDLE_INSET_M), hinge_u + dir_u * (length - HANDLE_INSET_M))
    dx, dy = (sign * dir_n, dir_u) if d.axis == "x" else (dir_u, sign * dir_n)
    yaw = float(np.arctan2(dy, dx))
    corners = box_mesh((*centre, 0.0), (length, th, 0.0), yaw)[0][:4, :2]
    return centre, yaw, length, handle, np.concatenate([corners.min(0), corners.max(0)])


def add_door_leaf(b: MeshBuilder, d: Doorway, cells: Sequence[Cell], rng: np.random.Generator, spec: DoorSpec) -> None:
    (x, y), yaw, length, (hx, hy), _ = leaf_pose(d, cells, spec)
    th, height, inst = spec.door_leaf_thickness_m, d.height - 2 * LEAF_GAP_M, b.new_instance()
    b.add_box((x, y, LEAF_GAP_M + height / 2), (length, th, height), "door", inst, colour(rng, WOOD), Texture.GRAIN, yaw=yaw)
    b.add_box((hx, hy, HANDLE_Z_M), HANDLE_SIZE_M, "door", inst, colour(rng, METAL), yaw=yaw)


def door_zones(doors: list[Doorway], cells: Sequence[Cell], room: int, spec: DoorSpec) -> list[np.ndarray]:
    """Rectangles (x0, y0, x1, y1) in front of the room's doorways that furniture must leave free."""
    zones = []
    for d in (d for d in doors if room in (d.a, d.b)):
        to_world, _ = door_frame(d, cells, room, spec.wall_thickness_m)
        xs, ys = to_world(np.array([0.0, spec.door_clearance_m]),
                          np.array([d.lo - spec.door_zone_side_m, d.hi + spec.door_zone_side_m]))
        zones.append(np.array([min(xs), min(ys), max(xs), max(ys)]))
    return zones
