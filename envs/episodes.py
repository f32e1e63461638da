"""ObjectNav episodes: generation (seeded, deterministic) and split caching (the records and
their habitat-lab JSON files: ``envs.episode_files``).

Goal view points: navigable cells whose horizontal distance to the goal object's footprint is
at most ``view_point_radius_m`` (1.0 m) and from which some part of the object is visible at
camera height within the vertical field of view (a ray from the camera to a surface sample of
the object hits that object first). An instance with no view point cannot be a goal.

Start poses: a navigable cell on an island of radius at least ``min_island_radius_m`` (habitat-lab's
``ISLAND_RADIUS_LIMIT``: no starts on a sliver or a bed top) whose geodesic distance to the
nearest view point lies in [min_geodesic_m, max_geodesic_m], drawn with probability
proportional to that distance (most of a house lies near some goal; the weighting keeps a
split's median above 5 m), with uniform heading. Like habitat-lab's generators, a start whose
geodesic / Euclidean distance ratio is below ``min_euclid_ratio`` (a straight shot) is rejected
with probability ``TRIVIAL_REJECT_PROB``.

Only solvable episodes: every drawn episode is run by the discrete-action oracle
(``envs.oracle.oracle_solves``: 0.25 m steps, 30 degree turns, the env's own motion) and kept
only if it reaches a view point and STOPs inside the success distance within
``dataset.oracle_max_steps`` actions (500, HM3D's step limit; a property of the dataset, so a run
with another ``env.max_episode_steps`` keeps the same episodes).
A grid path that the action lattice cannot follow (a start on a sliver where only one heading
moves, a gap a 30 degree turn cannot line up with) is rejected and counted: the counts per
scene are kept beside the split (``<split>/generation/<scene>.json``, ``generation_report``).
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from calnav.common.atomic import write_json_atomic
from calnav.envs.config import EnvConfig, plain_dict
from calnav.envs.episode_files import (goal_mask, view_point_mask,  # noqa: F401 (importable here too)
                                       GoalObject, ObjectNavEpisode, episodes_from_habitat,
                                       episodes_to_habitat, write_json_gz)
from calnav.envs.episode_cache import cached_episodes
from calnav.envs.episode_rules import (MAX_START_TRIES, MAX_UNSOLVABLE_TRIES, START_DISTANCE_POWER,  # noqa: F401
                                       SURFACE_SAMPLE_SPACING_M, TRIVIAL_REJECT_PROB, VISIBILITY_TARGETS,
                                       find_view_points)
from calnav.envs.oracle import oracle_solves
from calnav.envs.scene import Scene, cache_dir
from calnav.envs.semantics import GOAL_CATEGORIES
from calnav.envs.task import yaw_to_habitat_quaternion

GENERATOR_VERSION = 4  # 2: walls block in the nav grid; 3: starts weighted by distance^1; 4: navmesh, islands, oracle check
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


def island_radii(navgrid) -> np.ndarray:
    """(n_islands,) radius of each navmesh island, metres: the largest distance from the
    island's centroid to one of its cell centres (habitat-sim's ``island_radius``)."""
    islands = navgrid.islands if navgrid.islands is not None else np.where(navgrid.navigable, 0, -1)
    cells = np.argwhere(islands >= 0)
    ids = islands[cells[:, 0], cells[:, 1]]
    xy = navgrid.to_world(cells)
    n = int(ids.max()) + 1 if len(ids) else 0
    centre = np.stack([np.bincount(ids, xy[:, k], n) / np.bincount(ids, minlength=n) for k in range(2)], axis=1)
    radius = np.zeros(n)
    np.maximum.at(radius, ids, np.linalg.norm(xy - centre[ids], axis=1))
    return radius


def generate_scene_episodes(scene_id: str, scene: Scene, navgrid, raycasting_scene, env_cfg: EnvConfig,
                            n_episodes: int, seed: int, report: dict | None = None) -> list[ObjectNavEpisode]:
    """``n_episodes`` solvable episodes in one scene, deterministic for (scene, config, seed).
    Categories are cycled in a seeded random order so each present category gets episodes.
    ``report``: a dict to receive the counts of drawn, kept and rejected episodes (by reason:
    ``unsolvable`` by the oracle; ``no_start`` when no navigable start lies in the distance
    range on a large enough island)."""
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
    radii = island_radii(navgrid)
    islands = navgrid.islands[free[:, 0], free[:, 1]] if navgrid.islands is not None else np.zeros(len(free), int)
    on_big_island = radii[islands] >= ds.min_island_radius_m
    counts = {"drawn": 0, "kept": 0, "unsolvable": 0, "no_start": 0}
    episodes: list[ObjectNavEpisode] = []
    order = list(rng.permutation(categories))
    attempt = 0
    while len(episodes) < n_episodes and attempt < n_episodes * len(categories) * 2:
        category = order[attempt % len(order)]
        attempt += 1
        field_c = fields[category]
        dist = field_c.values[free[:, 0], free[:, 1]]
        ok = np.isfinite(dist) & (dist >= ds.min_geodesic_m) & (dist <= ds.max_geodesic_m) & on_big_island
        if not ok.any():
            counts["no_start"] += 1
            continue
        weights = np.where(ok, np.where(ok, dist, 1.0) ** START_DISTANCE_POWER, 0.0)
        all_vps = np.concatenate([g.view_points for g in goals_by_category[category]])
        unsolvable = 0
        for _ in range(MAX_START_TRIES):
            if unsolvable >= MAX_UNSOLVABLE_TRIES:   # this category's goals are hard to reach: try another
                break
            i = rng.choice(len(free), p=weights / weights.sum())
            geodesic = float(field_c.distance(free_xy[i]))
            euclid = float(np.min(np.linalg.norm(all_vps - free_xy[i], axis=1)))
            trivial = euclid > 0 and geodesic / euclid < ds.min_euclid_ratio
            if trivial and rng.random() < TRIVIAL_REJECT_PROB:
                continue
            episode = ObjectNavEpisode(
                episode_id=f"{scene_id}:{len(episodes):03d}", scene_id=scene_id,
                start_position=free_xy[i].astype(np.float64),
                start_rotation=yaw_to_habitat_quaternion(float(rng.uniform(0, 2 * np.pi))),
                object_category=str(category), geodesic_distance=geodesic, euclidean_distance=euclid,
                goals=goals_by_category[category])
            counts["drawn"] += 1
            if not oracle_solves(navgrid, env_cfg, episode.start_position, episode.start_yaw, field_c):
                counts["unsolvable"] += 1
                unsolvable += 1
                continue
            episodes.append(episode)
            counts["kept"] += 1
            break
    if report is not None:
        report.update(counts)
    return episodes


# ---------------------------------------------------------------- splits (cached)
def dataset_key(env_cfg: EnvConfig) -> str:
    """Hash of everything that changes the generated episodes."""
    relevant = {
        "version": GENERATOR_VERSION, "dataset": plain_dict(env_cfg.dataset), "navmesh": asdict(env_cfg.navmesh),
        "nav": [env_cfg.agent_radius_m, env_cfg.agent_height_m, env_cfg.nav_cell_m, env_cfg.view_point_radius_m,
                env_cfg.camera_height_m, env_cfg.hfov_deg, list(env_cfg.resolution)],
        # the oracle check runs the task's actions (its step limit is the dataset's oracle_max_steps)
        "task": [env_cfg.forward_step_m, env_cfg.turn_angle_deg, env_cfg.success_distance_m],
    }
    if env_cfg.dataset.style == "scanned":   # episodes on an older scan's floor are other episodes
        from calnav.envs.scenes import scan_versions

        relevant["scans"] = scan_versions()
    return hashlib.sha1(json.dumps(relevant, sort_keys=True).encode()).hexdigest()[:10]


def split_dir(split: str, env_cfg: EnvConfig) -> Path:
    return cache_dir() / "episodes" / f"{split}_{dataset_key(env_cfg)}"


def generate_scene(split: str, scene_id: str, env_cfg: EnvConfig) -> tuple[dict, dict]:
    """One scene's episodes, generated (the scene loaded, or scanned, first): (its generation
    report: counts and navmesh figures, its habitat-lab content file as a dict). Writes nothing:
    ``write_scene`` caches them (in the driver, so a Ray worker on another node needs no shared
    disk)."""
    from calnav.envs.navigation import NavGrid
    from calnav.envs.render import Camera, Renderer
    from calnav.envs.scenes import generation_seed, load_scene

    scene = load_scene(scene_id, env_cfg.dataset)
    renderer = Renderer(scene, Camera.from_config(env_cfg))
    navgrid = NavGrid.build(scene, env_cfg, renderer.raycasting_scene)
    counts: dict = {}
    generate = generate_scene_episodes
    if navgrid.layered:
        from calnav.envs.storey_episodes import generate_layered_episodes as generate
    eps = generate(scene_id, scene, navgrid, renderer.raycasting_scene, env_cfg, env_cfg.dataset.episodes_per_scene,
                   generation_seed(scene_id, env_cfg.dataset.seed), report=counts)
    if not eps:
        raise ValueError(f"scene {scene_id!r}: every episode drawn was rejected ({counts['unsolvable']} "
                         f"unsolvable by the oracle, {counts['no_start']} category draws without a start "
                         f"{ds_range(env_cfg)} on an island of radius >= "
                         f"{env_cfg.dataset.min_island_radius_m} m); check it with calnav check-scene")
    return {**counts, "navmesh": navgrid.stats}, episodes_to_habitat(eps)


def write_scene(split: str, scene_id: str, env_cfg: EnvConfig, report: dict, content: dict) -> None:
    """Cache ``generate_scene``'s result: ``<split>/generation/<scene>.json``, then
    ``<split>/content/<scene>.json.gz`` (a content file without its report is regenerated,
    never half-counted) and habitat-lab's ``<split>.json.gz`` beside them."""
    root = split_dir(split, env_cfg)
    write_json_atomic(root / "generation" / f"{scene_id}.json", report)
    write_json_gz(root / "content" / f"{scene_id}.json.gz", content)
    write_json_gz(root / f"{split}.json.gz", {   # the split file: its scenes are under content/
        "episodes": [],
        "category_to_task_category_id": {c: i for i, c in enumerate(GOAL_CATEGORIES)},
        "category_to_scene_annotation_category_id": {c: i for i, c in enumerate(GOAL_CATEGORIES)},
    })


