"""ObjectNav episodes in a house with storeys (a ``LayeredNavGrid``): ``envs.episodes``' rules,
with the storey added.

Goal view points: those of ``envs.episodes.find_view_points`` on the layer of the object's
storey (its record in ``Scene.meta["objects"]``), each with the floor height under it. A
category's goals are its instances on every storey; an episode's ``goal_storey`` is the storey
of the view point nearest to the start along the geodesic (one field per storey decides it).

Starts: drawn as ``envs.episodes`` draws them over every storey's floor (not on the stairs), except that
with probability ``CROSS_STOREY_PROB`` the draw is restricted to the cells whose nearest goal
lies on another storey (when there are any): otherwise a category present on every storey
would almost never send the agent up or down the stairs. Every episode is checked by the
layered oracle (``envs.oracle.layered_oracle_solves``).
"""
from __future__ import annotations

import numpy as np

from calnav.envs.config import EnvConfig
from calnav.envs.episode_files import GoalObject, ObjectNavEpisode, layered_goal_mask
from calnav.envs.episode_rules import (MAX_START_TRIES, MAX_UNSOLVABLE_TRIES, START_DISTANCE_POWER,
                                       TRIVIAL_REJECT_PROB, find_view_points)
from calnav.envs.oracle import layered_oracle_solves
from calnav.envs.scene import Scene
from calnav.envs.semantics import GOAL_CATEGORIES
from calnav.envs.task import yaw_to_habitat_quaternion

CROSS_STOREY_PROB = 0.5   # share of start draws kept to cells whose nearest goal is on another storey


class _LayerView:
    """One layer of a ``LayeredNavGrid`` as the single-storey grid ``find_view_points`` reads."""

    def __init__(self, grid, layer: int):
        self.navigable, self.floor_heights = grid.navigable[layer], grid.floor_heights[layer]
        self.cell_m, self.to_cell, self.to_world = grid.cell_m, grid.to_cell, grid.to_world


def storey_of(scene: Scene, grid):
    """instance id -> storey: the object's record in ``Scene.meta["objects"]``, or else the
    storey of the lowest point of its mesh (``LayeredNavGrid.storey_at``)."""
    known = {int(o["instance"]): int(o["storey"]) for o in scene.meta.get("objects", []) if "storey" in o}

    def storey(instance: int) -> int:
        if instance not in known:
            known[instance] = grid.storey_at(float(scene.instance_triangles(instance)[..., 2].min()))
        return known[instance]
    return storey


def find_layered_goals(scene: Scene, grid, raycasting_scene, env_cfg: EnvConfig,
                       rng: np.random.Generator) -> dict[str, list[GoalObject]]:
    """Goal categories present -> their instances with view points (on their storey's layer)."""
    storey = storey_of(scene, grid)
    goals: dict[str, list[GoalObject]] = {}
    for category in GOAL_CATEGORIES:
        if category not in scene.class_names:
            continue
        for instance_id in scene.instance_ids(scene.class_names.index(category)):
            k = storey(int(instance_id))
            view = _LayerView(grid, k)
            vps = find_view_points(scene, view, raycasting_scene, int(instance_id), env_cfg, rng)
            if len(vps) == 0:
                continue
            rc = grid.to_cell(vps)
            heights = grid.floor_heights[k, rc[:, 0], rc[:, 1]].astype(np.float64)
            centroid = scene.instance_triangles(int(instance_id)).reshape(-1, 3).mean(axis=0)
            goals.setdefault(category, []).append(
                GoalObject(int(instance_id), category, centroid.astype(np.float64), vps, heights))
    return goals


def _island_radii(grid) -> np.ndarray:
    """(n_islands,) largest horizontal distance from an island's centroid to its cells, metres."""
    cells = np.argwhere(grid.islands >= 0)
    ids = grid.islands[cells[:, 0], cells[:, 1], cells[:, 2]]
    xy = grid.to_world(cells[:, 1:])
    n = int(ids.max()) + 1 if len(ids) else 0
    centre = np.stack([np.bincount(ids, xy[:, k], n) / np.bincount(ids, minlength=n) for k in range(2)], axis=1)
    radius = np.zeros(n)
    np.maximum.at(radius, ids, np.linalg.norm(xy - centre[ids], axis=1))
    return radius


