"""The procedural house generator's constants: ``HouseSpec`` (every size, probability and count
``envs.house`` and ``envs.house_layout`` draw from) and the version that keys the scene caches.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass

GENERATOR_VERSION = 1  # bump when generated houses change for a given (seed, spec): invalidates caches
MAX_STOREYS = 3        # storeys a house may have (``env.dataset.storeys``' range)
ROOM_KINDS = ("bedroom", "bathroom", "living_room", "kitchen", "office", "hallway")


@dataclass(frozen=True)
class HouseSpec:
    """Every constant of the generator. Ranges are (low, high) sampled uniformly."""

    min_rooms: int = 3                                 # rooms per house (hallway included), inclusive
    max_rooms: int = 10
    room_area_m2: tuple[float, float] = (15.0, 26.0)    # mean footprint area per room, m^2 (HM3D-like episode lengths)
    min_floor_area_m2: float = 40.0                     # bounds on total walkable floor (room interiors), m^2
    max_floor_area_m2: float = 250.0
    area_margin: float = 0.08                           # keep the sampled footprint this fraction inside the bounds
    footprint_aspect: tuple[float, float] = (1.0, 1.7)  # long side / short side of the footprint
    min_room_side_m: float = 2.4                        # shortest side of a room cell, metres
    split_fraction: tuple[float, float] = (0.35, 0.65)  # BSP cut position as a fraction of the cut side
    hallway_prob: float = 0.5                           # chance of a corridor in a house with >= hallway_min_rooms
    hallway_min_rooms: int = 5
    hallway_width_m: tuple[float, float] = (1.3, 1.8)   # corridor width, metres
    wall_height_m: tuple[float, float] = (2.5, 3.0)     # floor-to-ceiling height per house, metres
    wall_thickness_m: float = 0.1                       # interior and exterior walls, metres
    door_width_m: tuple[float, float] = (0.9, 1.0)      # doorway opening width, metres
    door_height_m: tuple[float, float] = (2.0, 2.1)     # doorway opening height (lintel bottom), metres
    door_jamb_m: float = 0.15                           # least wall between a doorway and a room corner, metres
    door_corner_prob: float = 0.6                       # chance a doorway sits at the end of the shared wall
    extra_door_prob: float = 0.3                        # chance of a door on each adjacency off the spanning tree
    door_leaf_prob: float = 0.5                         # chance that a doorway has an open door leaf (>= 1 per house)
    door_leaf_thickness_m: float = 0.04                 # metres
    door_open_deg: tuple[float, float] = (90.0, 105.0)  # leaf opening angle from closed, degrees
    door_clearance_m: float = 1.0                       # free depth in front of a doorway, both sides, metres
    door_zone_side_m: float = 0.3                       # free width beside a doorway (covers the leaf), metres
    walk_gap_m: float = 0.6                             # least gap between furniture, and between furniture and
                                                        # a wall it does not touch, metres
    corner_prob: float = 0.35                           # chance a wall placement snaps into a corner
    patterned_wall_prob: float = 0.35                   # chance a room's walls are tiled / papered, else paint
    any_free_prob: float = 0.4                          # chance an "any"-mode item stands free of the walls
    placement_tries: int = 30                           # random poses tried per sampled group
    group_samples: int = 3                              # groups sampled per item before giving up
    required_samples: int = 8                           # extra samples (exhaustive scan) for required items
    scan_step_m: float = 0.1                            # step of the exhaustive wall scan for required items
    max_layout_tries: int = 50                          # layouts drawn before giving up
    kind_sequence: tuple[str, ...] = ("living_room", "bathroom", "bedroom", "kitchen", "bedroom", "office",
                                      "bathroom", "bedroom", "living_room", "office")  # kinds by room count

    def max_extent_m(self) -> tuple[float, float]:
        """(long, short) sides of the largest house's xy bounds, metres: the footprint of the
        largest floor area ``split_footprint`` draws at the most elongated aspect (the largest
        perimeter, hence the largest bounds once walls are added), plus half an exterior wall on
        each side. Memory estimates size the navigation grid for it."""
        area = self.max_floor_area_m2 * (1 - self.area_margin)
        aspect = self.footprint_aspect[1]
        wall = self.wall_thickness_m
        return math.sqrt(area * aspect) + wall, math.sqrt(area / aspect) + wall

    def digest(self) -> str:
        """Short hash of the spec and ``GENERATOR_VERSION`` (cache keys)."""
        blob = json.dumps({"spec": asdict(self), "version": GENERATOR_VERSION}, sort_keys=True)
        return hashlib.sha1(blob.encode()).hexdigest()[:10]
