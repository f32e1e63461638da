"""ObjectNav episodes: generation (seeded, deterministic), Habitat's JSON schema, split caching.

Goal view points: navigable cells whose horizontal distance to the goal object's footprint is
at most ``view_point_radius_m`` (1.0 m) and from which some part of the object is visible at
camera height within the vertical field of view (a ray from the camera to a surface sample of
the object hits that object first). An instance with no view point cannot be a goal.

Start poses: a navigable cell whose geodesic distance to the nearest view point lies in
[min_geodesic_m, max_geodesic_m], drawn with probability proportional to that distance (most
of a house lies near some goal; the weighting keeps a split's median above 5 m: 7.1 m on the
default val split), with uniform heading. Like habitat-lab's generators, a start whose geodesic / Euclidean distance ratio is below ``min_euclid_ratio``
(a straight shot) is rejected with probability ``TRIVIAL_REJECT_PROB``.

On disk (habitat-lab's ObjectNav layout, gzip JSON): ``<split>/<split>.json.gz`` holds the
category maps, ``<split>/content/<scene_id>.json.gz`` the episodes and ``goals_by_category``.
Positions are written in Habitat's y-up frame (x_h, y_h, z_h) = (x, z, -y) and rotations as
[x, y, z, w] quaternions about +y_h; calnav's z-up frame is restored on load. Each view point
carries the ``iou`` key that habitat-lab's ``ObjectViewLocation`` requires, as null: calnav
does not compute the object-in-view IoU (no measure reads it); files cached before the key
existed get it added on load (``load_split``), nothing else in them changes.
"""
from __future__ import annotations

import gzip
import hashlib
import json
import math
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage

from calnav.common.atomic import atomic_path
from calnav.common.gc_pause import gc_paused
from calnav.envs.config import EnvConfig
from calnav.envs.scene import Scene, cache_dir, sample_surface
from calnav.envs.semantics import GOAL_CATEGORIES
from calnav.envs.task import yaw_to_habitat_quaternion  # noqa: F401 (re-exported: the episode files' convention)

GENERATOR_VERSION = 3  # 2: walls block in the nav grid; 3: starts weighted by distance^1
TRIVIAL_REJECT_PROB = 0.98        # habitat-lab's rejection rate for near-straight episodes
SURFACE_SAMPLE_SPACING_M = 0.03   # spacing of object surface samples for footprints, metres
VISIBILITY_TARGETS = 48           # object surface points tested for visibility per view point
MAX_START_TRIES = 200             # start-pose draws per episode before giving up
START_DISTANCE_POWER = 1.0        # start cells are drawn with probability ∝ geodesic^power
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


# ---------------------------------------------------------------- geometry helpers
def _vertical_half_fov(env_cfg: EnvConfig) -> float:
    w, h = env_cfg.resolution
    return math.atan(math.tan(math.radians(env_cfg.hfov_deg) / 2) * h / w)


def find_view_points(scene: Scene, navgrid, raycasting_scene, instance_id: int, env_cfg: EnvConfig,
                     rng: np.random.Generator) -> np.ndarray:
    """(M, 2) world xy of the view points of one instance (may be empty)."""
    import open3d as o3d

    surface = sample_surface(scene.instance_triangles(instance_id).astype(np.float64),
                             SURFACE_SAMPLE_SPACING_M, rng)
    cells = navgrid.to_cell(surface[:, :2])
    h, w = navgrid.navigable.shape
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
    footprint = np.zeros((h, w), dtype=bool)
    footprint[cells[inside, 0], cells[inside, 1]] = True
    dist = ndimage.distance_transform_edt(~footprint, sampling=navgrid.cell_m)
    candidates = np.argwhere(navgrid.navigable & (dist <= env_cfg.view_point_radius_m))
    if len(candidates) == 0:
        return np.zeros((0, 2))
    targets = surface[rng.choice(len(surface), size=min(VISIBILITY_TARGETS, len(surface)), replace=False)]
    eyes_xy = navgrid.to_world(candidates)
    eyes = np.column_stack([eyes_xy, np.full(len(eyes_xy), scene.floor_z + env_cfg.camera_height_m)])
    direction = targets[None, :, :] - eyes[:, None, :]                       # (C, P, 3)
    length = np.linalg.norm(direction, axis=2)
    elevation = np.arcsin(np.clip(direction[..., 2] / np.maximum(length, 1e-9), -1, 1))
    in_fov = np.abs(elevation) <= _vertical_half_fov(env_cfg)
    rays = np.concatenate([np.repeat(eyes[:, None, :], targets.shape[0], axis=1),
                           direction / np.maximum(length, 1e-9)[..., None]], axis=2)
    hits = raycasting_scene.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6).astype(np.float32)))
    prim = hits["primitive_ids"].numpy().astype(np.int64).reshape(length.shape)
    valid = prim != o3d.t.geometry.RaycastingScene.INVALID_ID
    hit_instance = np.full(prim.shape, -1, dtype=np.int64)
    hit_instance[valid] = scene.tri_instance[prim[valid]]
    visible = ((hit_instance == instance_id) & in_fov).any(axis=1)
    return eyes_xy[visible]


