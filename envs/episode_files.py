"""ObjectNav episode records and their files: habitat-lab's ObjectNav-v1 JSON layout.

On disk (habitat-lab's ObjectNav layout, gzip JSON): ``<split>/<split>.json.gz`` holds the
category maps, ``<split>/content/<scene_id>.json.gz`` the episodes and ``goals_by_category``.
Positions are written in Habitat's y-up frame (x_h, y_h, z_h) = (x, z, -y) and rotations as
[x, y, z, w] quaternions about +y_h; calnav's z-up frame is restored on load. Each view point
carries the ``iou`` key that habitat-lab's ``ObjectViewLocation`` requires, as null: calnav
does not compute the object-in-view IoU (no measure reads it); files cached before the key
existed get it added on load (``read_episode_file``), nothing else in them changes.
Generation and the split cache: ``envs.episodes``.
"""
from __future__ import annotations

import gzip
import json
import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calnav.common.atomic import atomic_path
from calnav.common.gc_pause import gc_paused
from calnav.envs.semantics import GOAL_CATEGORIES

VIEW_POINT_IOU = None             # habitat-lab's ObjectViewLocation.iou: not computed by calnav


@dataclass
class GoalObject:
    """One instance of a goal category. position: (3,) world centroid, metres.
    view_points: (M, 2) float64 world xy of the view-point cell centres, metres."""

    object_id: int
    object_category: str
    position: np.ndarray
    view_points: np.ndarray


@dataclass
class ObjectNavEpisode:
    """start_position: (2,) world xy metres; start_rotation: Habitat [x, y, z, w] start
    quaternion, kept as the episode file stores it (habitat-lab's GPS / compass read these very
    numbers); ``start_yaw``: the same heading in radians, counter-clockwise from +x."""

    episode_id: str
    scene_id: str
    start_position: np.ndarray
    start_rotation: list[float]
    object_category: str
    geodesic_distance: float
    euclidean_distance: float
    goals: list[GoalObject] = field(default_factory=list)

    @property
    def start_yaw(self) -> float:
        return habitat_quaternion_to_yaw(self.start_rotation)

    @property
    def goal_id(self) -> int:
        return GOAL_CATEGORIES.index(self.object_category)


# ---------------------------------------------------------------- Habitat JSON schema
def _to_habitat(xy, z: float = 0.0) -> list[float]:
    return [float(xy[0]), float(z), float(-xy[1])]


def _from_habitat(p) -> np.ndarray:
    return np.array([p[0], -p[2]], dtype=np.float64)


