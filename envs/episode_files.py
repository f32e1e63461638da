"""ObjectNav episode records and their files: habitat-lab's ObjectNav-v1 JSON layout.

On disk (habitat-lab's ObjectNav layout, gzip JSON): ``<split>/<split>.json.gz`` holds the
category maps, ``<split>/content/<scene_id>.json.gz`` the episodes and ``goals_by_category``.
Positions are written in Habitat's y-up frame (x_h, y_h, z_h) = (x, z, -y) and rotations as
[x, y, z, w] quaternions about +y_h; calnav's z-up frame is restored on load. Each view point
carries the ``iou`` key that habitat-lab's ``ObjectViewLocation`` requires, as null: calnav
does not compute the object-in-view IoU (no measure reads it); files cached before the key
existed get it added on load (``read_episode_file``), nothing else in them changes. Parsed
files are cached per process and beside them (``envs.episode_cache``); generation and the split
cache: ``envs.episodes``.
"""
from __future__ import annotations

import gzip
import json
import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np

from calnav.common.atomic import atomic_path
from calnav.common.gc_pause import gc_paused
from calnav.envs.episode_values import distance, numbers, unit_quaternion
from calnav.envs.semantics import GOAL_CATEGORIES

VIEW_POINT_IOU = None             # habitat-lab's ObjectViewLocation.iou: not computed by calnav


@dataclass
class GoalObject:
    """One instance of a goal category. position: (3,) world centroid, metres.
    view_points: (M, 2) float64 world xy of the view-point cell centres, metres.
    view_point_heights: (M,) float64 floor height under each view point, metres (Habitat's
    view point y), or None: all on the single storey's floor (a file's y = 0)."""

    object_id: int
    object_category: str
    position: np.ndarray
    view_points: np.ndarray
    view_point_heights: np.ndarray | None = None

    def heights(self) -> np.ndarray:
        """(M,) float64 view point floor heights, metres (zeros on a single storey)."""
        if self.view_point_heights is None:
            return np.zeros(len(self.view_points))
        return np.asarray(self.view_point_heights, np.float64)


@dataclass
class ObjectNavEpisode:
    """start_position: (2,) world xy metres; start_rotation: Habitat [x, y, z, w] start
    quaternion, kept as the episode file stores it (habitat-lab's GPS / compass read these very
    numbers); ``start_yaw``: the same heading in radians, counter-clockwise from +x.
    ``start_height``: the floor height under the start, metres (Habitat's start y); in a house
    with storeys ``start_storey`` its storey and ``goal_storey`` the storey of the nearest goal
    view point (geodesically); all 0 on one storey. refused: why the episode cannot run on
    calnav's navmesh ("" when it can): an episode of a habitat-lab dataset
    (``envs.file_episodes``) keeps its index and is listed, not run. scene_dataset_config: the
    scene dataset config the file's episode names (habitat-lab's key; "" for calnav's own)."""

    episode_id: str
    scene_id: str
    start_position: np.ndarray
    start_rotation: list[float]
    object_category: str
    geodesic_distance: float
    euclidean_distance: float
    goals: list[GoalObject] = field(default_factory=list)
    start_height: float = 0.0
    refused: str = ""
    start_storey: int = 0
    goal_storey: int = 0
    scene_dataset_config: str = ""

    @property
    def crosses_storeys(self) -> bool:
        return self.start_storey != self.goal_storey

    @property
    def start_yaw(self) -> float:
        return habitat_quaternion_to_yaw(self.start_rotation)

    @property
    def goal_id(self) -> int:
        return GOAL_CATEGORIES.index(self.object_category)


# ------------------------------------------------------------------- goals on a grid
def goal_mask(navgrid, goals: list[GoalObject]) -> np.ndarray:
    """(H, W) bool: the view-point cells of all given goal instances; (L, H, W) on a layered
    grid (``layered_goal_mask``)."""
    if getattr(navgrid, "layered", False):
        return layered_goal_mask(navgrid, goals)
    return view_point_mask(navgrid, np.concatenate([g.view_points for g in goals]))


def layered_goal_mask(grid, goals: list[GoalObject]) -> np.ndarray:
    """(L, H, W) bool: the view-point cells of ``goals``, each on the layer of its height."""
    mask = np.zeros(grid.navigable.shape, dtype=bool)
    for g in goals:
        rc = grid.to_cell(np.asarray(g.view_points, np.float64).reshape(-1, 2))
        layers = np.array([grid.storey_at(z) for z in g.heights()], np.int64)
        inside = grid.in_grid(rc)
        mask[layers[inside], rc[inside, 0], rc[inside, 1]] = True
    return mask


def view_point_mask(navgrid, points_xy: np.ndarray) -> np.ndarray:
    """(H, W) bool: the cells of view points ``points_xy`` ((N, 2) world xy, metres); points
    off the grid mark nothing."""
    mask = np.zeros(navgrid.navigable.shape, dtype=bool)
    rc = navgrid.to_cell(np.asarray(points_xy, np.float64).reshape(-1, 2))
    inside = navgrid.in_grid(rc)
    mask[rc[inside, 0], rc[inside, 1]] = True
    return mask