def find_goal_objects(scene: Scene, navgrid, raycasting_scene, env_cfg: EnvConfig,
                      rng: np.random.Generator) -> dict[str, list[GoalObject]]:
    """Goal categories present in the scene -> their instances that have view points."""
    goals: dict[str, list[GoalObject]] = {}
    for category_id, category in enumerate(GOAL_CATEGORIES):
        if category not in scene.class_names:
            continue
        class_index = scene.class_names.index(category)
        for instance_id in scene.instance_ids(class_index):
            vps = find_view_points(scene, navgrid, raycasting_scene, int(instance_id), env_cfg, rng)
            if len(vps) == 0:
                continue
            centroid = scene.instance_triangles(int(instance_id)).reshape(-1, 3).mean(axis=0)
            goals.setdefault(category, []).append(
                GoalObject(int(instance_id), category, centroid.astype(np.float64), vps))
    return goals


def goal_mask(navgrid, goals: list[GoalObject]) -> np.ndarray:
    """(H, W) bool: the view-point cells of all given goal instances."""
    return view_point_mask(navgrid, np.concatenate([g.view_points for g in goals]))


def view_point_mask(navgrid, points_xy: np.ndarray) -> np.ndarray:
    """(H, W) bool: the cells of view points ``points_xy`` ((N, 2) world xy, metres); points
    off the grid mark nothing."""
    mask = np.zeros(navgrid.navigable.shape, dtype=bool)
    rc = navgrid.to_cell(np.asarray(points_xy, np.float64).reshape(-1, 2))
    inside = navgrid.in_grid(rc)
    mask[rc[inside, 0], rc[inside, 1]] = True
    return mask


def generate_scene_episodes(scene_id: str, scene: Scene, navgrid, raycasting_scene,
                            env_cfg: EnvConfig, n_episodes: int, seed: int) -> list[ObjectNavEpisode]:
    """``n_episodes`` episodes in one scene, deterministic for (scene, config, seed).
    Categories are cycled in a seeded random order so each present category gets episodes."""
    ds = env_cfg.dataset
    rng = np.random.default_rng(seed)
    goals_by_category = find_goal_objects(scene, navgrid, raycasting_scene, env_cfg, rng)
    if not goals_by_category:
        raise ValueError(f"scene {scene_id!r} has no reachable, visible instance of any goal category "
                         f"({', '.join(GOAL_CATEGORIES)})")
    categories = sorted(goals_by_category)
    fields = {c: navgrid.geodesic_field(goal_mask(navgrid, goals_by_category[c])) for c in categories}
    free = np.argwhere(navgrid.navigable)
    free_xy = navgrid.to_world(free)
    episodes: list[ObjectNavEpisode] = []
    order = list(rng.permutation(categories))
    attempt = 0
    while len(episodes) < n_episodes and attempt < n_episodes * len(categories) * 2:
        category = order[attempt % len(order)]
        attempt += 1
        field_c = fields[category]
        dist = field_c.values[free[:, 0], free[:, 1]]
        ok = np.isfinite(dist) & (dist >= ds.min_geodesic_m) & (dist <= ds.max_geodesic_m)
        if not ok.any():
            continue
        weights = np.where(ok, np.where(ok, dist, 1.0) ** START_DISTANCE_POWER, 0.0)
        all_vps = np.concatenate([g.view_points for g in goals_by_category[category]])
        for _ in range(MAX_START_TRIES):
            i = rng.choice(len(free), p=weights / weights.sum())
            geodesic = float(field_c.distance(free_xy[i]))
            euclid = float(np.min(np.linalg.norm(all_vps - free_xy[i], axis=1)))
            trivial = euclid > 0 and geodesic / euclid < ds.min_euclid_ratio
            if trivial and rng.random() < TRIVIAL_REJECT_PROB:
                continue
            episodes.append(ObjectNavEpisode(
                episode_id=f"{scene_id}:{len(episodes):03d}", scene_id=scene_id,
                start_position=free_xy[i].astype(np.float64),
                start_rotation=yaw_to_habitat_quaternion(float(rng.uniform(0, 2 * np.pi))),
                object_category=str(category), geodesic_distance=geodesic, euclidean_distance=euclid,
                goals=goals_by_category[category]))
            break
    return episodes


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