def scenes_needed(split: str, env_cfg: EnvConfig, upto: int | None) -> tuple[list[str], list[str]]:
    """(the leading scenes of ``split`` that hold episodes ``0:upto``, those of them not cached
    yet). A scene not generated yet counts as ``episodes_per_scene`` episodes, its most; after
    generating it the caller asks again (a scene that yields fewer moves the range on). Episode
    indices are positions in the scenes' concatenation, so a range needs every scene before it
    too. ``upto`` None: every scene."""
    from calnav.envs.scenes import split_scene_ids

    if split not in ("train", "val", "test"):
        raise ValueError(f"unknown split {split!r}; valid splits: train, val, test")
    root = split_dir(split, env_cfg) / "content"
    needed, todo, total = [], [], 0
    for sid in split_scene_ids(split, env_cfg.dataset):
        if upto is not None and total >= upto:
            break
        cached = cached_episodes(root / f"{sid}.json.gz")
        needed.append(sid)
        if cached is None:
            todo.append(sid)
        total += env_cfg.dataset.episodes_per_scene if cached is None else len(cached)
    return needed, todo


def load_split(split: str, env_cfg: EnvConfig, progress: bool = True, upto: int | None = None
               ) -> list[ObjectNavEpisode]:
    """The episodes of ``split``'s leading scenes that hold episodes ``0:upto`` (all scenes when
    ``upto`` is None; the list is then a prefix of the full split's, with the same indices),
    generating (and caching) missing or damaged scenes' episodes first, one after another here
    (``eval.episodes.prepare_episodes`` generates them on a run's worker pool)."""
    from tqdm import tqdm

    if env_cfg.dataset.data_path:   # a habitat-lab episode file: its episodes, placed on calnav's navmesh
        from calnav.envs.file_episodes import load_dataset_split

        return load_dataset_split(replace(env_cfg, split=split), progress, upto)
    generated: set[str] = set()
    while True:   # ends: every pass generates scenes not generated before, of finitely many
        needed, todo = scenes_needed(split, env_cfg, upto)
        if not todo:
            return split_prefix(split, env_cfg, needed)
        check_read_back(split, env_cfg, todo, generated)
        for sid in tqdm(todo, desc=f"generating {split} episodes", disable=not progress, unit="scene"):
            write_scene(split, sid, env_cfg, *generate_scene(split, sid, env_cfg))
            generated.add(sid)


