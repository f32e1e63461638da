"""The house as a scanner finds it: what real homes have on their floors and procedural houses
do not, added to a copy of the clean house before it is scanned (``envs.scanning.scanner``).

- rugs: thin slabs (``rug_thickness_m``) in some rooms, often reaching under furniture;
- thresholds: strips across some doorways (``threshold_height_m``), the step between two floors;
- clutter: small boxes and cylinders on the floor (bags, shoes, baskets, toys;
  ``clutter_height_m``), mostly in the gaps beside furniture and along walls, some low enough
  to walk over, some not; never in a doorway's clear zone.

All of it is unlabelled (void), as ScanNet leaves most such things. Every draw comes from the
generator passed in (the scan's seed), so the house is deterministic.
"""
from __future__ import annotations

import numpy as np

from calnav.envs.primitives import MeshBuilder
from calnav.envs.scanning.config import ScanningConfig
from calnav.envs.scene import Scene, Texture

RUG_COLOURS = ((150, 60, 50), (70, 80, 120), (190, 170, 130), (90, 110, 80), (120, 120, 125), (200, 195, 185))
CLUTTER_COLOURS = ((40, 40, 45), (180, 60, 40), (60, 90, 160), (220, 200, 60), (230, 230, 225), (120, 80, 50))
ROOM_MARGIN_M = 0.12          # rugs and clutter keep this far inside a room's walls, metres
DOOR_CLEAR_M = 0.6            # no clutter within this of a doorway's middle, metres
NEAR_FURNITURE_M = 0.5        # clutter prefers spots within this of furniture, metres
CLUTTER_TRIES = 30            # placement draws per clutter item


def _door_mids(scene: Scene) -> np.ndarray:
    """(n, 2) world xy of the doorways' middles (from the house generator's metadata)."""
    mids = []
    for d in scene.meta.get("doors", []):
        u = (d["span"][0] + d["span"][1]) / 2
        mids.append((d["coord"], u) if d["axis"] == "x" else (u, d["coord"]))
    return np.array(mids, np.float64).reshape(-1, 2)


def _furniture_rects(scene: Scene) -> np.ndarray:
    """(n, 4) [xmin, ymin, xmax, ymax] of the floor-standing objects' bounding boxes."""
    rects = [o["bbox"][:2] + o["bbox"][3:5] for o in scene.meta.get("objects", []) if o.get("support") == "floor"]
    return np.array(rects, np.float64).reshape(-1, 4)


def _rect_distance(p: np.ndarray, rects: np.ndarray) -> float:
    """Distance from point p (2,) to the nearest rectangle (0 inside); inf without rectangles."""
    if len(rects) == 0:
        return np.inf
    d = np.maximum(np.maximum(rects[:, :2] - p, p - rects[:, 2:]), 0.0)
    return float(np.hypot(d[:, 0], d[:, 1]).min())


def add_rugs(b: MeshBuilder, scene: Scene, cfg: ScanningConfig, rng: np.random.Generator) -> int:
    """A rug in each room with probability ``rug_prob``; returns how many."""
    n = 0
    for room in scene.rooms:
        if rng.random() >= cfg.rug_prob:
            continue
        w, d = room.xmax - room.xmin - 2 * ROOM_MARGIN_M, room.ymax - room.ymin - 2 * ROOM_MARGIN_M
        if min(w, d) < 0.8:
            continue
        sx, sy = w * rng.uniform(0.35, 0.75), d * rng.uniform(0.35, 0.75)
        cx = rng.uniform(room.xmin + ROOM_MARGIN_M + sx / 2, room.xmax - ROOM_MARGIN_M - sx / 2)
        cy = rng.uniform(room.ymin + ROOM_MARGIN_M + sy / 2, room.ymax - ROOM_MARGIN_M - sy / 2)
        t = rng.uniform(*cfg.rug_thickness_m)
        colour = np.array(RUG_COLOURS[rng.integers(len(RUG_COLOURS))])
        b.add_box((cx, cy, scene.floor_z + t / 2), (sx, sy, t), None, -1, colour,
                  (Texture.SPECKLE, Texture.STRIPES, Texture.FABRIC)[rng.integers(3)])
        n += 1
    return n