# ---------------------------------------------------------------- splits (cached)
def dataset_key(env_cfg: EnvConfig) -> str:
    """Hash of everything that changes the generated episodes."""
    relevant = {
        "version": GENERATOR_VERSION, "dataset": asdict(env_cfg.dataset),
        "nav": [env_cfg.agent_radius_m, env_cfg.agent_height_m, env_cfg.obstacle_min_height_m,
                env_cfg.nav_cell_m, env_cfg.view_point_radius_m, env_cfg.camera_height_m,
                env_cfg.hfov_deg, list(env_cfg.resolution)],
    }
    return hashlib.sha1(json.dumps(relevant, sort_keys=True).encode()).hexdigest()[:10]


def split_dir(split: str, env_cfg: EnvConfig) -> Path:
    return cache_dir() / "episodes" / f"{split}_{dataset_key(env_cfg)}"


# episode files already parsed in this process: path -> ((mtime_ns, size, inode), episodes). A
# command reads its split several times (preflight, feed order, the env); a rewritten file
# (another stat) is parsed again.
_PARSED: dict[Path, tuple[tuple[int, int, int], list[ObjectNavEpisode]]] = {}


def _stat_key(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_mtime_ns, st.st_size, st.st_ino


def _cached_episodes(path: Path) -> list[ObjectNavEpisode] | None:
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


def load_split(split: str, env_cfg: EnvConfig, progress: bool = True) -> list[ObjectNavEpisode]:
    """All episodes of a split, generating (and caching) missing or damaged scenes' episodes first."""
    from calnav.envs.scenes import generation_seed, load_scene, split_scene_ids
    from calnav.envs.navigation import NavGrid
    from calnav.envs.render import Camera, Renderer

    if split not in ("train", "val", "test"):
        raise ValueError(f"unknown split {split!r}; valid splits: train, val, test")
    root = split_dir(split, env_cfg)
    scene_ids = split_scene_ids(split, env_cfg.dataset)
    cached = {s: _cached_episodes(root / "content" / f"{s}.json.gz") for s in scene_ids}
    todo = [s for s in scene_ids if cached[s] is None]
    if todo:
        from tqdm import tqdm

        for sid in tqdm(todo, desc=f"generating {split} episodes", disable=not progress, unit="scene"):
            scene = load_scene(sid, env_cfg.dataset)
            renderer = Renderer(scene, Camera.from_config(env_cfg))
            navgrid = NavGrid.build(scene, env_cfg, renderer.raycasting_scene)
            seed = generation_seed(sid, env_cfg.dataset.seed)
            eps = generate_scene_episodes(sid, scene, navgrid, renderer.raycasting_scene, env_cfg,
                                          env_cfg.dataset.episodes_per_scene, seed)
            write_json_gz(root / "content" / f"{sid}.json.gz", episodes_to_habitat(eps))
            cached[sid] = episodes_from_habitat(episodes_to_habitat(eps))  # exactly what a later load reads
        write_json_gz(root / f"{split}.json.gz", {
            "episodes": [],
            "category_to_task_category_id": {c: i for i, c in enumerate(GOAL_CATEGORIES)},
            "category_to_scene_annotation_category_id": {c: i for i, c in enumerate(GOAL_CATEGORIES)},
        })
    return [ep for sid in scene_ids for ep in cached[sid]]


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


def parse_episode_range(spec: str, n_total: int) -> range:
    """'N' -> first N episodes; 'A:B' -> episodes A..B-1. Errors name the valid range."""
    try:
        if ":" in spec:
            a, b = (int(x) for x in spec.split(":", 1))
        else:
            a, b = 0, int(spec)
    except ValueError:
        raise ValueError(f"bad episode range {spec!r}; use N or A:B") from None
    if not (0 <= a < b <= n_total):
        raise ValueError(f"episode range {spec!r} is outside the split, which has episodes 0:{n_total}")
    return range(a, b)