def split_prefix(split: str, env_cfg: EnvConfig, scene_ids: list[str]) -> list[ObjectNavEpisode]:
    """The cached episodes of ``scene_ids`` (generated), concatenated in order."""
    root = split_dir(split, env_cfg) / "content"
    return [ep for sid in scene_ids for ep in cached_episodes(root / f"{sid}.json.gz")]


def check_read_back(split: str, env_cfg: EnvConfig, todo: list[str], generated: set[str]) -> None:
    """Raise when a scene generated in this call is still not readable from the cache (a cache
    directory that drops writes): generating it again would loop for ever."""
    lost = [s for s in todo if s in generated]
    if lost:
        raise OSError(f"the episodes of {lost[0]} were generated but cannot be read back from "
                      f"{split_dir(split, env_cfg) / 'content'}; check that CALNAV_CACHE is writable")


def ds_range(env_cfg: EnvConfig) -> str:
    """The start-distance range of the dataset, as text."""
    return f"{env_cfg.dataset.min_geodesic_m:g}-{env_cfg.dataset.max_geodesic_m:g} m from a view point"


def generation_report(split: str, env_cfg: EnvConfig) -> dict[str, dict]:
    """{scene id: its generation counts (drawn, kept, unsolvable, no_start) and navmesh
    figures} of the split's generated scenes (``load_split`` first); scenes generated before
    reports existed are missing."""
    from calnav.envs.scenes import split_scene_ids

    root = split_dir(split, env_cfg) / "generation"
    out = {}
    for sid in split_scene_ids(split, env_cfg.dataset):
        path = root / f"{sid}.json"
        if path.exists():
            out[sid] = json.loads(path.read_text())
    return out


