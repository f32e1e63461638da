"""A habitat-lab dataset's episodes on calnav's navmesh: placed per scene, counted, cached.

habitat-sim's navmesh and calnav's are computed by the same rules from the same mesh, but they
differ by centimetres (cell height, erosion, polygons against a 5 cm grid), so a file's start or
view point can lie just off calnav's navigable cells. Every start and view point is placed as
habitat-sim places a point on its navmesh (``PathFinder``): a point whose cell is navigable, on
a layer whose floor lies within ``MAX_Y_DELTA_M`` of the point's height (habitat-sim's
``is_navigable``), stays where it is; any other is snapped to the nearest navigable cell centre
in 3-D inside habitat-sim's search box (``polyPickExt``: half extents 2 m horizontally, 4 m
vertically; ``envs.navigation.NavGrid.snap``). Then:

- a start snapped farther than ``env.dataset.max_snap_m`` is refused (calnav would run another
  task than the file's), and so is a start outside the search box;
- a view point that snaps nowhere is dropped (habitat-sim's DistanceToGoal ignores one it cannot
  project, too); an episode whose category keeps no view point reachable from its start is
  refused (its DistanceToGoal would be infinite: no Success, SPL or DTG is defined);
- a start rotation that is not a turn about Habitat's up axis is refused (the agent only turns).

A refused episode keeps its index (``--episodes A:B`` indexes the file) and its reason
(``ObjectNavEpisode.refused``); a run lists it and runs the others. The counts of every scene
(episodes kept and refused by reason, starts and view points snapped, the largest snap) are
cached beside its episodes and named in the run's summary.

Cache: ``cache_dir()/datasets/<key>/`` with ``content/<scene>-<hash>.json.gz`` (the scene's episodes
as placed, in habitat-lab's schema), ``report/<scene>.json`` (its counts, the dataset index of
each of its episodes, the refused ones' reasons) and ``index.json`` (every dataset index's
scene, the categories), ``key`` a hash of the dataset's files and of every
setting that moves a placement (navmesh, agent, snap bound, ``PLACEMENT_VERSION``).
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from calnav.common.atomic import write_json_atomic
from calnav.envs.config import EnvConfig
from calnav.envs.episode_datasets import DatasetFiles, EpisodeDataset, dataset_files, read_dataset, scene_name
from calnav.envs.episode_cache import cached_episodes
from calnav.envs.episode_files import GoalObject, ObjectNavEpisode, episodes_to_habitat, write_json_gz
from calnav.envs.scene import cache_dir

PLACEMENT_VERSION = 3                   # 2: heights in the scene file's frame (floor offset); 3: the scene dataset config an episode names
MAX_Y_DELTA_M = 0.5                 # habitat-sim's is_navigable(max_y_delta): on the navmesh within this height
SNAP_BOX_M = (2.0, 4.0)             # habitat-sim's polyPickExt half extents: horizontal, vertical, metres
SNAP_CANDIDATES = 16                # nearest cells tried per point for one inside the search box
ROTATION_TOLERANCE = 1e-4           # a start quaternion's x / z parts above this are a tilt, not a turn


def placement_key(source: DatasetFiles, env_cfg: EnvConfig) -> str:
    """Hash of the dataset's files and the settings that move a placement."""
    from calnav.envs.scene_files import GLB_CONVERSION_VERSION, PLY_CONVERSION_VERSION

    relevant = {"version": [PLACEMENT_VERSION, GLB_CONVERSION_VERSION, PLY_CONVERSION_VERSION], "files": source.key, "navmesh": asdict(env_cfg.navmesh),
                "nav": [env_cfg.agent_radius_m, env_cfg.agent_height_m, env_cfg.nav_cell_m],
                "snap": env_cfg.dataset.max_snap_m, "scenes": str(Path(env_cfg.dataset.scene_dir).expanduser())}
    return hashlib.sha1(json.dumps(relevant, sort_keys=True).encode()).hexdigest()[:12]


def placement_dir(source: DatasetFiles, env_cfg: EnvConfig) -> Path:
    """Where the placed episodes of ``source`` under ``env_cfg`` are cached."""
    return cache_dir() / "datasets" / f"{source.split}_{placement_key(source, env_cfg)}"