# ---------------------------------------------------------------- Habitat JSON schema
def _to_habitat(xy, z: float = 0.0) -> list[float]:
    return [float(xy[0]), float(z), float(-xy[1])]


def _from_habitat(p) -> np.ndarray:
    return np.array([p[0], -p[2]], dtype=np.float64)


def _view_points_from_habitat(view_points: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """((V, 2) float64 calnav x-y, (V,) float64 heights) of habitat view points
    (``_from_habitat`` of each, in one array op: a goal has thousands)."""
    if not view_points:
        return np.zeros((0, 2)), np.zeros(0)
    p = np.array([numbers(v["agent_state"]["position"], 3, "a view point's position") for v in view_points],
                 dtype=np.float64)
    return np.stack([p[:, 0], -p[:, 2]], axis=1), p[:, 1].copy()


def habitat_quaternion_to_yaw(q) -> float:
    theta = 2 * math.atan2(q[1], q[3])
    return (theta + math.pi / 2) % (2 * math.pi)


def episodes_to_habitat(episodes: list[ObjectNavEpisode]) -> dict:
    """One scene's episodes as a habitat-lab ObjectNav content file (dict)."""
    goals_by_category: dict[str, list[dict]] = {}
    out = []
    for ep in episodes:
        key = goals_key(ep.scene_id, ep.object_category)
        if key not in goals_by_category:
            goals_by_category[key] = [{
                "object_id": g.object_id, "object_category": g.object_category,
                "position": [float(g.position[0]), float(g.position[2]), float(-g.position[1])],
                "view_points": [{"agent_state": {"position": _to_habitat(v, h), "rotation": [0.0, 0.0, 0.0, 1.0]},
                                 "iou": VIEW_POINT_IOU} for v, h in zip(g.view_points, g.heights())],
            } for g in ep.goals]
        info = {"geodesic_distance": ep.geodesic_distance, "euclidean_distance": ep.euclidean_distance}
        if ep.start_storey or ep.goal_storey or ep.start_height:   # (one storey: the file as before storeys)
            info.update(start_storey=int(ep.start_storey), goal_storey=int(ep.goal_storey))
        out.append({
            "episode_id": ep.episode_id, "scene_id": ep.scene_id,
            **({"scene_dataset_config": ep.scene_dataset_config} if ep.scene_dataset_config else {}),
            "start_position": _to_habitat(ep.start_position, ep.start_height),
            "start_rotation": [float(c) for c in ep.start_rotation],
            "object_category": ep.object_category,
            "info": info,
            "goals": [],
        })
    return {"episodes": out, "goals_by_category": goals_by_category}


def goals_key(scene_id: str, category: str) -> str:
    """habitat-lab's ``ObjectGoalNavEpisode.goals_key``: the scene file's base name and the
    category (``TEEsavR23oF.basis.glb_chair``; calnav's ``house_val_0003_chair``)."""
    return f"{PurePosixPath(scene_id).name}_{category}"


def _goal_from_habitat(g: dict) -> GoalObject:
    xy, heights = _view_points_from_habitat(g["view_points"])
    return GoalObject(int(g["object_id"]), g["object_category"],
                      np.array(numbers(g["position"], 3, f"goal object {g['object_id']}'s position"),
                               dtype=np.float64)[[0, 2, 1]] * [1.0, -1.0, 1.0],
                      xy, heights if heights.any() else None)   # (all 0: one storey, None as before storeys)


def episodes_from_habitat(data: dict) -> list[ObjectNavEpisode]:
    """The episodes of a habitat-lab ObjectNav file (dict): goals from ``goals_by_category``
    (``goals_key``), or from each episode's ``goals`` in a file without it."""
    goals = {key: [_goal_from_habitat(g) for g in gs] for key, gs in data.get("goals_by_category", {}).items()}
    episodes = []
    for e in data["episodes"]:
        key = goals_key(e["scene_id"], e["object_category"])
        if key not in goals and e.get("goals"):   # a file without goals_by_category (habitat-lab's dedup_goals)
            goals[key] = [_goal_from_habitat(g) for g in e["goals"]]
        if key not in goals:
            raise ValueError(f"episode {e['episode_id']}: no goals_by_category entry {key!r}")
        start = numbers(e["start_position"], 3, f"episode {e['episode_id']}: start_position")
        episodes.append(ObjectNavEpisode(
            episode_id=str(e["episode_id"]), scene_id=e["scene_id"],
            start_position=_from_habitat(start),
            start_rotation=unit_quaternion(e["start_rotation"], f"episode {e['episode_id']}: start_rotation"),
            object_category=e["object_category"],
            geodesic_distance=distance(e["info"]["geodesic_distance"], f"episode {e['episode_id']}: geodesic_distance"),
            euclidean_distance=float(e["info"].get("euclidean_distance", float("nan"))),   # (recorded nowhere)
            goals=goals[key], start_height=start[1],
            start_storey=int(e["info"].get("start_storey", 0)), goal_storey=int(e["info"].get("goal_storey", 0)),
            scene_dataset_config=str(e.get("scene_dataset_config") or "")))
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