def check_split_capacity(spec: str, split: str, env_cfg: EnvConfig) -> None:
    """Refuse the episode range ``spec`` at once when it ends past the most episodes ``split``
    can hold (its scenes x ``episodes_per_scene``), before any scene is generated: the exact
    size is known only after generation (a scene may yield fewer), the bound before it."""
    from calnav.envs.scenes import split_scene_ids

    end = parse_episode_range(spec, None).stop
    n_scenes = len(split_scene_ids(split, env_cfg.dataset))
    most = n_scenes * env_cfg.dataset.episodes_per_scene
    if end > most:
        raise ValueError(f"episode range {spec!r} is outside the split, which has at most {most} episodes "
                         f"({n_scenes} {split} scenes x dataset.episodes_per_scene "
                         f"{env_cfg.dataset.episodes_per_scene})")


def parse_episode_range(spec: str, n_total: int | None) -> range:
    """'N' -> first N episodes; 'A:B' -> episodes A..B-1. Errors name the valid range.
    ``n_total`` None: the split's size is not known yet (its scenes are not all generated), so
    only the form is checked."""
    try:
        if ":" in spec:
            a, b = (int(x) for x in spec.split(":", 1))
        else:
            a, b = 0, int(spec)
    except ValueError:
        raise ValueError(f"bad episode range {spec!r}; use N or A:B") from None
    if a < 0 or b <= a:
        raise ValueError(f"episode range {spec!r} is empty or reversed; use N (> 0) or A:B with 0 <= A < B")
    if n_total is not None and b > n_total:
        raise ValueError(f"episode range {spec!r} is outside the split, which has episodes 0:{n_total}")
    return range(a, b)