def _view_points_from_habitat(view_points: list[dict]) -> np.ndarray:
    """(V, 2) float64 calnav x-y of habitat view points (``_from_habitat`` of each, in one array
    op: a goal has thousands)."""
    if not view_points:
        return np.zeros((0, 2))
    p = np.array([v["agent_state"]["position"] for v in view_points], dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:   # (a ragged list already raised ValueError)
        raise ValueError(f"view point positions must be [x, y, z], got shape {p.shape}")
    return np.stack([p[:, 0], -p[:, 2]], axis=1)


def habitat_quaternion_to_yaw(q) -> float:
    theta = 2 * math.atan2(q[1], q[3])
    return (theta + math.pi / 2) % (2 * math.pi)


def episodes_to_habitat(episodes: list[ObjectNavEpisode]) -> dict:
    """One scene's episodes as a habitat-lab ObjectNav content file (dict)."""
    goals_by_category: dict[str, list[dict]] = {}
    out = []
    for ep in episodes:
        key = f"{ep.scene_id}_{ep.object_category}"
        if key not in goals_by_category:
            goals_by_category[key] = [{
                "object_id": g.object_id, "object_category": g.object_category,
                "position": [float(g.position[0]), float(g.position[2]), float(-g.position[1])],
                "view_points": [{"agent_state": {"position": _to_habitat(v), "rotation": [0.0, 0.0, 0.0, 1.0]},
                                 "iou": VIEW_POINT_IOU} for v in g.view_points],
            } for g in ep.goals]
        out.append({
            "episode_id": ep.episode_id, "scene_id": ep.scene_id,
            "start_position": _to_habitat(ep.start_position),
            "start_rotation": [float(c) for c in ep.start_rotation],
            "object_category": ep.object_category,
            "info": {"geodesic_distance": ep.geodesic_distance, "euclidean_distance": ep.euclidean_distance},
            "goals": [],
        })
    return {"episodes": out, "goals_by_category": goals_by_category}


def episodes_from_habitat(data: dict) -> list[ObjectNavEpisode]:
    goals = {
        key: [GoalObject(int(g["object_id"]), g["object_category"],
                         np.array([g["position"][0], -g["position"][2], g["position"][1]], dtype=np.float64),
                         _view_points_from_habitat(g["view_points"]))
              for g in gs]
        for key, gs in data.get("goals_by_category", {}).items()
    }
    episodes = []
    for e in data["episodes"]:
        key = f"{e['scene_id']}_{e['object_category']}"
        if key not in goals:
            raise ValueError(f"episode {e['episode_id']}: no goals_by_category entry {key!r}")
        episodes.append(ObjectNavEpisode(
            episode_id=str(e["episode_id"]), scene_id=e["scene_id"],
            start_position=_from_habitat(e["start_position"]),
            start_rotation=[float(c) for c in e["start_rotation"]],
            object_category=e["object_category"],
            geodesic_distance=float(e["info"]["geodesic_distance"]),
            euclidean_distance=float(e["info"].get("euclidean_distance", float("nan"))),
            goals=goals[key]))
    return episodes


def write_json_gz(path: Path, data: dict) -> None:
    with atomic_path(path) as tmp, gzip.open(tmp, "wt") as f:
        json.dump(data, f)


def read_json_gz(path: Path) -> dict:
    """The JSON object of a gzip file; ValueError naming the file when it is not readable gzip
    JSON (EOFError: a truncated file, e.g. a killed writer)."""
    try:
        with gzip.open(path, "rt") as f, gc_paused():   # ~3x faster on large files (common.gc_pause)
            data = json.load(f)
    except (OSError, EOFError, zlib.error, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"corrupt episode file {path}: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"damaged episode file {path}: expected a JSON object, got {type(data).__name__}")
    return data


def read_episode_file(path: Path) -> list[ObjectNavEpisode]:
    """The episodes of one habitat-lab content file (``<split>/content/<scene>.json.gz``);
    ValueError naming the file and the missing / malformed entry when it is damaged."""
    data = read_json_gz(path)
    if add_view_point_iou(data):   # a file cached before calnav wrote ``iou``: upgraded in place
        write_json_gz(path, data)
    try:
        with gc_paused():
            return episodes_from_habitat(data)
    except KeyError as exc:
        raise ValueError(f"damaged episode file {path}: missing key {exc}") from None
    except (TypeError, IndexError, ValueError) as exc:
        raise ValueError(f"damaged episode file {path}: {exc}") from None


def add_view_point_iou(data: dict) -> bool:
    """Give every view point of a content file (dict, edited in place) the ``iou`` key that
    habitat-lab requires (files written before calnav wrote it); True when something changed."""
    changed = False
    for goals in data.get("goals_by_category", {}).values():
        for g in goals:
            for v in g["view_points"]:
                if "iou" not in v:
                    v["iou"] = VIEW_POINT_IOU
                    changed = True
    return changed


# ---------------------------------------------------------------- parsed once per process
# episode files already parsed in this process: path -> ((mtime_ns, size, inode), episodes). A
# command reads its split several times (preflight, feed order, the env); a rewritten file
# (another stat) is parsed again.
_PARSED: dict[Path, tuple[tuple[int, int, int], list[ObjectNavEpisode]]] = {}


def _stat_key(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_mtime_ns, st.st_size, st.st_ino


def cached_episodes(path: Path) -> list[ObjectNavEpisode] | None:
    """A scene's cached episodes, or None when the cache file is missing or damaged (a killed
    writer, another layout): the cache is rebuilt, as damaged scene caches are. Parsed once
    per process while the file stays the same (``_PARSED``)."""
    try:
        key = _stat_key(path)   # before reading: a file rewritten meanwhile is parsed again next time
    except FileNotFoundError:
        return None
    hit = _PARSED.get(path)
    if hit is not None and hit[0] == key:
        return list(hit[1])   # (the episodes themselves are shared: nothing mutates them)
    try:
        episodes = read_episode_file(path)
    except (ValueError, FileNotFoundError):
        return None
    _PARSED[path] = (key, episodes)
    return list(episodes)
