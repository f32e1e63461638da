"""ObjectNav episode records and their files: habitat-lab's ObjectNav-v1 JSON layout.

On disk (habitat-lab's ObjectNav layout, gzip JSON): ``<split>/<split>.json.gz`` holds the
category maps, ``<split>/content/<scene_id>.json.gz`` the episodes and ``goals_by_category``.
Positions are written in Habitat's y-up frame (x_h, y_h, z_h) = (x, z, -y) and rotations as
[x, y, z, w] quaternions about +y_h; calnav's z-up frame is restored on load. Each view point
carries the ``iou`` key that habitat-lab's ``ObjectViewLocation`` requires, as null: calnav
does not compute the object-in-view IoU (no measure reads it); files cached before the key
existed get it added on load (``read_episode_file``), nothing else in them changes. Each parsed
file is cached beside it as ``<split>/parsed/<scene>.npz`` (``read_sidecar``, at the end: every
process of a run reads the split, and the JSON parse was ~1 s of each one's start-up).
Generation and the split cache: ``envs.episodes``.
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
    per process while the file stays the same (``_PARSED``), and read from its binary sidecar
    (``read_sidecar``) when that matches the file, so other processes skip the JSON."""
    try:
        key = _stat_key(path)   # before reading: a file rewritten meanwhile is parsed again next time
    except FileNotFoundError:
        return None
    hit = _PARSED.get(path)
    if hit is not None and hit[0] == key:
        return list(hit[1])   # (the episodes themselves are shared: nothing mutates them)
    episodes = read_sidecar(path, key)
    if episodes is None:
        try:
            episodes = read_episode_file(path)
        except (ValueError, FileNotFoundError):
            return None
        write_sidecar(path, key, episodes)
    _PARSED[path] = (key, episodes)
    return list(episodes)


# ---------------------------------------------------------------- the parsed sidecar
# A scene's parsed episodes beside its habitat-lab JSON file, in a form read ~50x faster.
#
# Why: every process of a run -- the driver and each pool or Ray worker -- reads its split, and
# parsing the JSON (``val``: 30 files, 51 MB, mostly the goals' view points) took ~1 s per
# process, a fixed cost paid again by every worker before its first episode. The sidecar holds
# the same numbers as arrays: ``<split dir>/parsed/<scene>.npz`` (never in ``content/``, which
# habitat-lab reads), written atomically by the first process that parses the JSON. It is a
# cache of the JSON, never a source: it records the JSON file's (mtime_ns, size, inode) and
# ``SIDECAR_FORMAT``, and anything that does not match, cannot be read, or does not hold
# consistent arrays is ignored (the JSON is parsed instead and the sidecar rewritten). No
# pickles: ``np.load(allow_pickle=False)``; strings travel as one JSON text.
SIDECAR_FORMAT = 1   # bump when ObjectNavEpisode / GoalObject change what they hold
# A house with storeys also stores heights and storeys (``STOREY_ARRAYS``); single-storey sidecars
# keep format 1 and their bytes.
STOREY_SIDECAR_FORMAT = 2
STOREY_ARRAYS = ("start_height", "storeys", "vp_heights")


def sidecar_path(content_file: Path) -> Path | None:
    """``<split>/content/<scene>.json.gz`` -> ``<split>/parsed/<scene>.npz``; None for a file
    outside a split's ``content`` folder (no sidecar: it is not calnav's cache)."""
    if content_file.parent.name != "content" or not content_file.name.endswith(".json.gz"):
        return None
    return content_file.parent.parent / "parsed" / f"{content_file.name.removesuffix('.json.gz')}.npz"