def generate_layered_episodes(scene_id: str, scene: Scene, grid, raycasting_scene, env_cfg: EnvConfig,
                              n_episodes: int, seed: int, report: dict | None = None) -> list[ObjectNavEpisode]:
    """``envs.episodes.generate_scene_episodes`` on a ``LayeredNavGrid`` (module docstring);
    ``report`` also counts the episodes kept that cross storeys (``cross_storey``)."""
    ds = env_cfg.dataset
    rng = np.random.default_rng(seed)
    goals_by_category = find_layered_goals(scene, grid, raycasting_scene, env_cfg, rng)
    if not goals_by_category:
        raise ValueError(f"scene {scene_id!r} has no reachable, visible instance of any goal category")
    categories = sorted(goals_by_category)
    fields, storey_fields = {}, {}
    for c in categories:
        fields[c] = grid.geodesic_field(layered_goal_mask(grid, goals_by_category[c]))
        per = [grid.geodesic_field(layered_goal_mask(grid, goals_by_category[c]) & (np.arange(grid.n_layers) == k)
                                   [:, None, None]).values for k in range(grid.n_layers)]
        storey_fields[c] = np.argmin(np.stack(per), axis=0)   # (L, H, W) storey of the nearest goal
    free = np.argwhere(grid.navigable)                         # (N, 3) layer, row, col
    free_xy = grid.to_world(free[:, 1:])
    free_z = grid.floor_heights[free[:, 0], free[:, 1], free[:, 2]].astype(np.float64)
    radii = _island_radii(grid)
    on_big_island = radii[grid.islands[free[:, 0], free[:, 1], free[:, 2]]] >= ds.min_island_radius_m
    # no starts on the stairs: a start stands on its storey's floor (within a climb of it)
    on_floor = np.abs(free_z - grid.storey_z[free[:, 0]]) <= grid.climb_m
    on_big_island &= on_floor
    counts = {"drawn": 0, "kept": 0, "unsolvable": 0, "no_start": 0, "cross_storey": 0}
    episodes: list[ObjectNavEpisode] = []
    order = list(rng.permutation(categories))
    attempt = 0
    while len(episodes) < n_episodes and attempt < n_episodes * len(categories) * 2:
        category = order[attempt % len(order)]
        attempt += 1
        field_c = fields[category]
        dist = field_c.values[free[:, 0], free[:, 1], free[:, 2]]
        goal_storey = storey_fields[category][free[:, 0], free[:, 1], free[:, 2]]
        ok = np.isfinite(dist) & (dist >= ds.min_geodesic_m) & (dist <= ds.max_geodesic_m) & on_big_island
        cross = ok & (goal_storey != free[:, 0])
        if cross.any() and rng.random() < CROSS_STOREY_PROB:
            ok = cross
        if not ok.any():
            counts["no_start"] += 1
            continue
        weights = np.where(ok, np.where(ok, dist, 1.0) ** START_DISTANCE_POWER, 0.0)
        goals = goals_by_category[category]
        vps = np.concatenate([np.column_stack([g.view_points, g.heights()]) for g in goals])
        unsolvable = 0
        for _ in range(MAX_START_TRIES):
            if unsolvable >= MAX_UNSOLVABLE_TRIES:
                break
            i = rng.choice(len(free), p=weights / weights.sum())
            layer = int(free[i, 0])
            geodesic = float(field_c.distance(free_xy[i], layer))
            euclid = float(np.min(np.linalg.norm(vps - np.append(free_xy[i], free_z[i]), axis=1)))
            if euclid > 0 and geodesic / euclid < ds.min_euclid_ratio and rng.random() < TRIVIAL_REJECT_PROB:
                continue
            episode = ObjectNavEpisode(
                episode_id=f"{scene_id}:{len(episodes):03d}", scene_id=scene_id,
                start_position=free_xy[i].astype(np.float64),
                start_rotation=yaw_to_habitat_quaternion(float(rng.uniform(0, 2 * np.pi))),
                object_category=str(category), geodesic_distance=geodesic, euclidean_distance=euclid, goals=goals,
                start_height=float(free_z[i]), start_storey=layer, goal_storey=int(goal_storey[i]))
            counts["drawn"] += 1
            if not layered_oracle_solves(grid, env_cfg, episode.start_position, layer, episode.start_yaw, field_c):
                counts["unsolvable"] += 1
                unsolvable += 1
                continue
            episodes.append(episode)
            counts["kept"] += 1
            counts["cross_storey"] += int(episode.crosses_storeys)
            break
    if report is not None:
        report.update(counts)
    return episodes