# ------------------------------------------------------------------------------- placing
def _is_yaw(q) -> bool:
    q = np.asarray(q, np.float64)
    n = float(np.linalg.norm(q))
    return n > 0 and math.isfinite(n) and abs(q[0]) / n <= ROTATION_TOLERANCE and abs(q[2]) / n <= ROTATION_TOLERANCE


def place_points(navgrid, xy, heights) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points as habitat-sim places them on its navmesh (module docstring), on one storey's
    ``NavGrid`` or a ``LayeredNavGrid``.

    xy: (N, 2) world xy, metres; heights: (N,) their heights (Habitat's y), metres. Returns
    ((N, 2) placed xy, (N,) int64 layers, (N,) bool placed, (N,) float64 distance moved in 3-D,
    metres): a point on a navigable cell whose floor lies within ``MAX_Y_DELTA_M`` stays; any
    other moves to the nearest navigable cell centre (floor height included) inside
    ``SNAP_BOX_M``, or is not placed.
    """
    from scipy.spatial import cKDTree

    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    heights = np.asarray(heights, np.float64).reshape(-1)
    out, moved = xy.copy(), np.zeros(len(xy))
    layers, placed = np.zeros(len(xy), np.int64), np.zeros(len(xy), bool)
    for i, (p, h) in enumerate(zip(xy, heights)):
        if navgrid.layered:
            k = navgrid.locate(p, h, MAX_Y_DELTA_M)
            placed[i] = k is not None and navgrid.is_navigable(p, k)
            layers[i] = k or 0
        else:
            placed[i] = navgrid.is_navigable(p) and abs(navgrid.floor_height(p) - h) <= MAX_Y_DELTA_M
    todo = np.flatnonzero(~placed)
    if len(todo):
        cells = np.argwhere(navgrid.navigable)                  # (N, 2) rows, cols, or (N, 3) layer first
        cells = cells if navgrid.layered else np.column_stack([np.zeros(len(cells), np.int64), cells])
        centres = navgrid.to_world(cells[:, 1:])
        grid_floors = navgrid.floor_heights if navgrid.floor_heights is not None else None
        if grid_floors is None:
            floors = np.full(len(cells), navgrid.floor_z)
        else:
            floors = (grid_floors[cells[:, 0], cells[:, 1], cells[:, 2]] if navgrid.layered
                      else grid_floors[cells[:, 1], cells[:, 2]]).astype(np.float64)
            floors = np.where(np.isfinite(floors), floors, navgrid.floor_z)
        tree = cKDTree(np.column_stack([centres, floors]))
        k = min(SNAP_CANDIDATES, len(cells))
        dist, idx = tree.query(np.column_stack([xy[todo], heights[todo]]), k=k)
        dist, idx = dist.reshape(len(todo), k), idx.reshape(len(todo), k)
        for row, i in enumerate(todo):   # the nearest candidate inside habitat-sim's search box
            for d, j in zip(dist[row], idx[row]):
                if not np.isfinite(d):
                    break
                if (np.abs(centres[j] - xy[i]) <= SNAP_BOX_M[0]).all() and abs(floors[j] - heights[i]) <= SNAP_BOX_M[1]:
                    out[i], layers[i], moved[i], placed[i] = centres[j], cells[j, 0], d, True
                    break
    return out, layers, placed, moved


def _floor(navgrid, xy, layer: int) -> float:
    """The floor height under ``xy`` on ``layer`` (one storey: its floor), metres."""
    return navgrid.floor_height(xy, int(layer)) if navgrid.layered else navgrid.floor_height(xy)


def _distance(navgrid, field, xy, layer: int) -> float:
    return float(field.distance(xy, int(layer)) if navgrid.layered else field.distance(xy))


def place_scene_episodes(navgrid, episodes: list[ObjectNavEpisode], env_cfg: EnvConfig
                         ) -> tuple[list[ObjectNavEpisode], dict]:
    """The episodes of one scene placed on ``navgrid`` (module docstring), in their order, and
    the scene's counts: episodes, kept, refused by reason, starts / view points snapped,
    view points dropped, the largest start snap (m)."""
    counts = {"episodes": len(episodes), "kept": 0, "refused": {}, "starts_snapped": 0, "max_start_snap_m": 0.0,
              "view_points": 0, "view_points_snapped": 0, "view_points_dropped": 0}
    placed_goals: dict[int, GoalObject] = {}

    def place_goal(g: GoalObject) -> GoalObject:
        if id(g) not in placed_goals:
            xy, layers, ok, moved = place_points(navgrid, g.view_points, g.heights())
            counts["view_points"] += len(ok)
            counts["view_points_dropped"] += int((~ok).sum())
            counts["view_points_snapped"] += int((moved[ok] > 0).sum())
            floors = np.array([_floor(navgrid, p, k) for p, k in zip(xy[ok], layers[ok])], np.float64)
            placed_goals[id(g)] = replace(g, view_points=xy[ok], view_point_heights=floors)
        return placed_goals[id(g)]

    out = []
    for ep in episodes:
        goals = [place_goal(g) for g in ep.goals]
        placed, reason = _place_episode(navgrid, ep, goals, env_cfg)
        if reason:
            kind = reason.split(":")[0]
            counts["refused"][kind] = counts["refused"].get(kind, 0) + 1
            out.append(replace(ep, goals=goals, refused=reason))
            continue
        placed, moved = placed
        counts["starts_snapped"] += moved > 0
        counts["max_start_snap_m"] = max(counts["max_start_snap_m"], round(moved, 4))
        out.append(placed)
        counts["kept"] += 1
    return out, counts


def _place_episode(navgrid, ep: ObjectNavEpisode, goals: list[GoalObject], env_cfg: EnvConfig
                   ) -> tuple[tuple[ObjectNavEpisode, float] | None, str]:
    """((``ep`` with its start placed and its ``goals`` (placed already), how far the start
    moved, metres) or None; why it cannot run on ``navgrid``, or ""). The file's
    ``info.geodesic_distance`` stays (its DistanceToGoal at reset is calnav's own)."""
    from calnav.envs.episode_files import goal_mask

    if not _is_yaw(ep.start_rotation):
        return None, f"tilted start: start_rotation {list(ep.start_rotation)} is not a turn about the up axis"
    xy, layers, ok, moved = place_points(navgrid, ep.start_position, [ep.start_height])
    if not ok[0]:
        return None, "start off the navmesh: no navigable cell within habitat-sim's snap box (2 m, 4 m)"
    xy, layer, moved = xy[0], int(layers[0]), float(moved[0])
    if moved > env_cfg.dataset.max_snap_m:
        return None, (f"start off the navmesh: the nearest navigable cell is {moved:.2f} m away, beyond "
                      f"env.dataset.max_snap_m ({env_cfg.dataset.max_snap_m:g} m)")
    if not any(len(g.view_points) for g in goals):
        return None, f"no view point: none of the {ep.object_category} view points lies on calnav's navmesh"
    mask = goal_mask(navgrid, [g for g in goals if len(g.view_points)])
    if not math.isfinite(_distance(navgrid, navgrid.geodesic_field(mask), xy, layer)):
        return None, f"unreachable: no {ep.object_category} view point is reachable from the start on calnav's navmesh"
    goal_storey = 0
    if navgrid.layered:   # the storey of the nearest view point (geodesically), as generated episodes name it
        per = [_distance(navgrid, navgrid.geodesic_field(mask & (np.arange(navgrid.n_layers) == k)[:, None, None]),
                         xy, layer) if mask[k].any() else math.inf for k in range(navgrid.n_layers)]
        goal_storey = int(np.argmin(per))
    return (replace(ep, start_position=xy, start_height=_floor(navgrid, xy, layer), start_storey=layer,
                    goal_storey=goal_storey, goals=goals), moved), ""


# --------------------------------------------------------------------------- per scene
def cache_name(scene_id: str) -> str:
    """The file name a scene's placed episodes are cached under: its name and a hash of its
    whole id (two releases' scenes may share a name)."""
    return f"{scene_name(scene_id)}-{hashlib.sha1(scene_id.encode()).hexdigest()[:8]}"


def scene_episodes(dataset: EpisodeDataset, scene_id: str) -> list[tuple[int, ObjectNavEpisode]]:
    """(dataset index, episode) of every episode of ``scene_id``, in the file's order."""
    return [(i, ep) for i, ep in enumerate(dataset.episodes) if ep.scene_id == scene_id]


def place_scene(scene_id: str, mine: list[tuple[int, ObjectNavEpisode]], env_cfg: EnvConfig) -> tuple[dict, dict]:
    """The episodes ``mine`` (``scene_episodes``) of one scene placed, the scene loaded and its
    navmesh built first: (its report, its placed content file as a dict). Writes nothing:
    ``write_placed`` caches them (in the driver, so a Ray worker needs no shared disk)."""
    from calnav.envs.navigation import NavGrid
    from calnav.envs.scene import RGB_UNAVAILABLE, SEMANTICS_UNAVAILABLE
    from calnav.envs.scenes import load_scene

    scene = load_scene(scene_id, env_cfg.dataset, dataset_config=mine[0][1].scene_dataset_config if mine else "")
    navgrid = NavGrid.build(scene, env_cfg)
    offset = float(scene.meta.get("floor_offset_m", 0.0))   # the file's heights are calnav's + this
    placed, counts = place_scene_episodes(navgrid, lowered([ep for _, ep in mine], offset), env_cfg)
    # what the scene's files could not give (a run that needs it is refused before it starts)
    lacks = {"rgb": scene.meta.get(RGB_UNAVAILABLE, ""), "semantics": scene.meta.get(SEMANTICS_UNAVAILABLE, "")}
    report = {**counts, "scene": scene_id, "scene_file": scene_file_key(scene_id, env_cfg.dataset.scene_dir), "navmesh": navgrid.stats,
              "indices": [i for i, _ in mine], "lacks": lacks,
              "refused_episodes": {ep.episode_id: ep.refused for ep in placed if ep.refused}}
    return report, episodes_to_habitat(placed)


def lowered(episodes: list[ObjectNavEpisode], offset_m: float) -> list[ObjectNavEpisode]:
    """``episodes`` with every height (start, view points, goal centroids) less ``offset_m``:
    a file's heights are in the scene file's frame, which calnav shifts to put the floor at
    z = 0 (``envs.scene_frame.place_on_floor``; ``meta["floor_offset_m"]``). HM3D's floors lie
    anywhere (-1.4 m, 2.9 m on an upper storey), so without this every start would be metres
    off its floor."""
    if offset_m == 0.0:
        return episodes
    goals: dict[int, GoalObject] = {}

    def low(g: GoalObject) -> GoalObject:
        if id(g) not in goals:
            goals[id(g)] = replace(g, position=np.asarray(g.position, np.float64) - [0.0, 0.0, offset_m],
                                   view_point_heights=g.heights() - offset_m)
        return goals[id(g)]

    return [replace(ep, start_height=ep.start_height - offset_m, goals=[low(g) for g in ep.goals]) for ep in episodes]


def scene_file_key(scene_id: str, scene_dir: str) -> list:
    """[[path, size, mtime_ns], ...] of the file ``scene_id`` resolves to and the files of its
    scene beside it (``<id>.semantic.glb``, ``.semantic.txt``, ``.house``, ``_semantic.ply``): a
    placement, and what it recorded of the scene, is of those files (a scene changed since is
    placed again)."""
    from calnav.envs.episode_datasets import resolve_scene

    path = resolve_scene(scene_id, scene_dir)
    stem = scene_name(path.name)
    files = sorted({path, *(p for p in path.parent.glob(f"{stem}*") if p.is_file())})
    return [[str(p.resolve()), p.stat().st_size, p.stat().st_mtime_ns] for p in files]


def write_placed(root: Path, scene_id: str, report: dict, content: dict) -> None:
    """Cache ``place_scene``'s result: the report first, then the content (a content file
    without its report is placed again, never half-counted)."""
    name = cache_name(scene_id)
    write_json_atomic(root / "report" / f"{name}.json", report)
    write_json_gz(root / "content" / f"{name}.json.gz", content)


def write_index(root: Path, dataset: EpisodeDataset) -> None:
    """``index.json``: the scene of every dataset index (so that a worker finds its episodes
    without parsing the dataset's files) and the task's categories."""
    path = root / "index.json"
    data = {"scenes": [ep.scene_id for ep in dataset.episodes], "categories": dataset.source.categories}
    if not path.exists() or json.loads(path.read_text()) != data:
        write_json_atomic(path, data)


def _placed(root: Path, scene_id: str, env_cfg: EnvConfig) -> bool:
    name = cache_name(scene_id)
    try:
        report = json.loads((root / "report" / f"{name}.json").read_text())
    except (OSError, ValueError):
        return False
    return _current(report, scene_id, env_cfg) and cached_episodes(root / "content" / f"{name}.json.gz") is not None


def _current(report: dict, scene_id: str, env_cfg: EnvConfig) -> bool:
    """Whether a cached placement is of the scene file ``scene_id`` resolves to now."""
    try:
        return isinstance(report, dict) and report.get("scene_file") == scene_file_key(scene_id, env_cfg.dataset.scene_dir)
    except (ValueError, OSError):
        return False


def scenes_to_place(dataset: EpisodeDataset, env_cfg: EnvConfig, upto: int | None) -> tuple[list[str], list[str]]:
    """(the scenes of episodes ``0:upto``, in order of first appearance; those not placed yet)."""
    root = placement_dir(dataset.source, env_cfg)
    needed = list(dict.fromkeys(ep.scene_id for ep in dataset.episodes[:upto]))
    return needed, [s for s in needed if not _placed(root, s, env_cfg)]


def _placed_prefix(root: Path, scenes: list[str], upto: int | None, env_cfg: EnvConfig) -> list[ObjectNavEpisode] | None:
    """Episodes ``0:upto`` as placed, from the cache (``scenes``: each dataset index's scene), or
    None when a scene they need is not placed (or its cache is damaged)."""
    n = len(scenes) if upto is None else min(upto, len(scenes))
    by_index: dict[int, ObjectNavEpisode] = {}
    for scene_id in dict.fromkeys(scenes[:n]):
        name = cache_name(scene_id)
        episodes = cached_episodes(root / "content" / f"{name}.json.gz")
        try:
            report = json.loads((root / "report" / f"{name}.json").read_text())
            indices, refused = report["indices"], report["refused_episodes"]
        except (OSError, ValueError, KeyError, TypeError):
            return None
        if not _current(report, scene_id, env_cfg):
            return None
        if episodes is None or len(indices) != len(episodes):
            return None
        for i, ep in zip(indices, episodes):
            by_index[i] = replace(ep, refused=refused.get(ep.episode_id, ""))
    if any(i not in by_index for i in range(n)):
        return None
    return [by_index[i] for i in range(n)]


def load_dataset_split(env_cfg: EnvConfig, progress: bool = True, upto: int | None = None) -> list[ObjectNavEpisode]:
    """Episodes ``0:upto`` (every one when None) of ``env_cfg.dataset.data_path``'s split
    ``env_cfg.split``, placed on calnav's navmesh (module docstring), in the file's order;
    scenes not placed yet are placed here, one after another (``eval.episodes`` places them on
    a run's worker pool). A worker whose scenes are placed reads only the cache."""
    from tqdm import tqdm

    source = dataset_files(env_cfg.dataset.data_path, env_cfg.split)
    root = placement_dir(source, env_cfg)
    try:
        scenes = json.loads((root / "index.json").read_text())["scenes"]
        fast = _placed_prefix(root, scenes, upto, env_cfg)
    except (OSError, ValueError, KeyError, TypeError):
        fast = None
    if fast is not None:
        return fast
    dataset = read_dataset(env_cfg.dataset.data_path, env_cfg.split)
    write_index(root, dataset)
    _, todo = scenes_to_place(dataset, env_cfg, upto)
    for sid in tqdm(todo, desc=f"placing {env_cfg.split} episodes", disable=not progress, unit="scene"):
        write_placed(root, sid, *place_scene(sid, scene_episodes(dataset, sid), env_cfg))
    placed = _placed_prefix(root, [ep.scene_id for ep in dataset.episodes], upto, env_cfg)
    if placed is None:
        raise OSError(f"the placed episodes of {env_cfg.dataset.data_path} cannot be read back from {root}; check "
                      "that CALNAV_CACHE is writable")
    return placed


def placement_report(dataset: EpisodeDataset, env_cfg: EnvConfig) -> dict[str, dict]:
    """{scene: its placement counts} of the dataset's placed scenes."""
    root = placement_dir(dataset.source, env_cfg) / "report"
    out = {}
    for scene_id in dataset.scene_ids():
        path = root / f"{cache_name(scene_id)}.json"
        if path.exists():
            out[scene_id] = json.loads(path.read_text())
    return out