def write_sidecar(content_file: Path, source_key: tuple[int, int, int], episodes: list) -> None:
    """Store ``episodes`` (parsed from ``content_file`` whose stat key was ``source_key``); a
    cache that cannot be written (read-only, full disk) is skipped: the JSON stays the source."""
    path = sidecar_path(content_file)
    if path is None:
        return
    goals, index = [], {}
    for ep in episodes:
        for g in ep.goals:
            if id(g) not in index:
                index[id(g)] = len(goals)
                goals.append(g)
    ep_goals = [index[id(g)] for ep in episodes for g in ep.goals]
    strings = {"episode_id": [e.episode_id for e in episodes], "scene_id": [e.scene_id for e in episodes],
               "object_category": [e.object_category for e in episodes],
               "goal_category": [g.object_category for g in goals]}
    if any(e.scene_dataset_config for e in episodes):   # (an episode file's; calnav's own sidecars keep their bytes)
        strings["scene_dataset_config"] = [e.scene_dataset_config for e in episodes]
    arrays = {
        "format": np.array([SIDECAR_FORMAT, *source_key], np.int64),
        "strings": np.array(json.dumps(strings)),
        "start_position": np.array([e.start_position for e in episodes], np.float64).reshape(-1, 2),
        "start_rotation": np.array([e.start_rotation for e in episodes], np.float64).reshape(-1, 4),
        "distances": np.array([[e.geodesic_distance, e.euclidean_distance] for e in episodes],
                              np.float64).reshape(-1, 2),
        "ep_goal_offsets": np.cumsum([0] + [len(e.goals) for e in episodes]).astype(np.int64),
        "ep_goals": np.array(ep_goals, np.int64),
        "goal_id": np.array([g.object_id for g in goals], np.int64),
        "goal_position": np.array([g.position for g in goals], np.float64).reshape(-1, 3),
        "vp_offsets": np.cumsum([0] + [len(g.view_points) for g in goals]).astype(np.int64),
        "view_points": np.concatenate([np.asarray(g.view_points, np.float64).reshape(-1, 2) for g in goals]
                                      or [np.zeros((0, 2))]),
    }
    if any(e.start_storey or e.goal_storey or e.start_height for e in episodes) or any(
            g.view_point_heights is not None for g in goals):
        arrays["format"][0] = STOREY_SIDECAR_FORMAT
        arrays["start_height"] = np.array([e.start_height for e in episodes], np.float64)
        arrays["storeys"] = np.array([[e.start_storey, e.goal_storey] for e in episodes], np.int64).reshape(-1, 2)
        arrays["vp_heights"] = np.concatenate([g.heights() for g in goals] or [np.zeros(0)])
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            np.savez(tmp, **arrays)
    except OSError:
        pass


def read_sidecar(content_file: Path, source_key: tuple[int, int, int]) -> list | None:
    """The episodes stored for ``content_file`` at stat key ``source_key``, or None (no sidecar,
    another key or format, unreadable or inconsistent arrays)."""
    path = sidecar_path(content_file)
    if path is None or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
        fmt = int(a["format"][0])
        if a["format"].tolist()[1:] != [*source_key] or fmt not in (SIDECAR_FORMAT, STOREY_SIDECAR_FORMAT):
            return None
        storeyed = fmt == STOREY_SIDECAR_FORMAT
        s = json.loads(str(a["strings"]))
        n, ng = len(s["episode_id"]), len(s["goal_category"])
        eo, vo = a["ep_goal_offsets"], a["vp_offsets"]
        shapes_ok = (len(s["scene_id"]) == len(s["object_category"]) == n and a["start_position"].shape == (n, 2)
                     and a["start_rotation"].shape == (n, 4) and a["distances"].shape == (n, 2) and len(eo) == n + 1
                     and eo[0] == 0 and (np.diff(eo) >= 0).all() and eo[-1] == len(a["ep_goals"])
                     and ((a["ep_goals"] >= 0) & (a["ep_goals"] < ng)).all() and len(a["goal_id"]) == ng
                     and a["goal_position"].shape == (ng, 3) and len(vo) == ng + 1 and vo[0] == 0
                     and (np.diff(vo) >= 0).all() and vo[-1] == len(a["view_points"]))
        if storeyed:
            shapes_ok = shapes_ok and a["start_height"].shape == (n,) and a["storeys"].shape == (n, 2) \
                and a["vp_heights"].shape == (len(a["view_points"]),)
        if not shapes_ok:
            return None
        goals = [GoalObject(int(a["goal_id"][i]), s["goal_category"][i], a["goal_position"][i].copy(),
                            a["view_points"][vo[i]:vo[i + 1]].copy(),
                            a["vp_heights"][vo[i]:vo[i + 1]].copy() if storeyed else None) for i in range(ng)]
        shared: dict[tuple, list] = {}   # episodes with the same goals share one list, as parsed from JSON
        episodes = []
        for i in range(n):
            ids = tuple(a["ep_goals"][eo[i]:eo[i + 1]].tolist())
            episodes.append(ObjectNavEpisode(
                episode_id=s["episode_id"][i], scene_id=s["scene_id"][i], start_position=a["start_position"][i].copy(),
                start_rotation=a["start_rotation"][i].tolist(), object_category=s["object_category"][i],
                geodesic_distance=float(a["distances"][i, 0]), euclidean_distance=float(a["distances"][i, 1]),
                goals=shared.setdefault(ids, [goals[j] for j in ids]),
                scene_dataset_config=s.get("scene_dataset_config", [""] * n)[i],
                **({"start_height": float(a["start_height"][i]), "start_storey": int(a["storeys"][i, 0]),
                    "goal_storey": int(a["storeys"][i, 1])} if storeyed else {})))
        return episodes
    except Exception:  # noqa: BLE001 -- any damage to a cache file means: parse the JSON instead
        return None