def add_thresholds(b: MeshBuilder, scene: Scene, cfg: ScanningConfig, rng: np.random.Generator) -> int:
    """A strip across each doorway with probability ``threshold_prob``; returns how many."""
    n = 0
    wall_t = float(scene.meta.get("spec", {}).get("wall_thickness_m", 0.1))
    for d in scene.meta.get("doors", []):
        if rng.random() >= cfg.threshold_prob:
            continue
        h = rng.uniform(*cfg.threshold_height_m)
        depth, length = wall_t + rng.uniform(0.04, 0.12), d["span"][1] - d["span"][0]
        u = (d["span"][0] + d["span"][1]) / 2
        centre = (d["coord"], u) if d["axis"] == "x" else (u, d["coord"])
        size = (depth, length, h) if d["axis"] == "x" else (length, depth, h)
        b.add_box((*centre, scene.floor_z + h / 2), size, None, -1,
                  np.array((150, 120, 90)) + rng.integers(-30, 30, 3), Texture.GRAIN)
        n += 1
    return n


def add_clutter(b: MeshBuilder, scene: Scene, cfg: ScanningConfig, rng: np.random.Generator) -> int:
    """About ``clutter_per_m2`` objects per m^2 of each room's floor; returns how many."""
    rects, doors = _furniture_rects(scene), _door_mids(scene)
    n = 0
    for room in scene.rooms:
        lo = np.array([room.xmin, room.ymin]) + ROOM_MARGIN_M
        hi = np.array([room.xmax, room.ymax]) - ROOM_MARGIN_M
        if (hi <= lo).any():
            continue
        for _ in range(int(rng.poisson(cfg.clutter_per_m2 * room.area))):
            size = rng.uniform(0.08, 0.4, 2)
            h = rng.uniform(*cfg.clutter_height_m)
            for _ in range(CLUTTER_TRIES):
                p = rng.uniform(lo + size.max() / 2, np.maximum(hi - size.max() / 2, lo + size.max() / 2))
                free = _rect_distance(p, rects) > size.max() / 2 + 0.02
                clear_of_doors = len(doors) == 0 or np.hypot(*(doors - p).T).min() > DOOR_CLEAR_M
                near = _rect_distance(p, rects) < NEAR_FURNITURE_M or (p - lo).min() < 0.3 or (hi - p).min() < 0.3
                if free and clear_of_doors and (near or rng.random() < 0.25):
                    break
            else:
                continue
            colour = np.array(CLUTTER_COLOURS[rng.integers(len(CLUTTER_COLOURS))])
            if rng.random() < 0.35:
                b.add_cylinder((*p, scene.floor_z), size.min() / 2, h, None, -1, colour, segments=10)
            else:
                b.add_box((*p, scene.floor_z + h / 2), (*size, h), None, -1, colour,
                          yaw=rng.uniform(0, np.pi))
            rects = np.vstack([rects, [*(p - size.max() / 2), *(p + size.max() / 2)]])
            n += 1
    return n


def lived_in(scene: Scene, cfg: ScanningConfig, rng: np.random.Generator) -> Scene:
    """``scene`` (a procedural house, left unchanged) with rugs, thresholds and clutter added;
    the counts go to ``meta["lived_in"]``."""
    b = MeshBuilder(scene.name, scene.class_names)
    counts = {"rugs": add_rugs(b, scene, cfg, rng), "thresholds": add_thresholds(b, scene, cfg, rng),
              "clutter": add_clutter(b, scene, cfg, rng)}
    meta = {**scene.meta, "lived_in": counts}
    extra = b.arrays()
    return Scene(name=scene.name, vertices=np.vstack([scene.vertices, extra["vertices"]]),
                 triangles=np.vstack([scene.triangles, extra["triangles"] + len(scene.vertices)]),
                 **{k: np.concatenate([getattr(scene, k), extra[k]])
                    for k in ("tri_class", "tri_instance", "tri_albedo", "tri_texture")},
                 class_names=scene.class_names, rooms=list(scene.rooms), floor_z=scene.floor_z, meta=meta)
